"""Layouts of the cluttered tabletop: boxes and cylinders of many sizes, placed touching each other.

Every object stands upright on the table (table frame: z up, origin at the centre of the top).
Its footprint is a convex polygon in the table plane (a cylinder's is the circumscribed
48-gon, so neighbours may stand up to 0.1 mm apart, never inside each other). Objects are
placed in clusters: a cluster's first object at a random free spot, every further object
slid towards a random member of the cluster from a random direction until it touches the first
object in its way (the smallest distance along the ray at which the footprints do not overlap,
found to ``precision`` metres). So every object of a cluster touches at least one other.

The kinds mimic the objects of a kitchen or office table (YCB-like):

===============  ======================================  ==============================
kind             footprint                               height
===============  ======================================  ==============================
``box``          4-12 x 4-16 cm                          6-20 cm
``can``          radius 3-5 cm                           7-14 cm
``short_can``    radius 3.5-5.5 cm (a tuna can)          2.5-4 cm
``short_box``    6-12 x 6-12 cm                          2.5-4.5 cm
``flat``         10-18 x 3-6 cm (scissors, a remote)     1.5-2.5 cm
===============  ======================================  ==============================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pal.checks import check_float, check_int

__all__ = ["KINDS", "ClutterObject", "LayoutConfig", "footprint", "layout", "overlap"]

#: kind -> (shape, ((low, high) of the x size, y size, height), metres); a cylinder's x size is its diameter.
KINDS: dict[str, tuple[str, tuple[tuple[float, float], ...]]] = {
    "box": ("box", ((0.04, 0.12), (0.04, 0.16), (0.06, 0.20))),
    "can": ("cylinder", ((0.06, 0.10), (0.0, 0.0), (0.07, 0.14))),
    "short_can": ("cylinder", ((0.07, 0.11), (0.0, 0.0), (0.025, 0.04))),
    "short_box": ("box", ((0.06, 0.12), (0.06, 0.12), (0.025, 0.045))),
    "flat": ("box", ((0.10, 0.18), (0.03, 0.06), (0.015, 0.025))),
}
_KIND_NAMES = tuple(KINDS)


@dataclass(frozen=True)
class ClutterObject:
    """One upright object on the table.

    Attributes:
        kind: a key of :data:`KINDS`.
        shape: ``"box"`` or ``"cylinder"``.
        size: (x, y, height) full extents, metres (a cylinder: (diameter, diameter, height)).
        xy: (x, y) of its centre on the table, metres.
        yaw: rotation about the table's z axis, rad.
        rgba: base colour, each in [0, 1].
        texture: seed of its printed texture, or None for one plain colour.
        label: ground-truth instance id (1, 2, ... in placement order).
    """

    kind: str
    shape: str
    size: tuple[float, float, float]
    xy: tuple[float, float]
    yaw: float
    rgba: tuple[float, float, float, float]
    texture: int | None
    label: int


@dataclass(frozen=True)
class LayoutConfig:
    """How layouts are drawn (module docstring).

    Attributes:
        objects: (fewest, most) objects per scene.
        clusters: (fewest, most) clusters of touching objects.
        kind_weights: relative frequency of each kind of :data:`KINDS`, in its order.
        textured: probability that an object is printed (else one plain colour).
        area: (half width x, half depth y) of the table region the footprints stay in, metres.
        precision: contact distance found to this precision, metres.
    """

    objects: tuple[int, int] = (6, 9)
    clusters: tuple[int, int] = (1, 2)
    kind_weights: tuple[float, ...] = (0.3, 0.25, 0.15, 0.15, 0.15)
    textured: float = 0.5
    area: tuple[float, float] = (0.22, 0.16)
    precision: float = 1e-4

    def __post_init__(self) -> None:
        for name in ("objects", "clusters"):
            lo, hi = getattr(self, name)
            check_int(f"{name}[0]", lo)
            check_int(f"{name}[1]", hi, minimum=lo)
        if len(self.kind_weights) != len(KINDS) or min(self.kind_weights) < 0 or sum(self.kind_weights) <= 0:
            raise ValueError(
                f"kind_weights is {self.kind_weights}, expected {len(KINDS)} non-negative weights "
                f"(for {list(KINDS)}) with a positive sum"
            )
        check_float("textured", self.textured, 0.0, 1.0)
        for v in self.area:
            check_float("area", v, 0.0, open_low=True)
        check_float("precision", self.precision, 0.0, 0.01, open_low=True)


def footprint(obj: ClutterObject, xy: tuple[float, float] | np.ndarray | None = None) -> np.ndarray:
    """(M, 2) counter-clockwise vertices of the object's footprint on the table, metres.

    Args:
        obj: the object.
        xy: its centre, (2,) metres (default: ``obj.xy``).
    """
    c = np.asarray(obj.xy if xy is None else xy, dtype=np.float64)
    if obj.shape == "box":
        hx, hy = obj.size[0] / 2.0, obj.size[1] / 2.0
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    else:
        n = 48
        r = obj.size[0] / 2.0 / math.cos(math.pi / n)  # circumscribed: never inside a neighbour
        a = np.arange(n) * (2.0 * math.pi / n)
        local = r * np.stack([np.cos(a), np.sin(a)], axis=1)
    cy, sy = math.cos(obj.yaw), math.sin(obj.yaw)
    return local @ np.array([[cy, sy], [-sy, cy]]) + c


def _axes(poly: np.ndarray) -> np.ndarray:
    edges = np.concatenate([poly[1:], poly[:1]]) - poly
    return edges[:, ::-1] * np.array([-1.0, 1.0])


def overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two convex polygons (M, 2) and (N, 2) overlap with positive area (separating axes)."""
    for axes in (_axes(a), _axes(b)):
        pa, pb = a @ axes.T, b @ axes.T
        if np.any((pa.max(axis=0) <= pb.min(axis=0)) | (pb.max(axis=0) <= pa.min(axis=0))):
            return False
    return True


