"""Grounded spatial predicates in the support-plane frame: near, on, left-of, in-front-of, touching.

These are the grounding maps of the language-of-thought queries: each takes two objects and
returns a grade in [0, 1] computed from their positions, extents and uncertainty, never a
hard threshold.

**The support-plane frame.** Origin at the foot of the camera on the support plane, z up
(the plane's normal), x the camera's x axis projected on the plane (to the right in the image),
y = z × x (away from the camera). So *left of* and *in front of* read as a viewer says them.
Without a support plane the camera frame is used with z = -y_cam (up in the image).

**Object geometry** (:class:`ObjectGeometry`, from the mask's points with depth): the median
position, the footprint box (2nd-98th percentiles of x and y), the bottom and top heights
(2nd and 98th percentiles of z), a sample of surface points for gaps, and ``sigma``, the
position uncertainty ``sqrt(sigma_z(z)² + floor²)`` (depth noise and segmentation).

**Predicates** (Phi is the standard normal CDF):

- ``left_of(a, b) = Phi((x_b - x_a) / s)``, ``s = sqrt(sigma_a² + sigma_b² + ((w_a + w_b) / 4)²)``
  with ``w`` the footprint widths: two side-by-side objects grade about 0.98, two objects one
  behind the other 0.5;
- ``in_front_of(a, b) = Phi((y_b - y_a) / s)`` on the depths ``d`` of the footprints alike;
- ``near(a, b) = Phi((d - gap) / (0.25 d + sqrt(sigma_a² + sigma_b²)))``, ``gap`` the metric
  distance between the objects' 3-D boxes (footprint and height span) and ``d = near_distance``
  (0.1 m by default): 0.5 at a 10 cm gap, 0.98 at 4 cm, under 0.01 at 20 cm, whatever the
  objects' sizes (a wall is not near everything);
- ``on(a, b)``: a's bottom at b's top, ``Phi((tolerance - |bottom_a - top_b|) / s)`` times the
  fraction of a's footprint over b's, zero when a is not above b; ``on_support(a)`` is the
  same against the plane (height 0), times the share of the object's lowest image edge that is
  visible, not hidden behind a nearer surface (``bottom_visible``): an occluded bottom is not
  evidence of contact;
- ``touching(a, b) = Phi((touch_gap - gap3d) / s)``, ``gap3d`` the smallest distance between
  their rim points (a k-d tree), ``s`` their depth noise plus 5 mm. Depth holes at a
  boundary do not matter: the gap is measured between the points both objects do have.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.special import ndtr

from pal.checks import check_float
from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask
from pal.perception.noise import DepthNoise
from pal.perception.plane import Plane
from pal.perception.quantiles import median, quantiles
from pal.perception.spatial import mask_points
from pal.perception.support import plane_basis

__all__ = [
    "PREDICATES",
    "GroundingConfig",
    "ObjectGeometry",
    "bottom_visibility",
    "grade",
    "object_geometry",
    "on_support",
    "support_frame",
]

#: The graded predicates, in the order of :func:`grade`'s vector.
PREDICATES: tuple[str, ...] = ("near", "on", "left_of", "in_front_of", "touching")
#: The least depth step, m, by which a surface under an object's lowest edge hides that edge.
OCCLUDER_MARGIN = 0.03


@dataclass(frozen=True)
class GroundingConfig:
    """Scales of the graded predicates (module docstring), metres.

    Attributes:
        noise: the depth sensor's noise model.
        position_floor: position uncertainty floor (segmentation), metres.
        near_distance: objects whose 3-D boxes are within this gap are near, m.
        on_tolerance: height mismatch of a resting contact, metres.
        touch_gap: surfaces closer than this touch.
        surface_points: rim points kept per object for gaps.
    """

    noise: DepthNoise = DepthNoise()
    position_floor: float = 0.01
    near_distance: float = 0.1
    on_tolerance: float = 0.03
    touch_gap: float = 0.015
    surface_points: int = 150

    def __post_init__(self) -> None:
        for name in ("position_floor", "near_distance", "on_tolerance", "touch_gap"):
            check_float(name, getattr(self, name), 0.0, open_low=True)
        if self.surface_points < 8:
            raise ValueError(f"surface_points is {self.surface_points}, expected >= 8")


def support_frame(plane: Plane | None) -> np.ndarray:
    """(4, 4) ``support_from_camera``: camera coordinates to the support-plane frame (module docstring)."""
    T = np.eye(4)
    if plane is None:
        T[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
        return T
    n = plane.normal
    e1, e2 = plane_basis(n)
    if e1 @ np.array([1.0, 0.0, 0.0]) < 0:  # keep x to the right of the image
        e1, e2 = -e1, -e2
    e2 = np.cross(n, e1)
    R = np.stack([e1, e2, n])
    origin = -plane.offset * n
    T[:3, :3], T[:3, 3] = R, -R @ origin
    return T


@dataclass(frozen=True, eq=False)
class ObjectGeometry:
    """An object in the support-plane frame (module docstring), metres.

    Attributes:
        position: (3,) median of its points.
        lo: (2,) footprint box minimum (x, y).
        hi: (2,) footprint box maximum (x, y).
        bottom: height of its lowest points above the plane.
        top: height of its highest points.
        sigma: position uncertainty.
        surface: (M, 3) points of its rim (the mask's boundary band), for gaps.
        bottom_visible: share in [0, 1] of the mask's lowest image edge that is seen, not
            hidden behind a nearer surface or cut by the image border (:func:`bottom_visibility`).
    """

    position: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    bottom: float
    top: float
    sigma: float
    surface: np.ndarray
    bottom_visible: float = 1.0

    @property
    def extent(self) -> float:
        """The largest side of the object's box, metres."""
        return float(max(np.max(self.hi - self.lo), self.top - self.bottom))

    def to_dict(self) -> dict:
        """JSON-compatible fields (without the surface sample)."""
        return {
            "position": [float(v) for v in self.position],
            "footprint": [[float(v) for v in self.lo], [float(v) for v in self.hi]],
            "bottom": self.bottom,
            "top": self.top,
            "sigma": self.sigma,
            "bottom_visible": self.bottom_visible,
        }


def object_geometry(
    frame: RGBDFrame,
    mask: Mask,
    support_from_camera: np.ndarray,
    config: GroundingConfig,
    max_depth: float = 10.0,
) -> ObjectGeometry | None:
    """The geometry of one object; None with fewer than 3 points with depth."""
    pts = mask_points(frame, mask, 0.05, max_depth, max_points=500)
    if pts.shape[0] < 3:
        return None
    z_med = float(median(pts[:, 2]))
    R, t = support_from_camera[:3, :3], support_from_camera[:3, 3]
    q = pts @ R.T + t
    lo, mid, hi = quantiles(q, (2.0, 50.0, 98.0))
    sigma = math.hypot(float(config.noise.sigma(z_med)), config.position_floor)
    rim = _rim_points(frame, mask, max_depth, config.surface_points)
    surface = q if rim.shape[0] < 3 else rim @ R.T + t
    visible = bottom_visibility(frame.depth, mask, max(3.0 * sigma, OCCLUDER_MARGIN))
    return ObjectGeometry(mid, lo[:2], hi[:2], float(lo[2]), float(hi[2]), sigma, surface, visible)


def bottom_visibility(depth: np.ndarray, mask: Mask, margin: float, below: int = 4) -> float:
    """Share of a mask's columns whose lowest pixel is seen with nothing nearer just below it.

    For each column of the mask with depth at its lowest pixel (z), the ``below`` pixels under
    it are read: the column is hidden when their median valid depth is nearer than
    ``z - margin`` (an occluder in front, e.g. a table edge before a chair's legs) or when the
    mask reaches the image's lower border. A support seen beside the object's foot is at about
    z, so a resting object's edge counts as seen.

    Args:
        depth: (H, W) metres, 0 = invalid.
        mask: the object's mask.
        margin: how much nearer a surface must be to hide the edge, m.
        below: rows read under the edge, pixels.

    Returns:
        the share in [0, 1]; 1.0 when no column has depth at its lowest pixel (nothing to judge).
    """
    x0, y0 = mask.bbox[0], mask.bbox[1]
    h = mask.crop.shape[0]
    cols = np.flatnonzero(mask.crop.any(axis=0))
    last = h - 1 - np.argmax(mask.crop[::-1, cols], axis=0)
    ys, xs = y0 + last, x0 + cols
    z = depth[ys, xs]
    has = z > 0
    if not has.any():
        return 1.0
    ys, xs, z = ys[has], xs[has], z[has]
    height = depth.shape[0]
    rows = ys[:, None] + np.arange(1, below + 1)[None, :]
    inside = rows < height
    under = np.where(inside, depth[np.minimum(rows, height - 1), xs[:, None]], 0.0)
    under = np.sort(np.where(under > 0, under, np.inf), axis=1)  # readings first, holes (inf) last
    count = np.isfinite(under).sum(axis=1)
    seen = count > 0
    near = np.full(z.shape, np.inf)
    rows, c = np.flatnonzero(seen), count[seen]
    near[seen] = 0.5 * (under[rows, (c - 1) // 2] + under[rows, c // 2])  # the median of the readings
    hidden = (ys + 1 >= height) | (near < z - margin)
    return float(1.0 - hidden.mean())


def _rim_points(frame: RGBDFrame, mask: Mask, max_depth: float, limit: int) -> np.ndarray:
    """Camera-frame points of the mask's rim (pixels within 2 of its boundary) with depth."""
    crop = mask.crop.view(np.uint8)
    inner = cv2.erode(crop, np.ones((5, 5), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    vs, us = np.nonzero(crop & ~inner.view(bool))
    x0, y0 = mask.bbox[0], mask.bbox[1]
    z = frame.depth[vs + y0, us + x0]
    ok = (z > 0.05) & (z < max_depth)
    vs, us, z = vs[ok], us[ok], z[ok]
    if vs.size > limit:
        keep = np.linspace(0, vs.size - 1, limit).astype(np.int64)
        vs, us, z = vs[keep], us[keep], z[keep]
    return backproject(us + x0, vs + y0, z, frame.K)


def box_gap(a: ObjectGeometry, b: ObjectGeometry) -> float:
    """Distance between the two objects' footprint boxes (0 when they overlap), metres."""
    d = np.maximum(0.0, np.maximum(a.lo - b.hi, b.lo - a.hi))
    return float(np.linalg.norm(d))


def _overlap(a: ObjectGeometry, b: ObjectGeometry) -> float:
    """Fraction of a's footprint box over b's."""
    inter = np.clip(np.minimum(a.hi, b.hi) - np.maximum(a.lo, b.lo), 0.0, None)
    area = float(np.prod(np.maximum(a.hi - a.lo, 1e-3)))
    return float(np.prod(inter)) / area


def on_support(a: ObjectGeometry, config: GroundingConfig) -> float:
    """Grade of ``a`` resting on the support plane: its bottom at height 0, times ``bottom_visible``."""
    s = config.on_tolerance / 2.0 + a.sigma
    return float(ndtr((config.on_tolerance - abs(a.bottom)) / s)) * a.bottom_visible


def surface_gap(a: ObjectGeometry, b: ObjectGeometry) -> float:
    """Smallest distance between the two objects' surface points, metres (a k-d tree)."""
    return float(cKDTree(a.surface).query(b.surface, k=1)[0].min())


def _phi(x: float) -> float:
    """The standard normal CDF of a scalar (``scipy.special.ndtr`` without the ufunc overhead)."""
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


def grade(
    a: ObjectGeometry, b: ObjectGeometry, config: GroundingConfig, gap: float | None = None
) -> dict[str, float]:
    """The graded predicates of the ordered pair (a, b), each in [0, 1] (module docstring).

    Args:
        a: first object's geometry.
        b: second object's geometry.
        config: the predicates' scales.
        gap: :func:`surface_gap` of the pair when already computed (it is symmetric).
    """
    sab = math.hypot(a.sigma, b.sigma)
    (ax0, ay0), (ax1, ay1) = a.lo.tolist(), a.hi.tolist()
    (bx0, by0), (bx1, by1) = b.lo.tolist(), b.hi.tolist()
    pa, pb = a.position.tolist(), b.position.tolist()
    s_x = math.sqrt(sab**2 + ((ax1 - ax0 + bx1 - bx0) / 4.0) ** 2)
    s_y = math.sqrt(sab**2 + ((ay1 - ay0 + by1 - by0) / 4.0) ** 2)
    left = _phi((pb[0] - pa[0]) / s_x)
    front = _phi((pb[1] - pa[1]) / s_y)
    d = config.near_distance
    vertical = max(0.0, a.bottom - b.top, b.bottom - a.top)
    box = math.sqrt(max(0.0, ax0 - bx1, bx0 - ax1) ** 2 + max(0.0, ay0 - by1, by0 - ay1) ** 2 + vertical**2)
    near = _phi((d - box) / (0.25 * d + sab))
    s_on = config.on_tolerance / 2.0 + sab
    above = pa[2] > pb[2]
    on = _phi((config.on_tolerance - abs(a.bottom - b.top)) / s_on) * _overlap(a, b) if above else 0.0
    gap3d = surface_gap(a, b) if gap is None else gap
    touching = _phi((config.touch_gap - gap3d) / (sab * 0.5 + 0.005))
    return {"near": near, "on": min(on, 1.0), "left_of": left, "in_front_of": front, "touching": touching}
