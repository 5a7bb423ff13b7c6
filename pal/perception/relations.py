"""Scene composition parsing SCP (Eq. 4.21-4.22): pairwise relations, a scene graph and a scene vector.

For every ordered pair (i, j) of objects:

- **relative position**: ``displacement = μ_j - μ_i`` (3-D centroids, metres, camera frame),
  ``distance = |displacement|``, ``direction = displacement / distance``;
- **topology** (symmetric, from masks and depth), the first that holds of:

  - ``contained``: one mask lies (>= ``contain_fraction``) inside the other's pixels or filled
    convex hull (e.g. an object in a bowl); ``container`` names the outer object;
  - ``overlapping``: the masks share pixels, or one covers >= ``overlap_fraction`` of the other's
    convex hull (e.g. partial occlusion);
  - ``touching``: the masks are within ``touch_px`` pixels and the closest back-projected
    points across that boundary are within ``touch_gap`` metres in 3-D (so objects merely
    adjacent in the image but apart in depth are not touching);
  - ``disjoint`` otherwise; None when either object has no mask this frame;

- **kinematic synchrony**: over the last ``sync_window_s`` seconds of centroid measurements
  shared by both objects, the uncentred correlation of their finite-difference velocities
  ``Σ v_i·v_j / sqrt(Σ|v_i|² Σ|v_j|²)`` in [-1, 1] (1: moving together). None when both move
  slower than ``min_speed`` (undefined) or fewer than 3 shared samples; 0.0 when only one moves.

The relations export as a networkx ``DiGraph`` (object nodes, relation edges) and as a
fixed-length vector (:func:`scene_vector_names` documents its layout; missing values are 0 with
presence flags, never NaN).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import networkx as nx
import numpy as np

from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask, intersection_area
from pal.perception.spatial import SpatialDescriptor

__all__ = [
    "TOPOLOGY",
    "PairRelation",
    "RelationConfig",
    "SceneRelations",
    "scene_relations",
    "scene_vector_names",
    "synchrony",
    "topology",
]

TOPOLOGY: tuple[str, ...] = ("disjoint", "touching", "overlapping", "contained")
_OBJ_FIELDS = ("present", "cx", "cy", "cz", "distance", "azimuth", "elevation")
_PAIR_FIELDS = (
    "present",
    "dx",
    "dy",
    "dz",
    "distance",
    *(f"topo_{t}" for t in TOPOLOGY),
    "synchrony",
    "synchrony_defined",
)


@dataclass(frozen=True)
class RelationConfig:
    """Relation thresholds (module docstring)."""

    touch_px: int = 2
    touch_gap: float = 0.015
    contain_fraction: float = 0.95
    overlap_fraction: float = 0.05
    sync_window_s: float = 1.0
    min_speed: float = 0.02
    max_objects: int = 8

    def __post_init__(self) -> None:
        if self.touch_px < 1 or not self.touch_gap > 0 or not self.sync_window_s > 0 or self.min_speed < 0:
            raise ValueError(
                f"touch_px >= 1, touch_gap > 0, sync_window_s > 0 and min_speed >= 0 are required; got {self}"
            )
        if not 0 < self.overlap_fraction < self.contain_fraction <= 1 or self.max_objects < 1:
            raise ValueError(
                f"need 0 < overlap_fraction < contain_fraction <= 1 and max_objects >= 1; got {self}"
            )


@dataclass(frozen=True, eq=False)
class PairRelation:
    """Relations from object ``a`` to object ``b`` (None where evidence is missing)."""

    a: int
    b: int
    displacement: np.ndarray | None
    distance: float | None
    direction: np.ndarray | None
    topology: str | None
    container: int | None
    synchrony: float | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields (arrays as lists, None kept)."""
        return {
            "a": self.a,
            "b": self.b,
            "displacement": None if self.displacement is None else self.displacement.tolist(),
            "distance": self.distance,
            "direction": None if self.direction is None else self.direction.tolist(),
            "topology": self.topology,
            "container": self.container,
            "synchrony": self.synchrony,
        }


def _hull_fill(m: np.ndarray) -> np.ndarray:
    pts = cv2.findNonZero(m.view(np.uint8))
    out = np.zeros(m.shape, dtype=np.uint8)
    cv2.fillConvexPoly(out, cv2.convexHull(pts), 1)
    return out.view(bool)


