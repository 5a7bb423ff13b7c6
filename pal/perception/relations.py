"""Scene composition parsing SCP (Eq. 4.21-4.22): pairwise relations, grounded predicates, a scene graph and vector.

For the pairs of objects the spatial index selects (below):

- **relative position**: ``displacement = μ_j - μ_i`` (3-D centroids, metres, camera frame),
  ``distance = |displacement|``, ``direction = displacement / distance``;
- **topology** (symmetric, from masks and depth, tolerant of depth holes):
  :func:`pal.perception.topology.topology`; None when either object has no mask this frame;
- **grounded predicates** near, on, left-of, in-front-of and touching, graded in [0, 1] in
  the support-plane frame from positions and their uncertainty
  (:mod:`pal.perception.grounding`); ``on_support`` grades each object resting on the plane;
- **kinematic synchrony**: over the last ``sync_window_s`` seconds of centroid measurements
  shared by both objects, the uncentred correlation of their finite-difference velocities
  ``Σ v_i·v_j / sqrt(Σ|v_i|² Σ|v_j|²)`` in [-1, 1] (1: moving together). None when both move
  slower than ``min_speed`` (undefined) or fewer than 3 distinct shared times; 0.0 when only one
  moves. Repeated timestamps (two frames at the same time) count once, the last one.

**Carried topology.** Between full segmentations the pipeline carries each mask by the
camera's motion and refines its border by a pixel (:mod:`pal.perception.propagation`); both
masks of a pair then move together, and their topological relation is the one of the previous
frame. Given ``previous`` relations and the ``carried`` ids, a pair of carried objects that
``previous`` related keeps that label and container instead of recomputing them; every other
pair (an object segmented anew, a pair not related before) is computed.

**Cost.** Relations are computed for each object's ``neighbours`` nearest objects in 3-D and
in the image (k-d trees), not for every pair, so a frame of n objects costs O(n k log n): on a
cluttered real frame of 30 fragments that is what keeps this layer at a few milliseconds.
The selected pairs' positions, gaps and grades are computed together
(:mod:`pal.perception.pair_geometry`), and their synchrony (:mod:`pal.perception.synchrony`).
Other pairs are far apart: their predicates are graded on demand by
:meth:`SceneRelations.grade` from the stored geometry.

The relations export as a networkx ``DiGraph`` (object nodes, relation edges) and as a
fixed-length vector whose slots are filled **by salience** (metric size, stability,
trackedness; given by the pipeline), not by id, so background fragments do not crowd out the
objects that matter (:func:`scene_vector_names` documents its layout; missing values are 0
with presence flags, never NaN).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass
from typing import Any

import networkx as nx
import numpy as np
from scipy.spatial import cKDTree

from pal.checks import check_float, check_int
from pal.perception.frames import RGBDFrame
from pal.perception.grounding import (
    PREDICATES,
    GroundingConfig,
    ObjectGeometry,
    grade,
    object_geometry,
    on_support,
    support_frame,
)
from pal.perception.masks import Mask
from pal.perception.pair_geometry import displacements, grade_pairs, surface_gaps
from pal.perception.plane import Plane
from pal.perception.spatial import SpatialDescriptor
from pal.perception.synchrony import distinct_history, pair_synchrony, velocity_correlation
from pal.perception.topology import TOPOLOGY, TopologyConfig, mask_hull, topology

__all__ = [
    "PREDICATES",
    "TOPOLOGY",
    "PairRelation",
    "RelationConfig",
    "SceneRelations",
    "scene_relations",
    "scene_vector_names",
    "synchrony",
    "topology",
]

_OBJ_FIELDS = ("present", "cx", "cy", "cz", "distance", "azimuth", "elevation", "on_support")
_PAIR_FIELDS = (
    "present",
    "dx",
    "dy",
    "dz",
    "distance",
    *(f"topo_{t}" for t in TOPOLOGY),
    "synchrony",
    "synchrony_defined",
    *PREDICATES,
)


@dataclass(frozen=True)
class RelationConfig:
    """Relation settings (module docstring).

    Attributes:
        topology: thresholds of the topological relation.
        grounding: scales of the graded predicates.
        sync_window_s: synchrony window, s.
        min_speed: below this mean speed an object counts as still, m/s.
        max_objects: object slots of :meth:`SceneRelations.vector` in the pipeline's state.
        neighbours: each object is related to this many nearest objects (3-D and image).
    """

    topology: TopologyConfig = TopologyConfig()
    grounding: GroundingConfig = GroundingConfig()
    sync_window_s: float = 1.0
    min_speed: float = 0.02
    max_objects: int = 8
    neighbours: int = 3

    def __post_init__(self) -> None:
        check_float("sync_window_s", self.sync_window_s, 0.0, open_low=True)
        check_float("min_speed", self.min_speed, 0.0)
        check_int("max_objects", self.max_objects)
        check_int("neighbours", self.neighbours)


@dataclass(frozen=True, eq=False)
class PairRelation:
    """Relations from object ``a`` to object ``b`` (None where evidence is missing).

    Attributes:
        a, b: object ids.
        displacement: (3,) ``μ_b - μ_a``, metres, camera frame.
        distance: its norm, metres.
        direction: its direction (unit).
        topology: a label of :data:`TOPOLOGY`.
        container: the containing object's id when ``contained``.
        synchrony: velocity correlation in [-1, 1].
        grades: ``{predicate: grade in [0, 1]}`` of :data:`PREDICATES` for (a, b), or None
            without both objects' geometry.
    """

    a: int
    b: int
    displacement: np.ndarray | None
    distance: float | None
    direction: np.ndarray | None
    topology: str | None
    container: int | None
    synchrony: float | None
    grades: dict[str, float] | None = None

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
            "grades": None if self.grades is None else dict(self.grades),
        }


def synchrony(
    history_a: tuple[np.ndarray, np.ndarray],
    history_b: tuple[np.ndarray, np.ndarray],
    now: float,
    config: RelationConfig | None = None,
) -> float | None:
    """Velocity correlation of two (timestamps (N,), positions (N, 3)) histories (:mod:`pal.perception.synchrony`)."""
    cfg = config or RelationConfig()
    if len(history_a[0]) < 3 or len(history_b[0]) < 3:
        return None  # fewer than 3 common timestamps
    a, b = distinct_history(history_a), distinct_history(history_b)
    return velocity_correlation(a, b, now, cfg.sync_window_s, cfg.min_speed)


def scene_vector_names(max_objects: int) -> list[str]:
    """Names of the :meth:`SceneRelations.vector` entries, in order.

    Per object slot k (objects by decreasing salience)
    ``obj{k}.{present,cx,cy,cz,distance,azimuth,elevation,on_support}``, then per slot pair
    k < l ``pair{k}_{l}.{present,dx,dy,dz,distance,topo_*(4),synchrony,synchrony_defined,
    near,on,left_of,in_front_of,touching}``.
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
        pairs: one :class:`PairRelation` per ordered pair the spatial index selected.
        geometry: per visible object its geometry in the support-plane frame (or None).
        on_support: per object with geometry, the grade of resting on the support plane.
        salience: per object, the salience that orders the vector's slots.
        support_from_camera: (4, 4) camera coordinates to the support-plane frame.
        config: the relation settings.
    """

    objects: dict[int, SpatialDescriptor | None]
    visible: frozenset[int]
    pairs: tuple[PairRelation, ...]
    geometry: dict[int, ObjectGeometry | None]
    on_support: dict[int, float]
    salience: dict[int, float]
    support_from_camera: np.ndarray
    config: RelationConfig

    def pair(self, a: int, b: int) -> PairRelation | None:
        """The stored relation of (a, b), or None when the spatial index did not select it."""
        return next((p for p in self.pairs if p.a == a and p.b == b), None)

    def grade(self, predicate: str, a: int, b: int) -> float | None:
        """Grade in [0, 1] of ``predicate(a, b)`` (one of :data:`PREDICATES`); None without geometry.

        Computed from the stored geometry when the pair was not among the nearest ones.
        """
        if predicate not in PREDICATES:
            raise ValueError(f"predicate {predicate!r} unknown; expected one of {PREDICATES}")
        p = self.pair(a, b)
        if p is not None and p.grades is not None:
            return p.grades[predicate]
        ga, gb = self.geometry.get(a), self.geometry.get(b)
        if ga is None or gb is None:
            return None
        return grade(ga, gb, self.config.grounding)[predicate]

    def order(self) -> list[int]:
        """Object ids by decreasing salience (ties by id)."""
        return sorted(self.objects, key=lambda i: (-self.salience.get(i, 0.0), i))

    def graph(self) -> nx.DiGraph:
        """The scene graph of this frame.

        Nodes are object ids (attributes ``visible``, ``spatial`` dict or None, ``salience``,
        ``on_support``); edges (a, b) carry the pair's relation fields.
        """
        g = nx.DiGraph()
        for oid, sp in self.objects.items():
            g.add_node(
                oid,
                visible=oid in self.visible,
                spatial=None if sp is None else sp.to_dict(),
                salience=self.salience.get(oid, 0.0),
                on_support=self.on_support.get(oid),
            )
        for p in self.pairs:
            attrs = p.to_dict()
            del attrs["a"], attrs["b"]
            g.add_edge(p.a, p.b, **attrs)
        return g

    def vector(self, max_objects: int = 8) -> np.ndarray:
        """Fixed-length vector (len ``len(scene_vector_names(max_objects))``), no NaN.

        Objects fill slots by decreasing salience; objects beyond ``max_objects`` are left out.
        """
        ids = self.order()[:max_objects]
        slot = {oid: k for k, oid in enumerate(ids)}
        obj = np.zeros((max_objects, len(_OBJ_FIELDS)))
        for oid in ids:
            sp = self.objects[oid]
            if sp is not None:
                obj[slot[oid], :7] = [1.0, *sp.centroid, sp.distance, sp.azimuth, sp.elevation]
            obj[slot[oid], 7] = self.on_support.get(oid, 0.0)
        n_pair = len(_PAIR_FIELDS)
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
                if p.grades is not None:
                    row[11:] = [p.grades[k] for k in PREDICATES]
        return np.concatenate([obj.ravel(), *[pairs[key] for key in sorted(pairs)]])

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible layer: objects (keyed by str id), visible ids, salience order, pairs."""
        return {
            "objects": {str(k): None if v is None else v.to_dict() for k, v in self.objects.items()},
            "visible": sorted(self.visible),
            "order": self.order(),
            "geometry": {str(k): None if v is None else v.to_dict() for k, v in self.geometry.items()},
            "on_support": {str(k): v for k, v in self.on_support.items()},
            "pairs": [p.to_dict() for p in self.pairs],
        }


