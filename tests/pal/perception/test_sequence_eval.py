"""The static-sequence evaluation on the shipped 4-frame excerpt of TUM RGB-D freiburg1_xyz."""

from __future__ import annotations

import numpy as np
import pytest

from pal.experiments.perception.evaluation import rotation_angle_deg
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
    # about 20 objects a frame; most are seen in both frames of a pair and keep their id
    assert r["seen_in_both"] >= 0.7 * r["objects_per_frame"] * r["pairs"] and r["kept_fraction"] >= 0.9
    # the experiment's targets (perception-sequence): >= 70 % posed, medians <= 1.5 deg and 1 cm, none wrong
    assert r["pose_fraction"] >= 0.7 and r["pose_fraction"] == pytest.approx(
        r["with_pose"] / r["kept_id"], abs=1e-12
    )
    assert r["rot_err_deg_median"] <= 1.5 and r["trans_err_m_median"] <= 0.01 and r["wrong_estimated"] == 0
    # no motion errs by the camera's own motion (~2 cm at the objects per frame); the estimate far less
    assert 0.01 < r["trans_err_still_m_median"] < 0.05
    assert r["trans_err_m_median"] < 0.5 * r["trans_err_still_m_median"]
    assert r["area_change_median"] < 0.2
    assert r["stage_ms"].keys() >= {"segmentation", "camera_motion", "pose", "relations"}
    # Pi's own camera motion: the best truth clock offset fits it at least as well as offset 0
    assert r["camera_rot_err_deg_median"] <= 1.5
    assert r["camera_rot_err_deg_at_best"] <= r["camera_rot_err_deg_median"] + 1e-9


def test_the_no_motion_predictor_is_scored_on_the_same_pairs(stride1):
    seq, r = stride1
    rows = r["rows"]
    posed = [row for row in rows if row["pose"]]
    assert len(posed) == r["with_pose"]
    # both errors exist on exactly the posed pairs, and the medians are taken over them
    assert all((row["rot_err_still_deg"] is None) == (not row["pose"]) for row in rows)
    assert all((row["trans_err_still_m"] is None) == (row["rot_err_deg"] is None) for row in rows)
    for key in ("rot_err_deg", "trans_err_m", "rot_err_still_deg", "trans_err_still_m"):
        assert r[f"{key}_median"] == pytest.approx(np.median([row[key] for row in posed]), abs=1e-12)
    better = sum(row["rot_err_deg"] < row["rot_err_still_deg"] for row in posed) / len(posed)
    assert r["rot_better_than_still"] == pytest.approx(better, abs=1e-12)
    # no motion errs in rotation by exactly the truth's camera rotation between the two frames
    poses = seq.camera_poses().poses
    for row in posed:
        i, j = r["per_pair"][row["pair"]]["frames"]
        turn = rotation_angle_deg(np.eye(3), (np.linalg.inv(poses[j]) @ poses[i])[:3, :3])
        assert row["rot_err_still_deg"] == pytest.approx(turn, abs=1e-6)
    # the estimate beats no motion on most posed pairs (the experiment's stride-1 target asks 80 %)
    assert r["rot_better_than_still"] > 0.5
    # the halves: pairs 0-1 and pair 2 (of 3)
    first = [row for row in rows if row["pair"] < 1.5 and row["kept"]]
    assert r["pose_fraction_halves"][0] == pytest.approx(
        sum(x["pose"] for x in first) / len(first), abs=1e-12
    )
    assert r["pose_fraction_halves"][1] == pytest.approx(r["per_pair"][2]["pose_fraction"], abs=1e-12)


def test_speed_is_reported_consistently(stride1):
    _, r = stride1
    assert r["fps_cpu"] == pytest.approx(r["frames"] / r["seconds_cpu"], rel=1e-12)
    assert r["fps_wall"] == pytest.approx(r["frames"] / r["seconds_wall"], rel=1e-12)


def test_stride_three_uses_frames_zero_and_three():
    seq = open_sequence("")
    r = evaluate_sequence(seq, 3, SequenceConfig())
    assert r["frames"] == 2 and r["pairs"] == 1 and r["per_pair"][0]["frames"] == [0, 3]
    # three frames of camera motion: no motion errs more, the estimate still meets the targets
    assert r["trans_err_still_m_median"] > 0.03 and r["trans_err_m_median"] <= 0.01
    assert r["rot_err_deg_median"] <= 1.5 and r["wrong_estimated"] == 0 and r["kept_fraction"] >= 0.9


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
    (d / "calibration.json").write_text(
        json.dumps({"fx": 10, "fy": 10, "cx": 3.5, "cy": 3.5, "depth_scale": 2e-4})
    )
    seq = TUMSequence(d)
    P = seq.camera_poses(offset=-0.02).poses
    motions = [(i, i + 1, np.linalg.inv(P[i + 1]) @ P[i]) for i in range(4)]
    offset, err = truth_clock_offset(seq, motions)
    assert offset == pytest.approx(-0.02) and err < 0.01  # degrees: the slerp between 10 ms samples
    # at the image times the turns differ by 20 ms of acceleration: a measurable error
    at_zero = truth_clock_offset(seq, motions, offsets=(0.0,))
    assert at_zero[0] == 0.0 and at_zero[1] > 5 * err
    assert truth_clock_offset(seq, []) == (None, None)