def topology(
    frame: RGBDFrame, a: Mask, b: Mask, config: RelationConfig | None = None, ids: tuple[int, int] = (0, 1)
) -> tuple[str, int | None]:
    """Topological relation of two masks: (label in :data:`TOPOLOGY`, container id or None)."""
    cfg = config or RelationConfig()
    inter = intersection_area(a, b)
    small, big = (a, b) if a.area <= b.area else (b, a)
    big_id = ids[1] if big is b else ids[0]
    if inter >= cfg.contain_fraction * small.area:
        return "contained", big_id
    r = cfg.touch_px
    ax0, ay0, ax1, ay1 = a.bbox
    bx0, by0, bx1, by1 = b.bbox
    if ax0 >= bx1 + r or bx0 >= ax1 + r or ay0 >= by1 + r or by0 >= ay1 + r:
        return "disjoint", None  # boxes (and so masks and hulls) too far apart to meet
    x0 = max(0, min(a.bbox[0], b.bbox[0]) - r)
    y0 = max(0, min(a.bbox[1], b.bbox[1]) - r)
    x1 = min(frame.width, max(a.bbox[2], b.bbox[2]) + r)
    y1 = min(frame.height, max(a.bbox[3], b.bbox[3]) + r)
    ra, rb = a.region(x0, y0, x1, y1), b.region(x0, y0, x1, y1)
    in_b = np.count_nonzero(ra & _hull_fill(rb)) / a.area
    in_a = np.count_nonzero(rb & _hull_fill(ra)) / b.area
    if in_b >= cfg.contain_fraction and in_b >= in_a:
        return "contained", ids[1]
    if in_a >= cfg.contain_fraction:
        return "contained", ids[0]
    if inter > 0 or max(in_a, in_b) >= cfg.overlap_fraction:
        return "overlapping", None
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    near_a = ra & cv2.dilate(rb.view(np.uint8), kernel).view(bool)
    near_b = rb & cv2.dilate(ra.view(np.uint8), kernel).view(bool)
    if not near_a.any() or not near_b.any():
        return "disjoint", None
    depth = frame.depth[y0:y1, x0:x1]

    def points(sel: np.ndarray) -> np.ndarray:
        vs, us = np.nonzero(sel & (depth > 0))
        if vs.size > 200:
            keep = np.linspace(0, vs.size - 1, 200).astype(np.int64)
            vs, us = vs[keep], us[keep]
        return backproject(us + x0, vs + y0, depth[vs, us], frame.K)

    pa, pb = points(near_a), points(near_b)
    if len(pa) == 0 or len(pb) == 0:
        return "disjoint", None
    gap = float(np.sqrt(((pa[:, None, :] - pb[None, :, :]) ** 2).sum(axis=2)).min())
    return ("touching" if gap <= cfg.touch_gap else "disjoint"), None


def synchrony(
    history_a: tuple[np.ndarray, np.ndarray],
    history_b: tuple[np.ndarray, np.ndarray],
    now: float,
    config: RelationConfig | None = None,
) -> float | None:
    """Velocity correlation of two (timestamps (N,), positions (N, 3)) histories (module docstring)."""
    cfg = config or RelationConfig()
    ta, pa = history_a
    tb, pb = history_b
    common, ia, ib = np.intersect1d(ta, tb, assume_unique=True, return_indices=True)
    recent = common >= now - cfg.sync_window_s
    common, ia, ib = common[recent], ia[recent], ib[recent]
    if common.size < 3:
        return None
    dt = np.diff(common)[:, None]
    va = np.diff(pa[ia], axis=0) / dt
    vb = np.diff(pb[ib], axis=0) / dt
    sa, sb = np.linalg.norm(va, axis=1).mean(), np.linalg.norm(vb, axis=1).mean()
    moving_a, moving_b = sa >= cfg.min_speed, sb >= cfg.min_speed
    if not moving_a and not moving_b:
        return None
    if not (moving_a and moving_b):
        return 0.0
    return float(np.sum(va * vb) / np.sqrt(np.sum(va * va) * np.sum(vb * vb)))


def scene_vector_names(max_objects: int) -> list[str]:
    """Names of the :meth:`SceneRelations.vector` entries, in order.

    Per object slot k (objects sorted by id)
    ``obj{k}.{present,cx,cy,cz,distance,azimuth,elevation}``, then per slot pair k < l
    ``pair{k}_{l}.{present,dx,dy,dz,distance,topo_*(4),synchrony,synchrony_defined}``.
    """
    names = [f"obj{k}.{f}" for k in range(max_objects) for f in _OBJ_FIELDS]
    names += [
        f"pair{k}_{m}.{f}"
        for k in range(max_objects)
        for m in range(k + 1, max_objects)
        for f in _PAIR_FIELDS
    ]
    return names