def _neighbour_pairs(points: np.ndarray, k: int) -> set[tuple[int, int]]:
    """Unordered index pairs (i < j) linking each point to its ``k`` nearest others."""
    n = points.shape[0]
    if n < 2:
        return set()
    kk = min(k + 1, n)
    _, idx = cKDTree(points).query(points, k=kk)
    out = set()
    for i, row in enumerate(np.atleast_2d(idx)):
        for j in row[1:]:
            if j < n and j != i:
                out.add((min(i, int(j)), max(i, int(j))))
    return out


def _pair_relations(
    selected: Sequence[tuple[int, int]],
    spatial: Mapping[int, SpatialDescriptor | None],
    geometry: Mapping[int, ObjectGeometry | None],
    distinct: Mapping[int, tuple[np.ndarray, np.ndarray]],
    labels: Mapping[tuple[int, int], tuple[str | None, int | None]],
    now: float,
    cfg: RelationConfig,
) -> list[PairRelation]:
    """Both ordered relations of each selected pair (a < b): positions, gaps and grades of all pairs at once."""
    located = [
        k for k, (a, b) in enumerate(selected) if spatial.get(a) is not None and spatial.get(b) is not None
    ]
    rel: dict[int, tuple[np.ndarray, float, np.ndarray]] = {}
    if located:
        ca = np.array([spatial[selected[k][0]].centroid for k in located])  # type: ignore[union-attr]
        cb = np.array([spatial[selected[k][1]].centroid for k in located])  # type: ignore[union-attr]
        disp, dist, direc = displacements(ca, cb)
        back, back_dir = -disp, -direc
        for j, k in enumerate(located):
            rel[k] = (disp[j], float(dist[j]), direc[j])
            rel[-k - 1] = (back[j], float(dist[j]), back_dir[j])
    shaped = [
        k for k, (a, b) in enumerate(selected) if geometry.get(a) is not None and geometry.get(b) is not None
    ]
    grades: dict[int, dict[str, float]] = {}
    if shaped:
        geo: dict[int, ObjectGeometry] = {i: g for i, g in geometry.items() if g is not None}
        gap = surface_gaps([selected[k] for k in shaped], geo, cfg.grounding, {})
        ga, gb = [geo[selected[k][0]] for k in shaped], [geo[selected[k][1]] for k in shaped]
        rows = grade_pairs(ga + gb, gb + ga, cfg.grounding, np.concatenate([gap, gap])).tolist()
        for j, k in enumerate(shaped):
            grades[k] = dict(zip(PREDICATES, rows[j], strict=True))
            grades[-k - 1] = dict(zip(PREDICATES, rows[j + len(shaped)], strict=True))
    syncs = pair_synchrony(selected, distinct, now, cfg.sync_window_s, cfg.min_speed)
    out = []
    for k, (a, b) in enumerate(selected):
        label, container = labels[(a, b)]
        sync = syncs[k]
        for x, y, key in ((a, b, k), (b, a, -k - 1)):
            disp_xy, dist_xy, dir_xy = rel.get(key, (None, None, None))
            out.append(PairRelation(x, y, disp_xy, dist_xy, dir_xy, label, container, sync, grades.get(key)))
    return out


