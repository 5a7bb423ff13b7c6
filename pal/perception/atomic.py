"""Atomic writes of perception artifacts (PNG on top of :mod:`pal.files`) and their provenance."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from pal.files import atomic_write_bytes, atomic_write_json, atomic_write_npz
from pal.files import versions as _versions

__all__ = ["atomic_write_bytes", "atomic_write_json", "atomic_write_npz", "atomic_write_png", "versions"]


def versions() -> dict[str, str]:
    """Versions of Python and of the libraries perception artifacts depend on (provenance)."""
    return {**_versions(("pal", "numpy", "scipy")), "opencv": cv2.__version__}


def atomic_write_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """Encode ``image`` as PNG and write it atomically.

    Args:
        image: (H, W) uint8/uint16 or (H, W, 3) uint8 in OpenCV's BGR channel order.
    """
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(
            f"OpenCV could not encode an image of shape {image.shape} and dtype {image.dtype} as PNG"
        )
    return atomic_write_bytes(path, buf.tobytes())
