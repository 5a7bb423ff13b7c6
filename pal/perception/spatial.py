"""The egocentric spatial descriptor ŝ_i^spat (§4.2.2.5): where an object is relative to the camera.

From the object's mask and the aligned depth:

- ``centroid``: per-axis median of the back-projected mask pixels with valid depth, metres,
  OpenCV camera frame (x right, y down, z forward); the median resists flying pixels at
  silhouettes;
- ``distance``: ``|centroid|``, metres;
- ``azimuth``: ``atan2(x, z)``, rad, positive to the right of the optical axis;
- ``elevation``: ``atan2(-y, sqrt(x² + z²))``, rad, positive above it;
- ``spread``: (3,) half inter-quartile range of the points per axis, metres — a crude
  half-extent of the visible surface, used as the centroid's uncertainty;
- ``num_points``: valid depth pixels behind the estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask

__all__ = ["SpatialDescriptor", "mask_points", "spatial_descriptor"]


def mask_points(frame: RGBDFrame, mask: Mask, min_depth: float = 0.1, max_depth: float = 5.0) -> np.ndarray:
    """(M, 3) camera-frame points of the mask pixels with depth in [min_depth, max_depth], metres."""
    x0, y0, x1, y1 = mask.bbox
    z = frame.depth[y0:y1, x0:x1]
    sel = mask.crop & (z >= min_depth) & (z <= max_depth)
    vs, us = np.nonzero(sel)
    return backproject(us + x0, vs + y0, z[vs, us], frame.K)


@dataclass(frozen=True, eq=False)
class SpatialDescriptor:
    """Egocentric spatial descriptor (module docstring)."""

    centroid: np.ndarray
    distance: float
    azimuth: float
    elevation: float
    spread: np.ndarray
    num_points: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields (arrays as lists)."""
        return {
            "centroid": self.centroid.tolist(),
            "distance": self.distance,
            "azimuth": self.azimuth,
            "elevation": self.elevation,
            "spread": self.spread.tolist(),
            "num_points": self.num_points,
        }


def spatial_descriptor(
    frame: RGBDFrame, mask: Mask, *, min_depth: float = 0.1, max_depth: float = 5.0, min_points: int = 3
) -> SpatialDescriptor | None:
    """The descriptor of one object; None when fewer than ``min_points`` pixels have valid depth."""
    pts = mask_points(frame, mask, min_depth, max_depth)
    if pts.shape[0] < min_points:
        return None
    q25, c, q75 = np.percentile(pts, [25, 50, 75], axis=0)
    x, y, z = (float(v) for v in c)
    return SpatialDescriptor(
        centroid=c,
        distance=float(np.linalg.norm(c)),
        azimuth=math.atan2(x, z),
        elevation=math.atan2(-y, math.hypot(x, z)),
        spread=(q75 - q25) / 2.0,
        num_points=int(pts.shape[0]),
    )