def _carried_topology(
    previous: SceneRelations | None, carried: AbstractSet[int]
) -> dict[tuple[int, int], tuple[str, int | None]]:
    """``{(a, b): (label, container)}`` of ``previous``'s pairs of two ``carried`` objects, a < b."""
    if previous is None or not carried:
        return {}
    return {
        (p.a, p.b): (p.topology, p.container)
        for p in previous.pairs
        if p.a < p.b and p.topology is not None and p.a in carried and p.b in carried
    }


def _pair_topology(
    frame: RGBDFrame,
    masks: Mapping[int, Mask],
    selected: Sequence[tuple[int, int]],
    cfg: RelationConfig,
    kept: Mapping[tuple[int, int], tuple[str, int | None]],
) -> dict[tuple[int, int], tuple[str | None, int | None]]:
    """``{(a, b): (label, container)}`` of the selected pairs: ``kept``'s, else computed (None without masks)."""
    hulls: dict[int, np.ndarray | None] = {}
    out: dict[tuple[int, int], tuple[str | None, int | None]] = {}
    for a, b in selected:
        if (a, b) in kept or a not in masks or b not in masks:
            out[(a, b)] = kept.get((a, b), (None, None))
            continue
        for i in (a, b):
            if i not in hulls:
                hulls[i] = mask_hull(masks[i])
        out[(a, b)] = topology(frame, masks[a], masks[b], cfg.topology, (a, b), (hulls[a], hulls[b]))
    return out


