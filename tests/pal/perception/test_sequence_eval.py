"""The static-sequence evaluation on the shipped 4-frame excerpt of TUM RGB-D freiburg1_xyz."""

from __future__ import annotations

import numpy as np
import pytest

from pal.experiments.perception.sequence_eval import SequenceConfig, evaluate_sequence, open_sequence


@pytest.fixture(scope="module")
def stride1():
    seq = open_sequence("")
    return seq, evaluate_sequence(seq, 1, SequenceConfig())


def test_excerpt_opens_with_camera_truth_for_every_frame():
    seq = open_sequence("")
    poses = seq.camera_poses()
    assert len(seq) == 4 and poses.valid.all()
    # the camera moves about 1 cm per frame in this clip (SOURCE: median per-frame motion)
    step = np.linalg.norm(poses.poses[1][:3, 3] - poses.poses[0][:3, 3])
    assert 0.002 < step < 0.03


def test_stride_one_scores_ids_poses_and_the_no_motion_predictor(stride1):
    _, r = stride1
    assert r["frames"] == 4 and r["pairs"] == 3 and r["pairs_without_truth"] == 0
    assert r["seen_in_both"] >= 10 and r["kept_fraction"] >= 0.9
    assert r["with_pose"] >= 5 and r["wrong_estimated"] == 0
    assert r["rot_err_deg_median"] < 3.0 and r["trans_err_m_median"] < 0.02
    # no motion is wrong by the camera's own motion: ~1 cm and a few tenths of a degree per frame
    assert 0.003 < r["trans_err_still_m_median"] < 0.05
    assert 0.0 < r["rot_err_still_deg_median"] < 2.0
    assert 0.0 <= r["rot_better_than_still"] <= 1.0
    assert r["fps_cpu"] > 0 and set(r["stage_ms"]) >= {"segmentation", "pose"}
    assert 0.0 <= r["area_change_median"] < 0.5 and len(r["pose_fraction_halves"]) == 2
    posed = [row for row in r["rows"] if row["pose"]]
    assert all(row["rot_err_still_deg"] is not None for row in posed)


def test_stride_three_uses_frames_zero_and_three():
    seq = open_sequence("")
    r = evaluate_sequence(seq, 3, SequenceConfig())
    assert r["frames"] == 2 and r["pairs"] == 1


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"strides": ()}, "strides"),
        ({"strides": (0,)}, "strides"),
        ({"camera": "kinect"}, "camera"),
        ({"frames": 1}, "frames"),
        ({"truth_offset_s": 0.5}, "truth_offset_s"),
    ],
)
def test_bad_settings_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SequenceConfig(**kwargs)


def test_a_stride_longer_than_the_run_is_refused(stride1):
    seq, _ = stride1
    with pytest.raises(ValueError, match="stride 5 over 4 frames"):
        evaluate_sequence(seq, 5, SequenceConfig())


def test_static_objects_take_the_checked_egomotion_prediction(stride1):
    """Most poses after the first frames are the camera's motion confirmed by depth and grey levels."""
    from pal.experiments.perception.sequence import sequence_stage_table

    _, r = stride1
    assert r["pose_solvers"].get("egomotion", 0) >= 0.5 * r["with_pose"] and r["wrong_estimated"] == 0
    table = sequence_stage_table({1: r})
    rows = {row[0]: row[1] for row in table.rows}
    assert rows["pose"] > 0 and rows["all (CPU time of the process)"] == pytest.approx(1000.0 / r["fps_cpu"])
