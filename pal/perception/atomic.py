"""Atomic file writes for perception artifacts: a temp file next to the target, then a rename.

``pal.perception`` must not import ``models`` (DESIGN.md, "Dependencies run one way"), so it
keeps this small helper of its own instead of borrowing ``models.io.atomic_write``.
"""

from __future__ import annotations

import io
import json
import os
import platform
import tempfile
from collections.abc import Mapping
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import cv2
import numpy as np

__all__ = ["atomic_write_bytes", "atomic_write_json", "atomic_write_npz", "atomic_write_png", "versions"]


def versions() -> dict[str, str]:
    """Versions of Python and of the libraries perception artifacts depend on (provenance)."""
    out = {"python": platform.python_version(), "opencv": cv2.__version__}
    for dist in ("pal", "numpy", "scipy"):
        try:
            out[dist] = importlib_metadata.version(dist)
        except importlib_metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to a temp file in ``path``'s directory, fsync it, then rename it over ``path``.

    A reader never sees a half-written file; an interrupted write leaves no temp file behind.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_json(path: str | os.PathLike[str], data: Any) -> Path:
    """Write ``data`` as indented UTF-8 JSON (NaN/inf are refused: JSON has no such values)."""
    text = json.dumps(data, indent=2, sort_keys=True, allow_nan=False) + "\n"
    return atomic_write_bytes(path, text.encode("utf-8"))


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


def atomic_write_npz(path: str | os.PathLike[str], arrays: Mapping[str, np.ndarray]) -> Path:
    """Write ``arrays`` as a compressed ``.npz`` (no object arrays: it must load with ``allow_pickle=False``)."""
    for key, value in arrays.items():
        if np.asarray(value).dtype == object:
            raise ValueError(f"array {key!r} has dtype object; .npz files here must load without pickle")
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return atomic_write_bytes(path, buf.getvalue())
