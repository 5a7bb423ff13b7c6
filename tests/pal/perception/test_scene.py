"""Scene descriptor schema (Table 5.6) and the relational layer (Eq. 4.21-4.22)."""

from __future__ import annotations

import json

import networkx as nx
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.frames import RGBDFrame
from pal.perception.masks import Mask
from pal.perception.pipeline import Pipeline, PipelineConfig
from pal.perception.relations import RelationConfig, scene_relations, scene_vector_names, synchrony, topology
from pal.perception.scene import OBJECT_KEYS, SCENE_KEYS
from pal.perception.spatial import spatial_descriptor
from pal.perception.synthetic import Box, Sphere, SyntheticCamera
from pal.perception.topology import TopologyConfig

K = np.array([[200.0, 0.0, 49.5], [0.0, 200.0, 39.5], [0.0, 0.0, 1.0]])


def flat(depth_b: float | None = None, mask_b: np.ndarray | None = None) -> RGBDFrame:
    depth = np.ones((80, 100), np.float32)
    if depth_b is not None and mask_b is not None:
        depth[mask_b] = depth_b
    return RGBDFrame(np.zeros((80, 100, 3), np.uint8), depth, K, 0.0)


def box(x0: int, x1: int, y0: int, y1: int) -> np.ndarray:
    m = np.zeros((80, 100), bool)
    m[y0:y1, x0:x1] = True
    return m


def test_topology_from_masks_and_depth():
    a, b = box(10, 30, 20, 40), box(30, 50, 20, 40)
    assert topology(flat(), Mask.from_full(a), Mask.from_full(b)) == ("touching", None)
    assert topology(flat(1.3, b), Mask.from_full(a), Mask.from_full(b)) == (
        "disjoint",
        None,
    )  # apart in depth
    assert topology(flat(), Mask.from_full(a), Mask.from_full(box(60, 80, 20, 40))) == ("disjoint", None)
    assert topology(flat(), Mask.from_full(a), Mask.from_full(box(20, 40, 20, 40))) == ("overlapping", None)
    ring = box(10, 60, 10, 60) & ~box(20, 50, 20, 50)
    inner = box(28, 42, 28, 42)
    assert topology(flat(), Mask.from_full(inner), Mask.from_full(ring), ids=(5, 9)) == ("contained", 9)
    assert topology(flat(), Mask.from_full(ring), Mask.from_full(inner), ids=(9, 5)) == ("contained", 9)
    cup = box(10, 60, 10, 60) & ~box(20, 50, 10, 50)  # a U open at the top
    half_in = box(25, 45, 0, 25)
    # half inside the U's hull but neither touching nor in front of it: a hull alone never overlaps
    assert topology(flat(), Mask.from_full(half_in), Mask.from_full(cup)) == ("disjoint", None)
    in_front = box(25, 45, 0, 25) | box(20, 50, 22, 25)  # now adjacent to the U's arms ...
    assert topology(flat(1.3, cup), Mask.from_full(in_front), Mask.from_full(cup)) == ("overlapping", None)
    # ... and 30 cm in front of it: an occlusion. Behind it instead, it occludes nothing
    assert topology(flat(1.3, in_front), Mask.from_full(in_front), Mask.from_full(cup)) == ("disjoint", None)
    # a band of missing depth between two touching objects does not separate them
    gap = box(30, 34, 20, 40)
    a2, b2 = box(10, 30, 20, 40), box(34, 54, 20, 40)
    d = np.ones((80, 100), np.float32)
    d[gap] = 0.0
    f = RGBDFrame(np.zeros((80, 100, 3), np.uint8), d, K, 0.0)
    wide = TopologyConfig(hole_px=32)  # 5 px at this 100-px-wide frame
    assert topology(f, Mask.from_full(a2), Mask.from_full(b2), wide) == ("touching", None)
    assert topology(f, Mask.from_full(a2), Mask.from_full(b2), TopologyConfig(hole_px=0)) == (
        "disjoint",
        None,
    )


def test_kinematic_synchrony():
    ts = np.arange(10) / 10.0
    path = np.stack([ts * 0.1, np.zeros(10), np.ones(10)], axis=1)
    still = np.tile([0.3, 0.0, 1.0], (10, 1))
    assert synchrony((ts, path), (ts, path + 0.2), 0.9) == pytest.approx(1.0)
    assert synchrony((ts, path), (ts, -path), 0.9) == pytest.approx(-1.0)
    assert synchrony((ts, path), (ts, still), 0.9) == 0.0  # only one moves
    assert synchrony((ts, still), (ts, still), 0.9) is None  # undefined when nothing moves
    assert synchrony((ts[:2], path[:2]), (ts[:2], path[:2]), 0.9) is None  # too few shared samples


