"""Merging fragments that move rigidly together: a split object becomes one id, separate ones stay apart."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.fragments import FragmentMerger, MergeConfig, touching, union
from pal.perception.masks import Mask
from pal.perception.pipeline import Pipeline, PipelineConfig
from pal.perception.synthetic import Box, SyntheticCamera

CAM = SyntheticCamera(320, 240)
FRAMES = 8


def on_table(x: float, y: float, z: float, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = [x, y, z]
    return CAM.table @ T


def scene(k: int) -> list[Box]:
    """Labels 1 + 2: one object cut in two (halves glued face to face), sliding and turning together.

    Labels 3 and 4: two boxes side by side, sliding past each other in opposite directions.
    Labels 5 and 6: two touching boxes that stay still.
    """
    pair = on_table(-0.14, -0.08 + 0.012 * k, 0.04, 3.0 * k) @ np.linalg.inv(CAM.table)
    half = (0.06, 0.1, 0.08)
    a = on_table(-0.03, 0.0, 0.0)
    b = on_table(0.03, 0.0, 0.0)
    return [
        Box(half, pair @ a, label=1, seed=1),
        Box(half, pair @ b, label=2, seed=2),
        Box((0.06, 0.1, 0.08), on_table(0.05, -0.02 + 0.012 * k, 0.04), label=3, seed=3),
        Box((0.06, 0.1, 0.08), on_table(0.11, 0.02 - 0.012 * k, 0.04), label=4, seed=4),
        Box((0.06, 0.08, 0.06), on_table(0.0, 0.2, 0.03), label=5, seed=5),
        Box((0.06, 0.08, 0.06), on_table(0.06, 0.2, 0.03), label=6, seed=6),
    ]


@pytest.fixture(scope="module")
def run():
    cfg = PipelineConfig(segmenter="oracle", camera_motion=None, relations=None, merge=MergeConfig())
    pipe = Pipeline(cfg)
    return pipe, [pipe(CAM.render(scene(k), 0.1 * k)) for k in range(FRAMES)]


def test_pieces_moving_rigidly_together_are_merged_and_others_stay_apart(run):
    pipe, states = run
    first = {o.label: o.obj_id for o in states[0].objects if o.visible}
    assert sorted(first) == [1, 2, 3, 4, 5, 6]
    window = MergeConfig().window  # the pairs that stay apart had poses to compare too
    assert all(s.object(first[i]).pose.is_valid for s in states[:window] for i in (3, 4, 5, 6))
    merges = [m for s in states for m in s.merges]
    assert merges == [(first[1], first[2])]
    decided = next(k for k, s in enumerate(states) if s.merges)
    assert decided >= window - 1
    last = states[-1]
    ids = sorted(o.obj_id for o in last.objects if o.visible)
    assert ids == sorted([first[1], first[3], first[4], first[5], first[6]])  # the older id is kept
    merged = last.object(first[1])  # one object with the union of both pieces' masks
    frame = CAM.render(scene(FRAMES - 1), 0.1 * (FRAMES - 1))
    x0, y0, x1, y1 = merged.mask.bbox
    covered = frame.labels[y0:y1, x0:x1][merged.mask.crop]
    assert set(np.unique(covered).tolist()) == {1, 2}
    assert merged.mask.area == int(np.isin(frame.labels, (1, 2)).sum())
    assert first[2] not in pipe.records and first[2] in pipe.merger.aliases


def test_helpers_and_config_checks():
    a = np.zeros((20, 20), bool)
    a[2:8, 2:8] = True
    b = np.zeros_like(a)
    b[2:8, 10:16] = True
    ma, mb = Mask.from_full(a), Mask.from_full(b)
    assert not touching(ma, mb, 2) and touching(ma, mb, 3)  # a gap of two columns
    assert union([ma, mb]).area == 72
    merger = FragmentMerger()
    merger.aliases[5] = 3
    merger.aliases[3] = 1
    assert merger.target(5) == 1 and merger.target(7) == 7
    with pytest.raises(ValueError, match="window"):
        MergeConfig(window=1)
    with pytest.raises(ValueError, match="max_rotation_deg"):
        MergeConfig(max_rotation_deg=0.0)
    with pytest.raises(ValueError, match="adjacency_px"):
        MergeConfig(adjacency_px=-1)