def _draw(kind: str, rng: np.random.Generator, label: int, textured: float) -> ClutterObject:
    shape, ranges = KINDS[kind]
    sx, sy, h = (float(rng.uniform(lo, hi)) for lo, hi in ranges)
    if shape == "cylinder":
        sy = sx
    hue = float(rng.uniform(0.0, 1.0))
    rgb = np.clip(np.abs((hue * 6.0 + np.array([0.0, 4.0, 2.0])) % 6.0 - 3.0) - 1.0, 0.0, 1.0)
    value, sat = float(rng.uniform(0.45, 0.95)), float(rng.uniform(0.4, 0.9))
    rgb = value * (1.0 - sat + sat * rgb)
    texture = int(rng.integers(2**31)) if rng.random() < textured else None
    return ClutterObject(
        kind, shape, (sx, sy, h), (0.0, 0.0), float(rng.uniform(0.0, math.pi)),
        (float(rgb[0]), float(rgb[1]), float(rgb[2]), 1.0), texture, label,
    )  # fmt: skip


def _inside(poly: np.ndarray, area: tuple[float, float]) -> bool:
    return bool(np.all(np.abs(poly[:, 0]) <= area[0]) and np.all(np.abs(poly[:, 1]) <= area[1]))


def _free(obj: ClutterObject, xy: np.ndarray, placed: list[np.ndarray]) -> bool:
    """Whether the object's footprint at ``xy`` overlaps none of the placed footprints."""
    if not placed:
        return True
    reach = float(np.hypot(obj.size[0], obj.size[1])) / 2.0 + 1e-3
    centres = np.array([q[0] for q in placed])  # footprints carry their bounding circle first
    radii = np.array([q[1, 0] for q in placed])
    close = np.flatnonzero(np.hypot(*(centres - xy).T) <= reach + radii)
    if close.size == 0:
        return True
    poly = footprint(obj, xy)
    return not any(overlap(poly, placed[i][2:]) for i in close)


def _with_circle(poly: np.ndarray) -> np.ndarray:
    """``poly`` (M, 2) behind two rows: its centre and (its bounding radius, 0)."""
    centre = poly.mean(axis=0)
    return np.vstack([centre, [float(np.max(np.hypot(*(poly - centre).T))), 0.0], poly])


def _slide(
    obj: ClutterObject, anchor: np.ndarray, direction: np.ndarray, placed: list[np.ndarray], precision: float
) -> np.ndarray | None:
    """The first centre along ``anchor + t direction`` (t >= 0) whose footprint overlaps nothing placed."""

    def free(t: float) -> bool:
        return _free(obj, anchor + t * direction, placed)

    step = 0.01
    reach = 0.5
    t = 0.0
    while not free(t):
        t += step
        if t > reach:
            return None
    lo, hi = max(t - step, 0.0), t
    if lo == hi:
        return anchor + t * direction
    while hi - lo > precision:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if free(mid) else (mid, hi)
    return anchor + hi * direction


def layout(seed: int, config: LayoutConfig | None = None) -> tuple[ClutterObject, ...]:
    """Draw one cluttered layout (module docstring); the same seed gives the same layout.

    Returns:
        the objects, labelled 1, 2, ... in placement order.
    """
    cfg = config or LayoutConfig()
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xC1A7]))
    n = int(rng.integers(cfg.objects[0], cfg.objects[1] + 1))
    k = int(rng.integers(cfg.clusters[0], min(cfg.clusters[1], n) + 1))
    weights = np.asarray(cfg.kind_weights, dtype=np.float64) / sum(cfg.kind_weights)
    cluster_of = np.sort(np.concatenate([np.arange(k), rng.integers(0, k, n - k)]))
    objects: list[ClutterObject] = []
    polys: list[np.ndarray] = []
    members: dict[int, list[int]] = {}
    for i in range(n):
        kind = _KIND_NAMES[int(rng.choice(len(weights), p=weights))]
        obj = _draw(kind, rng, i + 1, cfg.textured)
        group = members.setdefault(int(cluster_of[i]), [])
        for _ in range(200):
            if group:
                anchor = np.asarray(objects[group[int(rng.integers(len(group)))]].xy)
                a = float(rng.uniform(0.0, 2.0 * math.pi))
                xy = _slide(obj, anchor, np.array([math.cos(a), math.sin(a)]), polys, cfg.precision)
            else:
                xy = rng.uniform(-1.0, 1.0, 2) * np.asarray(cfg.area) * 0.7
                if not _free(obj, xy, polys):
                    xy = None
            if xy is not None and _inside(footprint(obj, xy), cfg.area):
                break
        else:
            continue  # no room left for this object: the scene holds fewer
        obj = replace(obj, xy=(float(xy[0]), float(xy[1])), label=len(objects) + 1)
        group.append(len(objects))
        objects.append(obj)
        polys.append(_with_circle(footprint(obj)))
    return tuple(objects)