def test_relations_graph_and_fixed_length_vector():
    a, b = box(10, 30, 20, 40), box(30, 50, 20, 40)
    f = flat()
    masks = {1: Mask.from_full(a), 2: Mask.from_full(b)}
    spatial = {1: spatial_descriptor(f, masks[1]), 2: spatial_descriptor(f, masks[2]), 3: None}
    rel = scene_relations(f, spatial, masks, {}, RelationConfig(), salience={1: 0.5, 2: 2.0, 3: 0.0})
    assert len(rel.pairs) == 2 and rel.visible == {1, 2}  # object 3 has no position: no neighbour
    p12 = rel.pair(1, 2)
    assert p12 is not None and p12.topology == "touching" and p12.distance == pytest.approx(0.1, abs=0.01)
    assert np.allclose(p12.direction, [1, 0, 0], atol=0.01) and p12.synchrony is None
    # grounded predicates, in the camera-up frame without a support plane: 1 is left of 2, touching
    assert p12.grades is not None and p12.grades["left_of"] > 0.9 and p12.grades["touching"] > 0.75
    assert rel.grade("left_of", 2, 1) < 0.1 and rel.grade("near", 1, 2) > 0.9
    assert rel.grade("near", 1, 3) is None and rel.pair(1, 3) is None
    with pytest.raises(ValueError, match="predicate 'under' unknown"):
        rel.grade("under", 1, 2)
    g = rel.graph()
    assert isinstance(g, nx.DiGraph) and g.number_of_nodes() == 3 and g.number_of_edges() == 2
    assert g.nodes[3]["spatial"] is None and g.edges[1, 2]["topology"] == "touching"
    assert rel.order() == [2, 1, 3]  # by salience, not by id
    v = rel.vector(4)
    assert v.shape == (len(scene_vector_names(4)),) == (4 * 8 + 6 * 16,)
    assert np.all(np.isfinite(v))
    names = scene_vector_names(4)
    assert v[names.index("obj2.present")] == 0.0 and v[names.index("pair0_1.topo_touching")] == 1.0
    assert v[names.index("obj0.cx")] == pytest.approx(spatial[2].centroid[0])  # slot 0: the most salient
    assert v[names.index("pair0_1.left_of")] == pytest.approx(rel.grade("left_of", 2, 1))
    json.dumps(rel.to_dict(), allow_nan=False)


def render_frames() -> list[RGBDFrame]:
    cam = SyntheticCamera(320, 240)
    out = []
    for k in range(6):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", 3 * k, degrees=True).as_matrix()
        T[:3, 3] = [-0.1 + 0.005 * k, 0.0, 0.04]
        objects: list[Box | Sphere] = [Box((0.14, 0.1, 0.08), cam.table @ T, label=1, seed=1)]
        if k < 4:  # the ball leaves the scene after four frames
            objects.append(Sphere(0.04, (cam.table @ np.array([0.12, 0.0, 0.04, 1.0]))[:3], label=2))
        out.append(cam.render(objects, 0.5 * k))
    return out


def test_scene_descriptor_schema_with_nulls():
    pipe = Pipeline(PipelineConfig(segmenter="oracle"))
    states = [pipe(f) for f in render_frames()]
    scene = states[-1].scene
    assert tuple(scene) == SCENE_KEYS
    text = json.dumps(scene, allow_nan=False)  # JSON-serialisable, no NaN
    assert json.loads(text) == scene
    assert scene["frame_count"] == 6 and scene["timestamp"] == 2.5 and scene["num_objects"] == 2
    box_d, ball_d = scene["objects"]
    for obj in (box_d, ball_d):
        assert tuple(obj) == OBJECT_KEYS
        assert set(obj["bbox"]) == {"xyxy", "xywh", "centroid", "area"} and obj["is_busy"] is False
    assert box_d["has_pose"] and set(box_d["pose"]) == {"position", "orientation", "timestamp"}
    assert set(box_d["velocity"]) == {"linear", "dt_s"} and box_d["velocity"]["dt_s"] == 0.5
    assert box_d["num_valid_poses"] == box_d["num_poses"] == 6 and box_d["num_snapshots"] >= 1
    assert box_d["last_pose_diagnostics"]["solver"] in ("canonical", "kabsch", "pnp")
    # the featureless ball: snapshots but no pose, no velocity (null, not invented)
    assert ball_d["pose"] is None and ball_d["velocity"] is None and not ball_d["has_pose"]
    assert ball_d["num_snapshots"] >= 1 and ball_d["num_poses"] == 6 and ball_d["num_valid_poses"] == 0
    assert ball_d["visible"]  # last seen 1 s ago, within the 2 s window
    assert ball_d["last_updated"] == 1.5 and ball_d["age_s"] == 2.5
    assert scene["num_visible_objects"] == 2
    ball_now = states[-1].object(ball_d["obj_id"])
    assert not ball_now.visible and ball_now.position is None and ball_now.spatial is None


def test_carried_pairs_keep_the_previous_topology_and_others_are_recomputed():
    """Objects 1 and 2 touch in the previous frame; now 2 is 10 px away, 3 is new beside 1."""
    f = flat()
    before = {1: Mask.from_full(box(10, 30, 20, 40)), 2: Mask.from_full(box(30, 50, 20, 40))}
    spatial = {i: spatial_descriptor(f, m) for i, m in before.items()}
    prev = scene_relations(f, spatial, before, {}, RelationConfig())
    assert prev.pair(1, 2).topology == "touching"
    now = {1: before[1], 2: Mask.from_full(box(60, 80, 20, 40)), 3: Mask.from_full(box(10, 30, 40, 60))}
    spatial = {i: spatial_descriptor(f, m) for i, m in now.items()}
    fresh = scene_relations(f, spatial, now, {}, RelationConfig())
    assert fresh.pair(1, 2).topology == "disjoint" and fresh.pair(1, 3).topology == "touching"
    kept = scene_relations(f, spatial, now, {}, RelationConfig(), previous=prev, carried=frozenset({1, 2, 3}))
    # (1, 2) were both carried and related before: the previous label; (1, 3) was not related before
    assert kept.pair(1, 2).topology == "touching" and kept.pair(2, 1).topology == "touching"
    assert kept.pair(1, 3).topology == "touching" and kept.pair(2, 3).topology == fresh.pair(2, 3).topology
    # 2 segmented anew (not carried): recomputed
    anew = scene_relations(f, spatial, now, {}, RelationConfig(), previous=prev, carried=frozenset({1, 3}))
    assert anew.pair(1, 2).topology == "disjoint"
    # everything but topology is computed from this frame's masks and positions
    assert kept.pair(1, 2).distance == pytest.approx(fresh.pair(1, 2).distance)
    assert kept.pair(1, 2).grades == fresh.pair(1, 2).grades