def scene_relations(
    frame: RGBDFrame,
    spatial: Mapping[int, SpatialDescriptor | None],
    masks: Mapping[int, Mask],
    histories: Mapping[int, tuple[np.ndarray, np.ndarray]],
    config: RelationConfig | None = None,
    ids: Sequence[int] | None = None,
    *,
    support: Plane | None = None,
    salience: Mapping[int, float] | None = None,
    previous: SceneRelations | None = None,
    carried: AbstractSet[int] = frozenset(),
) -> SceneRelations:
    """SCP (Eq. 4.22) over the given objects (module docstring).

    Args:
        frame: the current frame (depth for topology and geometry).
        spatial: per object id, its spatial descriptor (None if unknown).
        masks: masks of the objects visible this frame.
        histories: per object id, recent (timestamps (N,), centroids (N, 3)).
        config: relation settings (default: ``RelationConfig()``).
        ids: objects to relate (default: the keys of ``spatial``).
        support: the support plane (its frame grounds the predicates); None: camera frame.
        salience: per object id, the salience ordering the vector (default: visible points).
        previous: the previous frame's relations, whose topology carried pairs keep.
        carried: ids whose masks were carried from the previous frame (module docstring).
    """
    cfg = config or RelationConfig()
    ids = sorted(spatial) if ids is None else sorted(ids)
    S = support_frame(support)
    geometry = {i: object_geometry(frame, masks[i], S, cfg.grounding) if i in masks else None for i in ids}
    resting = {
        i: on_support(g, cfg.grounding) for i, g in geometry.items() if g is not None and support is not None
    }
    if salience is None:
        salience = {i: float(0 if spatial.get(i) is None else spatial[i].num_points) for i in ids}  # type: ignore[union-attr]
    located = [i for i in ids if spatial.get(i) is not None]
    selected: set[tuple[int, int]] = set()
    if located:
        cents = np.array([spatial[i].centroid for i in located])  # type: ignore[union-attr]
        selected |= {(located[a], located[b]) for a, b in _neighbour_pairs(cents, cfg.neighbours)}
    shown = [i for i in ids if i in masks]
    if shown:
        boxes = np.array(
            [[(m.bbox[0] + m.bbox[2]) / 2, (m.bbox[1] + m.bbox[3]) / 2] for m in (masks[i] for i in shown)]
        )
        selected |= {(shown[a], shown[b]) for a, b in _neighbour_pairs(boxes, cfg.neighbours)}
    distinct = {i: distinct_history(h) for i, h in histories.items() if len(h[0]) >= 3}
    labels = _pair_topology(frame, masks, sorted(selected), cfg, _carried_topology(previous, carried))
    pairs = _pair_relations(sorted(selected), spatial, geometry, distinct, labels, frame.timestamp, cfg)
    pairs.sort(key=lambda p: (p.a, p.b))
    return SceneRelations(
        {i: spatial.get(i) for i in ids},
        frozenset(i for i in ids if i in masks),
        tuple(pairs),
        geometry,
        resting,
        {i: float(salience.get(i, 0.0)) for i in ids},
        S,
        cfg,
    )
