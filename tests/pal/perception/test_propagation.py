"""Mask propagation: warped masks land where the known motion puts them, and new objects still appear."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.masks import Mask
from pal.perception.pipeline import Pipeline, PipelineConfig
from pal.perception.plane import Plane
from pal.perception.propagation import PropagationConfig, carried_plane, propagate_masks
from pal.perception.segmentation import SegmentationConfig
from pal.perception.synthetic import Box, SyntheticCamera, table_pose
from pal.perception.topology import topology

W, H = 320, 240
TABLE = table_pose()


def motion() -> np.ndarray:
    """current_from_previous: 2 cm sideways, 1 cm closer, 1.5 degrees of yaw."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("y", 1.5, degrees=True).as_matrix()
    T[:3, 3] = [0.02, 0.0, -0.01]
    return T


def on_table(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [x, y, z]
    return TABLE @ T


def scene(T: np.ndarray, t: float = 0.0, extra: bool = False):
    """The tabletop seen by a camera moved by ``T`` (current_from_previous), optionally with a second box."""
    cam = SyntheticCamera(W, H, table=T @ TABLE)
    objects = [Box((0.12, 0.1, 0.1), T @ on_table(-0.05, 0.0, 0.05), label=1, seed=1)]
    if extra:
        objects.append(Box((0.08, 0.08, 0.06), T @ on_table(0.16, 0.08, 0.03), label=2, seed=2))
    return cam.render(objects, t)


def support(T: np.ndarray) -> Plane:
    table = T @ TABLE
    n = table[:3, 2]
    return Plane(n, float(-n @ table[:3, 3]))


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_carried_plane_is_the_plane_seen_after_the_motion():
    T = motion()
    got = carried_plane(support(np.eye(4)), T)
    want = support(T)
    assert got is not None and carried_plane(None, T) is None
    np.testing.assert_allclose(got.normal, want.normal, atol=1e-12)
    assert got.offset == pytest.approx(want.offset, abs=1e-12)


@pytest.mark.parametrize("shrink", [0, 2])
def test_propagated_mask_lands_on_the_object_after_a_known_motion(shrink: int):
    T = motion()
    f0, f1 = scene(np.eye(4)), scene(T)
    truth0, truth1 = f0.labels == 1, f1.labels == 1
    moved = iou(truth0, truth1)
    assert moved < 0.8  # the motion moves the object visibly: staying put would not pass
    prev = truth0
    if shrink:  # a mask short of its object by `shrink` pixels: the refinement grows it back
        prev = cv2.erode(truth0.view(np.uint8), np.ones((2 * shrink + 1,) * 2, np.uint8)).view(bool)
    out = propagate_masks(  # border 2 at 640 columns: 1 pixel here
        {7: Mask.from_full(prev)}, f0.depth, f1, T, support(T), PropagationConfig(border=2), SegmentationConfig()
    )
    assert [c.label for c in out] == [7]
    got = out[0].mask.full()
    assert iou(got, truth1) >= (0.99 if not shrink else 0.9)
    assert (got & ~truth1).sum() <= 0.01 * truth1.sum()  # neither the table nor the background
    if shrink:  # the border refinement recovers pixels a plain warp (border 0) leaves out
        plain = propagate_masks(
            {7: Mask.from_full(prev)}, f0.depth, f1, T, support(T), PropagationConfig(border=0), SegmentationConfig()
        )
        assert iou(got, truth1) > iou(plain[0].mask.full(), truth1) + 0.03


def test_propagation_drops_a_mask_that_left_the_view():
    T = np.eye(4)
    T[0, 3] = -2.0  # everything moves 2 m to the left: out of the image
    f0 = scene(np.eye(4))
    out = propagate_masks(
        {1: Mask.from_full(f0.labels == 1)}, f0.depth, f0, T, None, PropagationConfig(), SegmentationConfig()
    )
    assert out == []


def test_bad_propagation_settings_are_refused():
    with pytest.raises(ValueError, match="every"):
        PropagationConfig(every=0)
    with pytest.raises(ValueError, match="max_interval_s"):
        PropagationConfig(max_interval_s=-1.0)
    assert PropagationConfig().small(motion()) and not PropagationConfig().small(np.diag([1.0, -1.0, -1.0, 1.0]))
    f0 = scene(np.eye(4))
    with pytest.raises(ValueError, match="previous depth"):
        propagate_masks({}, f0.depth[:10], f0, np.eye(4), None, PropagationConfig(), SegmentationConfig())


def test_periodic_full_segmentation_finds_a_new_object_and_ids_persist():
    """Static camera at 30 Hz, full segmentation every 3rd frame; a second box appears in frame 1."""
    frames = [scene(np.eye(4), k / 30.0, extra=k >= 1) for k in range(5)]
    pipe = Pipeline(
        PipelineConfig(
            propagation=PropagationConfig(every=3), estimate_pose=False, relations=None, seed=3
        )
    )
    seen = []
    for f in frames:
        state = pipe(f)
        labels = {}
        for o in state.objects:
            if o.visible:
                x0, y0, x1, y1 = o.mask.bbox
                labels[int(np.bincount(f.labels[y0:y1, x0:x1][o.mask.crop]).argmax())] = o.obj_id
        seen.append(labels)
    first = seen[0][1]
    assert all(s.get(1) == first for s in seen)  # the first box keeps its id, propagated or segmented
    assert 2 not in seen[1] and 2 not in seen[2]  # propagated frames carry only known objects
    assert 2 in seen[3] and seen[4].get(2) == seen[3][2]  # the full segmentation finds it, then it is carried
    box = [o for o in pipe(scene(np.eye(4), 5 / 30.0, extra=True)).objects if o.obj_id == first][0]
    assert iou(box.mask.full(), frames[-1].labels == 1) >= 0.9


def test_carried_frames_keep_the_topology_of_the_last_full_segmentation(monkeypatch):
    """Two boxes 4 mm apart (touching) and one farther, camera turning slowly: the labels of the full segmentations."""

    def frame(k: int):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("y", 0.3 * k, degrees=True).as_matrix()
        cam = SyntheticCamera(W, H, table=T @ TABLE)
        boxes = [
            Box((0.08, 0.1, 0.12), T @ on_table(-0.08, 0.0, 0.06), label=1, seed=1),
            Box((0.08, 0.1, 0.05), T @ on_table(0.004, 0.0, 0.025), label=2, seed=2),  # 4 mm apart
            Box((0.06, 0.06, 0.06), T @ on_table(0.2, 0.1, 0.03), label=3, seed=3),
        ]
        return cam.render(boxes, k / 30.0)

    import pal.perception.relations as relations

    calls = []
    monkeypatch.setattr(relations, "topology", lambda *a, **k: calls.append(1) or topology(*a, **k))
    pipe = Pipeline(PipelineConfig(propagation=PropagationConfig(every=3), estimate_pose=False, seed=3))
    labels, computed = [], []
    for k in range(6):
        f = frame(k)
        state = pipe(f)
        computed.append(len(calls))
        calls.clear()
        ids = {}
        for o in state.objects:
            x0, y0, x1, y1 = o.mask.bbox
            ids[int(np.bincount(f.labels[y0:y1, x0:x1][o.mask.crop]).argmax())] = o.obj_id
        rel = state.relations
        labels.append(rel.pair(min(ids[1], ids[2]), max(ids[1], ids[2])).topology)
    assert labels[:3] == [labels[0]] * 3 and labels[3:] == [labels[3]] * 3
    assert labels[0] == labels[3] == "touching"
    assert computed[0] > 0 and computed[3] > 0 and computed[1] == computed[2] == computed[4] == computed[5] == 0
