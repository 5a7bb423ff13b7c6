"""Experiments C1-C4, ``pal loop`` and the loop video at tiny sizes: the JSON contract and the outputs."""

import json

import cv2
import numpy as np
import pytest

from pal.agent.history import History
from pal.agent.video import VideoRecorder
from pal.cli import main
from pal.experiments import c1, c2, c3, c4
from pal.experiments.closed_loop import LoopConfig
from pal.experiments.output import jsonable

TINY = {"babble_steps": 24, "epochs": 3, "hidden": (8,), "reset_every": 12}


def test_c1_reports_perceived_and_ground_truth_mse():
    result = c1.run(c1.Config(**TINY))
    d = jsonable(result.to_dict())
    assert d["mse_perceived"] > 0 and d["mse_ground_truth"] > 0 and d["unit"] == "cm^2"
    assert set(d["per_object"]) == {"box", "ball"}
    assert "C1" in result.to_markdown() and set(result.figures()) == {"errors"}


def test_c3_compares_three_answers_with_the_replayed_simulator():
    result = c3.run(c3.Config(**TINY, queries=2, min_motion=0.0, test_fraction=0.5))
    d = jsonable(result.to_dict())
    for key in ("cf_err_cm_median", "interventional_err_cm_median", "factual_err_cm_median"):
        assert d[key] is not None and d[key] >= 0
    assert d["n"] == 2 and "ground_truth_model" in d


def test_c2_runs_the_three_controllers():
    result = c2.run(c2.Config(**TINY, targets=1, episode_steps=1))
    d = jsonable(result.to_dict())
    for c in ("inferred", "random", "scripted"):
        assert d[c]["final_err_cm_median"] >= 0
    assert "model_err_cm_median" in d and len(d["episodes"]) == 1
    json.dumps(d)  # JSON-compatible (NaN became None)


def test_c4_coverage_contract_and_curve():
    result = c4.run(c4.Config(**{**TINY, "babble_steps": 12}, budget=2, seeds=(0,), checkpoint_every=1))
    d = jsonable(result.to_dict())
    assert set(d["coverage_at_budget"]) == {"curiosity", "random"}
    assert all(0 <= v <= 1 for v in d["coverage_at_budget"].values())
    h = History(("shoulder", "elbow"), ("box",))
    for k in range(3):  # the box moves at step 1 only
        prev, now = np.array([[0.0, 0.1]]), np.array([[0.0, 0.1 + (0.1 if k == 1 else 0.0)]])
        h.append(
            episode=0,
            act=[0, 0],
            q_prev=[0, 0],
            q=[0, 0],
            hand_prev=[0, 0, 0],
            hand=[0, 0, 0],
            touch=[0],
            meas_prev=prev,
            meas=now,
            std=prev,
            est_prev=prev,
            est=now,
            truth_prev=prev,
            truth=now,
            state=np.zeros(2),
        )
    curve = c4.coverage_curve(h, 0, np.array([1, 3]), ((-0.5, 0.0), (0.5, 0.4)), (4, 4), 0.005)
    np.testing.assert_allclose(curve, [0.0, 1 / 16])


def test_pal_loop_writes_an_annotated_video(tmp_path, capsys):
    video = tmp_path / "loop.mp4"
    assert main(["loop", "--steps", "3", "--babble", "3", "--video", str(video), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (
        summary["steps"] == 3
        and summary["modes"] == {}
        and summary["babble_steps"] == 3
        and summary["video_frames"] == 4
    )
    cap = cv2.VideoCapture(str(video))
    frames = 0
    while cap.read()[0]:
        frames += 1
    assert frames == 4
    for bad, match in (
        (["--goal", "a,b"], "expected X,Y"),
        (["--video", "x.avi"], "ending in .mp4"),
        (["--babble", "9"], "babble must be in"),
    ):
        with pytest.raises(SystemExit, match=match):
            main(["loop", "--steps", "3", *bad])


def test_video_recorder_rejects_bad_frames(tmp_path):
    with VideoRecorder(tmp_path / "v.mp4") as rec:
        rec.write(np.zeros((48, 64, 3), np.uint8))
        with pytest.raises(ValueError, match="differs from the first frame"):
            rec.write(np.zeros((32, 64, 3), np.uint8))
        with pytest.raises(ValueError, match="uint8"):
            rec.write(np.zeros((48, 64, 3), np.float32))
    assert (tmp_path / "v.mp4").stat().st_size > 0
    with pytest.raises(ValueError, match="steps must be a positive int"):
        LoopConfig(steps=0)