@dataclass(frozen=True, eq=False)
class SceneRelations:
    """The relational layer of one frame.

    Attributes:
        objects: ``{obj_id: spatial descriptor or None}`` (sorted by id).
        visible: ids with a mask this frame.
        pairs: one :class:`PairRelation` per ordered pair (a != b).
    """

    objects: dict[int, SpatialDescriptor | None]
    visible: frozenset[int]
    pairs: tuple[PairRelation, ...]

    def graph(self) -> nx.DiGraph:
        """The scene graph of this frame.

        Nodes are object ids (attributes ``visible``, ``spatial`` dict or None); edges (a, b)
        carry the pair's relation fields.
        """
        g = nx.DiGraph()
        for oid, sp in self.objects.items():
            g.add_node(oid, visible=oid in self.visible, spatial=None if sp is None else sp.to_dict())
        for p in self.pairs:
            attrs = p.to_dict()
            del attrs["a"], attrs["b"]
            g.add_edge(p.a, p.b, **attrs)
        return g

    def vector(self, max_objects: int = 8) -> np.ndarray:
        """Fixed-length vector (len ``len(scene_vector_names(max_objects))``), no NaN.

        Objects fill slots in increasing id order; objects beyond ``max_objects`` are left out.
        """
        ids = sorted(self.objects)[:max_objects]
        slot = {oid: k for k, oid in enumerate(ids)}
        n_obj, n_pair = len(_OBJ_FIELDS), len(_PAIR_FIELDS)
        obj = np.zeros((max_objects, n_obj))
        for oid in ids:
            sp = self.objects[oid]
            if sp is not None:
                obj[slot[oid]] = [1.0, *sp.centroid, sp.distance, sp.azimuth, sp.elevation]
        pairs = {(k, m): np.zeros(n_pair) for k in range(max_objects) for m in range(k + 1, max_objects)}
        for p in self.pairs:
            if p.a in slot and p.b in slot and slot[p.a] < slot[p.b]:
                row = pairs[(slot[p.a], slot[p.b])]
                row[0] = 1.0
                if p.displacement is not None and p.distance is not None:
                    row[1:4], row[4] = p.displacement, p.distance
                if p.topology is not None:
                    row[5 + TOPOLOGY.index(p.topology)] = 1.0
                if p.synchrony is not None:
                    row[9], row[10] = p.synchrony, 1.0
        return np.concatenate([obj.ravel(), *[pairs[key] for key in sorted(pairs)]])

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible layer: objects (keyed by str id), sorted visible ids and pairs."""
        return {
            "objects": {str(k): None if v is None else v.to_dict() for k, v in self.objects.items()},
            "visible": sorted(self.visible),
            "pairs": [p.to_dict() for p in self.pairs],
        }


def scene_relations(
    frame: RGBDFrame,
    spatial: Mapping[int, SpatialDescriptor | None],
    masks: Mapping[int, Mask],
    histories: Mapping[int, tuple[np.ndarray, np.ndarray]],
    config: RelationConfig | None = None,
    ids: Sequence[int] | None = None,
) -> SceneRelations:
    """SCP (Eq. 4.22) over the given objects.

    Args:
        frame: the current frame (depth for topology).
        spatial: per object id, its spatial descriptor (None if unknown).
        masks: masks of the objects visible this frame.
        histories: per object id, recent (timestamps (N,), centroids (N, 3)).
        config: relation settings (default: ``RelationConfig()``).
        ids: objects to relate (default: the keys of ``spatial``).
    """
    cfg = config or RelationConfig()
    ids = sorted(spatial) if ids is None else sorted(ids)
    empty = (np.zeros(0), np.zeros((0, 3)))
    topo: dict[tuple[int, int], tuple[str | None, int | None]] = {}
    sync: dict[tuple[int, int], float | None] = {}
    for k, a in enumerate(ids):
        for b in ids[k + 1 :]:
            topo[(a, b)] = (
                topology(frame, masks[a], masks[b], cfg, (a, b))
                if a in masks and b in masks
                else (None, None)
            )
            sync[(a, b)] = synchrony(histories.get(a, empty), histories.get(b, empty), frame.timestamp, cfg)
    pairs = []
    for a in ids:
        for b in ids:
            if a == b:
                continue
            key = (min(a, b), max(a, b))
            sa, sb = spatial.get(a), spatial.get(b)
            disp = dist = direc = None
            if sa is not None and sb is not None:
                disp = sb.centroid - sa.centroid
                dist = float(np.linalg.norm(disp))
                direc = disp / dist if dist > 0 else np.zeros(3)
            label, container = topo[key]
            pairs.append(PairRelation(a, b, disp, dist, direc, label, container, sync[key]))
    return SceneRelations(
        {i: spatial.get(i) for i in ids}, frozenset(i for i in ids if i in masks), tuple(pairs)
    )
