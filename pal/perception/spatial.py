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
- ``num_points``: valid depth pixels behind the estimate (a mask of more than 1500 pixels is
  sampled on a regular grid of about 1500).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask
from pal.perception.quantiles import quantiles

__all__ = ["SpatialDescriptor", "lift", "mask_points", "spatial_descriptor"]


def mask_points(
    frame: RGBDFrame,
    mask: Mask,
    min_depth: float = 0.1,
    max_depth: float = 5.0,
    max_points: int | None = None,
) -> np.ndarray:
    """(M, 3) camera-frame points of the mask pixels with depth in [min_depth, max_depth], metres.

    With ``max_points``, a mask of more pixels is sampled on a regular pixel grid (every s-th
    row and column, ``s = ceil(sqrt(area / max_points))``), so statistics of large masks cost
    what those of small ones do.
    """
    x0, y0, x1, y1 = mask.bbox
    step = (
        1 if max_points is None or mask.area <= max_points else int(np.ceil(np.sqrt(mask.area / max_points)))
    )
    z = frame.depth[y0:y1:step, x0:x1:step]
    sel = mask.crop[::step, ::step] & (z >= min_depth) & (z <= max_depth)
    vs, us = np.nonzero(sel)
    return backproject(us * step + x0, vs * step + y0, z[vs, us], frame.K)


def lift(
    points: np.ndarray,
    depth: np.ndarray,
    origin: tuple[int, int],
    K: np.ndarray,
    min_depth: float,
    max_depth: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Lift pixels to 3-D with the depth at their nearest pixel.

    Args:
        points: (N, 2) full-frame pixel coordinates.
        depth: (h, w) float32 metres, the frame's depth or a crop of it.
        origin: (x0, y0) of ``depth`` in the full frame.
        K: (3, 3) full-frame intrinsics.
        min_depth: smallest depth accepted, metres.
        max_depth: largest depth accepted, metres.

    Returns:
        ((N, 3) camera-frame points, zero where invalid; (N,) bool valid).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    u = np.rint(pts[:, 0]).astype(np.int64) - origin[0]
    v = np.rint(pts[:, 1]).astype(np.int64) - origin[1]
    inside = (u >= 0) & (v >= 0) & (u < depth.shape[1]) & (v < depth.shape[0])
    z = np.zeros(len(pts))
    z[inside] = depth[v[inside], u[inside]]
    valid = inside & (z >= min_depth) & (z <= max_depth)
    out = np.zeros((len(pts), 3))
    if valid.any():
        out[valid] = backproject(pts[valid, 0], pts[valid, 1], z[valid], K)
    return out, valid


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
    pts = mask_points(frame, mask, min_depth, max_depth, max_points=1500)
    if pts.shape[0] < min_points:
        return None
    q25, c, q75 = quantiles(pts, (25.0, 50.0, 75.0))
    x, y, z = (float(v) for v in c)
    return SpatialDescriptor(
        centroid=c,
        distance=float(np.linalg.norm(c)),
        azimuth=math.atan2(x, z),
        elevation=math.atan2(-y, math.hypot(x, z)),
        spread=(q75 - q25) / 2.0,
        num_points=int(pts.shape[0]),
    )
