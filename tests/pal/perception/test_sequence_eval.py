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


def test_the_truth_clock_offset_is_found_where_the_camera_motions_fit_it(tmp_path):
    """A camera turning ever faster about its axis; motions measured 20 ms before the image times."""
    import json

    import cv2
    from scipy.spatial.transform import Rotation

    from pal.experiments.perception.sequence_eval import truth_clock_offset
    from pal.perception.tum import TUMSequence

    d = tmp_path / "tum"
    (d / "rgb").mkdir(parents=True)
    (d / "depth").mkdir()
    times = [1.0 + k / 30.0 for k in range(5)]
    for t in times:
        cv2.imwrite(str(d / "rgb" / f"{t:.6f}.png"), np.zeros((8, 8, 3), np.uint8))
        cv2.imwrite(str(d / "depth" / f"{t:.6f}.png"), np.full((8, 8), 5000, np.uint16))
    for name in ("rgb", "depth"):
        (d / f"{name}.txt").write_text("".join(f"{t:.6f} {name}/{t:.6f}.png\n" for t in times))
    # yaw 20 deg/s^2 * t^2: each frame's turn depends on when it is read
    rows = []
    for t in np.arange(0.9, 1.25, 0.01):
        q = Rotation.from_euler("z", 20.0 * (t - 0.9) ** 2, degrees=True).as_quat()
        rows.append(f"{t:.3f} 0 0 0 {q[0]:.12f} {q[1]:.12f} {q[2]:.12f} {q[3]:.12f}\n")
    (d / "groundtruth.txt").write_text("".join(rows))
    (d / "calibration.json").write_text(json.dumps({"fx": 10, "fy": 10, "cx": 3.5, "cy": 3.5, "depth_scale": 2e-4}))
    seq = TUMSequence(d)
    P = seq.camera_poses(offset=-0.02).poses
    motions = [(i, i + 1, np.linalg.inv(P[i + 1]) @ P[i]) for i in range(4)]
    offset, err = truth_clock_offset(seq, motions)
    assert offset == pytest.approx(-0.02) and err < 0.01  # degrees: the slerp between 10 ms samples
    # at the image times the turns differ by 20 ms of acceleration: a measurable error
    at_zero = truth_clock_offset(seq, motions, offsets=(0.0,))
    assert at_zero[0] == 0.0 and at_zero[1] > 5 * err
    assert truth_clock_offset(seq, []) == (None, None)
