"""Re-identification by predicted 3-D position and memory-gallery appearance after a short loss."""

from __future__ import annotations

import numpy as np
import pytest

from pal.perception.pipeline import Pipeline, PipelineConfig
from pal.perception.reid import ReidConfig, gallery_histograms
from pal.perception.segmentation import OracleSegmenter
from pal.perception.synthetic import Box, Sphere, SyntheticCamera
from pal.perception.tracking import Tracker, TrackerConfig

CAM = SyntheticCamera(160, 120)
DT = 1.0 / 30.0
SPEED = 0.3  # m/s along the table's x: 1 cm per frame
HIDDEN = range(4, 14)  # 10 frames (0.33 s) out of sight: the box moves 10 cm, nearly its width


def on_table(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [x, y, z]
    return CAM.table @ T


def scene(k: int, newcomer: bool = False) -> list[Box | Sphere]:
    objects: list[Box | Sphere] = [Box((0.08, 0.08, 0.1), on_table(0.15, 0.12, 0.05), label=2, seed=2)]
    x = -0.15 + SPEED * DT * k
    if k in HIDDEN:
        return objects
    if newcomer and k > HIDDEN[-1]:  # a red ball where the box would be
        objects.append(Sphere(0.05, (CAM.table @ np.array([x, -0.05, 0.05, 1.0]))[:3], label=1))
    else:
        objects.append(Box((0.12, 0.1, 0.08), on_table(x, -0.05, 0.04), label=1, seed=1))
    return objects


def moving_ids(config: TrackerConfig, newcomer: bool = False) -> list[int | None]:
    """The id given to the moving object (label 1) in each frame, None while hidden."""
    tracker, seg, out = Tracker(config), OracleSegmenter((0,)), []
    for k in range(HIDDEN[-1] + 4):
        frame = CAM.render(scene(k, newcomer), DT * k)
        cands = seg(frame)
        obs = tracker.update(cands, frame.timestamp, frame=frame)
        out.append(next((o.track_id for o, c in zip(obs, cands, strict=True) if c.label == 1), None))
    return out


def test_a_box_hidden_for_ten_frames_keeps_its_id_by_position_and_appearance():
    cfg = TrackerConfig(predict_s=0.0)  # no mask extrapolation: only the 3-D prediction can bridge the gap
    ids = moving_ids(cfg)
    assert all(i is None for i in ids[HIDDEN[0] : HIDDEN[-1] + 1])
    assert set(ids[: HIDDEN[0]]) == set(ids[HIDDEN[-1] + 1 :]) == {ids[0]}
    # without the stage, the same box is born again under a new id
    without = moving_ids(TrackerConfig(predict_s=0.0, reid=None))
    assert without[HIDDEN[-1] + 1] != without[0]


def test_a_different_object_at_the_predicted_place_gets_a_new_id():
    ids = moving_ids(TrackerConfig(predict_s=0.0), newcomer=True)
    after = ids[HIDDEN[-1] + 1 :]
    assert after[0] is not None and after[0] != ids[0] and len(set(after)) == 1


def test_no_reidentification_after_the_maximum_gap():
    cfg = TrackerConfig(predict_s=0.0, reid=ReidConfig(max_gap_s=0.2))  # shorter than the 0.37 s gap
    ids = moving_ids(cfg)
    assert ids[HIDDEN[-1] + 1] != ids[0]


def test_the_pipeline_keeps_the_id_through_the_loss():
    pipe = Pipeline(
        PipelineConfig(
            segmenter="oracle",
            estimate_pose=False,
            relations=None,
            camera_motion=None,  # the camera is known to be static: the world is the camera frame
            tracker=TrackerConfig(predict_s=0.0),
        )
    )
    states = [pipe(CAM.render(scene(k), DT * k)) for k in range(HIDDEN[-1] + 4)]
    first = {o.label: o.obj_id for o in states[0].objects if o.visible}
    back = next(o for o in states[HIDDEN[-1] + 1].objects if o.visible and o.label == 1)
    assert back.obj_id == first[1] and back.status == "reidentified"
    views = pipe._views(first[1])
    assert len(views) >= 1 and all(v.shape == (48,) for v in views)


def test_gallery_histograms_and_config_checks():
    rgb = np.zeros((8, 8, 3), np.uint8)
    rgb[..., 0] = 255
    mask = np.zeros((8, 8), bool)
    mask[2:6, 2:6] = True
    (h,) = gallery_histograms([rgb, rgb], [mask, np.zeros_like(mask)])  # an empty view is skipped
    assert h.sum() == pytest.approx(1.0, abs=1e-5) and h.max() == pytest.approx(1.0, abs=1e-5)
    with pytest.raises(ValueError, match="max_gap_s"):
        ReidConfig(max_gap_s=0.0)
    with pytest.raises(ValueError, match="max_appearance"):
        ReidConfig(max_appearance=1.5)
    with pytest.raises(ValueError, match="size_ratio"):
        ReidConfig(size_ratio=0.9)
