"""Experiments A1-A3 and the perception benchmark at small sizes; the conceptual-space evaluation helpers."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from pal.cli import main
from pal.experiments.bench import perception as bench_perception
from pal.experiments.perception import a1_kinematic, a2_visual, a3_multidomain
from pal.experiments.perception import sequence as perception_sequence
from pal.experiments.perception.concept_eval import (
    FamilyScaler,
    leave_one_out,
    loo_accuracy,
    pca_2d,
    prototype_distances,
)
from pal.experiments.perception.evaluation import RunResult, evaluate_sequence
from pal.experiments.perception.runs import TINY_RUNS, RunSet
from pal.lab import configs, registry
from pal.lab.render import jsonable
from pal.perception import KINEMATIC_DIM, VISUAL_DIM, PipelineConfig, RecordedSequence, SequenceWriter
from pal.perception.synthetic import SyntheticCamera

SMALL = RunSet(motions=("box-translation", "ball-roll"), per_motion=1, fps=6.0, width=320, height=240)


def test_registered_entries_and_their_configs():
    for name, module in (("a1", a1_kinematic), ("a2", a2_visual), ("a3", a3_multidomain)):
        entry = registry.get("experiment", name)
        assert entry.config is module.Config and entry.run is module.run
        assert entry.tiny.runs == TINY_RUNS and entry.default().runs.per_motion == 4
        assert entry.summary.startswith(name.upper() + ":")
    quick = registry.get("experiment", "a1").quick.runs
    assert quick.motions == ("box-rotation", "ball-roll") and quick.per_motion == 1 and quick.width == 640
    bench = registry.get("bench", "perception")
    assert (
        bench.config is bench_perception.Config
        and bench.tiny.frames < bench.quick.frames < bench.default().frames
    )


def test_config_checks_and_overrides():
    with pytest.raises(ValueError, match="must be a non-empty list of"):
        RunSet(motions=("box-flight",))
    with pytest.raises(ValueError, match="per_motion must be a positive int, got 0"):
        RunSet(per_motion=0)
    with pytest.raises(ValueError, match="segmenter 'sam' unknown"):
        RunSet(segmenter="sam")
    with pytest.raises(ValueError, match="frames must be an int >= 2, got 1"):
        bench_perception.Config(frames=1)
    with pytest.raises(ValueError, match="motion 'box-flight' unknown"):
        bench_perception.Config(motion="box-flight")
    c = configs.override(a1_kinematic.Config(), "runs.motions", ["ball-roll"])
    c = configs.override(c, "runs.per_motion", 2)
    assert c.runs.motions == ("ball-roll",) and c.runs.per_motion == 2 and c.runs.width == 640
    assert configs.to_dict(c)["runs"]["motions"] == ["ball-roll"]
    with pytest.raises(ValueError, match="must be a non-empty list"):
        configs.override(c, "runs.motions", ["box-flight"])


@pytest.fixture(scope="module")
def a1_report(tmp_path_factory):
    config = a1_kinematic.Config(runs=dataclasses.replace(SMALL, data_dir=str(tmp_path_factory.mktemp("a1"))))
    return config, a1_kinematic.run(config)


@pytest.mark.render
@pytest.mark.slow
def test_a1_scores_the_box_and_flags_the_ball(a1_report):
    _, rep = a1_report
    m = json.loads(json.dumps(jsonable(dict(rep.metrics)), allow_nan=False))
    runs = {r["motion"]: r for r in m["runs"]}
    box, ball = runs["box-translation"], runs["ball-roll"]
    # the textured box is tracked with estimated poses close to the truth
    assert (
        box["estimated_fraction"] >= 0.8
        and box["trans_err_cm_median"] < 1.0
        and box["rot_err_deg_median"] < 5.0
    )
    assert (
        box["valid_total"][0] <= box["valid_total"][1] and box["tracks"] == 1 and box["seg_iou_mean"] > 0.85
    )
    # the one-colour ball has no usable 6-DoF trajectory, and is flagged as such
    assert not ball["usable_trajectory"] and ball["estimated_fraction"] < 0.8 and ball["failures"]
    assert m["ball"] == {
        "runs": 1,
        "usable_trajectories": 0,
        "estimated_poses": [ball["valid_total"][0]],
        "estimated_fraction": [ball["estimated_fraction"]],
        "centroid_err_cm_median": ball["centroid_err_cm_median"],
    }
    assert m["rigid"]["runs"] == 1 and m["rigid"]["runs_meeting"] == 1
    assert m["per_motion"]["box-translation"]["estimated_fraction_min"] == box["estimated_fraction"]
    assert set(m["per_object"]) == {"box", "ball"} and m["per_object"]["box"]["seg_iou_mean"] > 0.85
    assert rep.target("rigid_estimated_fraction").value == box["estimated_fraction"]
    assert rep.target("rigid_trans_err_cm").value == box["trans_err_cm_median"]
    assert all(t.met for t in rep.targets), [(t.name, t.value) for t in rep.targets]
    # Table 5.3 with the thesis's numbers beside ours, and the summary against the thesis
    t53 = next(t for t in rep.tables if "Table 5.3" in t.title)
    row = dict(zip(t53.columns, next(r for r in t53.rows if r[0] == "box-translation"), strict=True))
    assert row["thesis Valid/total"] == "271/272" and row["Valid/total"] == "{}/{}".format(
        *box["valid_total"]
    )
    summary = next(t for t in rep.tables if t.title == "A1 against the thesis")
    assert summary.rows[0][2].startswith("0.075-0.107") and summary.rows[0][3] == box["estimated_fraction"]
    # figures: one trajectory panel per motion (ground truth, estimate, start, end), pose errors per run
    assert {"trajectories", "pose_error"} <= set(rep.figures)
    if "motion_pca" in rep.figures:  # the ball's few poses give a descriptor: drawn hollow (not usable)
        filled = [len(c.get_facecolor()) for c in rep.figures["motion_pca"].axes[0].collections]
        assert sorted(filled) == [0, 1]  # the ball hollow, the box filled
    ax = rep.figures["trajectories"].axes[0]
    assert ax.get_title() == "box-translation" and ax.get_xlabel() == "Δx [cm]" and len(ax.lines) == 4
    assert rep.figures["pose_error"].axes[0].get_ylabel() == "error [cm]"


@pytest.mark.render
@pytest.mark.slow
def test_a1_reuses_recordings_in_data_dir(a1_report):
    config, rep = a1_report
    root = Path(config.runs.data_dir)
    stamps = {p: p.stat().st_mtime_ns for p in root.rglob("sequence.json")}
    again = a1_kinematic.run(config)  # same data_dir: nothing is re-rendered, same numbers
    assert len(stamps) == 2 and {p: p.stat().st_mtime_ns for p in root.rglob("sequence.json")} == stamps
    strip = [{k: v for k, v in r.items() if k != "fps"} for r in rep.metrics["runs"]]
    assert strip == [{k: v for k, v in r.items() if k != "fps"} for r in again.metrics["runs"]]


def _record(object_: str, kind: str, run: int, rng: np.random.Generator, usable: bool = True) -> RunResult:
    centre = {"box": 0.0, "boat": 3.0, "ball": -3.0}[object_]
    motion_centre = {"translation": 0.0, "rotation": 1.0, "roll": 2.0}[kind]
    kin = np.full(KINEMATIC_DIM, motion_centre) + 0.05 * rng.normal(size=KINEMATIC_DIM)
    return RunResult(
        motion=f"{object_}-{kind}",
        object=object_,
        kind=kind,
        run=run,
        seed=run,
        frames=10,
        in_view=10,
        duration_s=1.0,
        snapshots=2,
        valid=10 if usable else 2,
        total=10,
        propagated=0,
        attempts=10,
        matches_mean=50.0,
        estimated_fraction=1.0 if usable else 0.2,
        trans_err_cm=[0.1],
        rot_err_deg=[0.5],
        centroid_err_cm=[0.2],
        seg_iou=[0.9],
        seg_iou_all=[0.9],
        tracks=1,
        fragments=0,
        kinematic=kin if usable else None,
        kinematic_reliable=usable,
        visual=centre + 0.3 * rng.normal(size=VISUAL_DIM),
        fps=30.0,
    )


def _records() -> list[RunResult]:
    rng = np.random.default_rng(0)
    return [
        _record(o, k, r, rng, usable=o != "ball")
        for o, k in (("box", "translation"), ("boat", "rotation"), ("ball", "roll"))
        for r in range(3)
    ]


def test_a1_report_on_records_with_known_clusters():
    rep = a1_kinematic.report(_records(), RunSet(), 0)
    space = rep.metrics["motion_space"]
    assert space["labels"] == ["translation"] * 3 + ["rotation"] * 3 and space["motion_loo_accuracy"] == 1.0
    assert rep.metrics["rigid"] == {
        "runs": 6,
        "runs_meeting": 6,
        "estimated_fraction_min": 1.0,
        "trans_err_cm_worst_run": 0.1,
        "rot_err_deg_worst_run": 0.5,
    }
    assert rep.target("ball_usable_trajectories").value == 0 and rep.target("ball_usable_trajectories").met
    pca = rep.figures["motion_pca"].axes[0]
    assert len(pca.collections) == 6 and pca.get_xlabel().startswith("PC1")
    filled = [c.get_facecolor()[0][3] for c in pca.collections]
    assert filled == [1.0] * 6  # every box and boat trajectory usable: no hollow markers


def test_a2_and_a3_on_records_with_known_clusters():
    records = _records()
    rep2 = a2_visual.report(records, RunSet(), 0)
    m2 = rep2.metrics
    assert (
        m2["loo_accuracy"] == 1.0 and m2["nearest_own_prototype"] == 1.0 and m2["nearest_own_count"] == [9, 9]
    )
    assert m2["prototype_support"] == {"ball": 3, "boat": 3, "box": 3}
    assert [r["nearest"] for r in m2["records"]] == [r.object for r in records]
    assert rep2.target("loo_accuracy").met and rep2.target("nearest_own_prototype").value == 1.0
    summary = next(t for t in rep2.tables if t.title == "A2 against the thesis")
    assert summary.rows[0][2].startswith("4 of 5") and summary.rows[0][3] == "9 of 9"
    assert len(rep2.figures["visual_pca"].axes[0].collections) == 9
    with pytest.raises(ValueError, match="at least 2 visual records"):
        a2_visual.report(records[:1], RunSet(), 0)

    rep3 = a3_multidomain.report(records, RunSet(), 0)
    m3 = rep3.metrics
    domains = {e["name"]: e["domains"] for e in m3["entities"]}
    assert domains["box-translation/0"] == ["motion", "visual"] and domains["ball-roll/0"] == ["visual"]
    assert m3["coverage"] == {
        "entities": 9,
        "both": 6,
        "visual_only": 3,
        "motion_only": 0,
        "strict_pairs": 15,
    }
    ball = next(e for e in m3["entities"] if e["name"] == "ball-roll/0")
    assert ball["strict_nearest"] is None and ball["shared_nearest"]["domains"] == ["visual"]
    box = next(e for e in m3["entities"] if e["name"] == "box-translation/0")
    assert box["strict_nearest"]["entity"].startswith("box-translation")
    assert m3["shared_nearest_same_object"] == [9, 9]
    cov = next(t for t in rep3.tables if t.title == "A3 against the thesis")
    assert cov.rows[0] == ("entities", 5, 9) and cov.rows[4] == (
        "pairs comparable strictly over both domains",
        1,
        15,
    )
    heat = np.ma.filled(rep3.figures["strict_distances"].axes[0].images[0].get_array(), np.nan)
    assert heat.shape == (9, 9) and np.isnan(heat[0, 0]) and np.isnan(heat[0, -1]) and heat[0, 1] > 0
    space = a3_multidomain.conceptual_space()
    entities = a3_multidomain.build_entities(records, space)
    with pytest.raises(ValueError, match="required domain 'motion' is missing"):
        space.distance(entities[0], entities[-1], ("motion", "visual"))


def test_concept_helpers():
    X = np.array([[0.0, 0.0, 10.0], [0.1, 0.0, 11.0], [5.0, 5.0, 0.0], [5.1, 5.0, 0.5]])
    labels = ["a", "a", "b", "b"]
    fam = {"t": slice(0, 2), "r": slice(2, 3)}
    scaled = FamilyScaler(fam).fit_transform(X)
    assert np.sqrt(np.mean(np.sum(scaled[:, :2] ** 2, axis=1))) == pytest.approx(1.0)
    assert leave_one_out(X, labels, lambda: FamilyScaler(fam)) == labels
    assert leave_one_out(X, ["a", "a", "b", "c"], lambda: FamilyScaler(fam))[3] is None  # no other "c"
    assert loo_accuracy(["a", None], ["a", "b"]) == 0.5
    dists, support = prototype_distances(X, labels, lambda: FamilyScaler(fam))
    raw, _ = prototype_distances(X, labels, None)
    assert support == {"a": 2, "b": 2} and dists[0]["a"] < dists[0]["b"]
    assert raw[0]["a"] == pytest.approx(np.linalg.norm(X[0] - X[:2].mean(axis=0)))
    Z, ev = pca_2d(X)
    assert Z.shape == (4, 2) and 0.9 < ev.sum() <= 1.0 + 1e-12 and ev[0] >= ev[1]
    with pytest.raises(ValueError, match="partition"):
        FamilyScaler({"t": slice(0, 2)}).fit(X)


def test_evaluate_sequence_needs_ground_truth(tmp_path):
    cam = SyntheticCamera(64, 48)
    with SequenceWriter(tmp_path / "s", metadata={"object": "box"}) as w:
        w.append(cam.render([], 0.0))
    with pytest.raises(ValueError, match="ground-truth masks and poses"):
        evaluate_sequence(RecordedSequence(tmp_path / "s"), PipelineConfig())


@pytest.mark.render
@pytest.mark.slow
def test_bench_perception_tiny(tiny_run):
    rep = tiny_run("bench", "perception").report
    m = rep.metrics
    assert m["frames"] == 3 and (m["width"], m["height"]) == (160, 120) and m["limits"]["opencv_threads"] == 1
    assert m["ratio_no_pose"] == pytest.approx(m["fps_no_pose"] / m["render_fps"])
    assert m["fps_no_pose"] == pytest.approx(3 / m["seconds_per_call"]["no_pose"])
    assert "pose" in m["stage_ms"]["with_pose"] and m["stage_ms"]["with_pose"]["pose"] > m["stage_ms"][
        "no_pose"
    ].get("pose", 0.0)
    # the real frames: 2 of each sample, every stage timed, and scored
    assert m["real_frames"] == 4 and m["fps_real"] == pytest.approx(4 / m["seconds_per_call"]["real"])
    assert set(m["stage_ms"]["real"]) >= {"segmentation", "camera_motion", "pose", "relations"}
    assert m["real"]["support_checks"] == 4 and m["real"]["total"]["seen_in_both"] > 5
    assert [t.name for t in rep.targets] == [
        "fps_no_pose",
        "fps_with_pose",
        "fps_real",
        "real_pose_fraction",
        "real_rot_err_deg",
        "real_trans_err_m",
        "real_wrong_estimated",
        "real_ids_kept",
        "real_support_plane",
        *(
            f"seq_s3_{k}"
            for k in ("pose_fraction", "rot_err_deg", "trans_err_m", "wrong_estimated", "ids_kept")
        ),
    ]
    assert m["sequence"]["stride_3"]["frames"] == 2 and rep.target("seq_s3_wrong_estimated").value == 0
    assert (
        rep.target("fps_with_pose").value == m["fps_with_pose"]
        and rep.target("fps_with_pose").threshold == 10
    )
    assert rep.target("fps_real").threshold == 15 and rep.target("real_support_plane").met
    assert rep.target("real_wrong_estimated").value == 0
    throughput = rep.tables[0]
    assert [r[0] for r in throughput.rows] == [
        "render (baseline)",
        "Pi without pose",
        "Pi with pose",
        "Pi with pose and relations, real frames",
        "the same, CPU time of the process",
    ]
    # CPU seconds of the process never exceed the wall-clock seconds by more than timer noise
    assert m["fps_real_cpu"] == pytest.approx(4 / throughput.rows[4][1])
    assert m["fps_real_cpu"] >= 0.9 * m["fps_real"]
    assert throughput.rows[0][3] == 1.0 and throughput.rows[2][2] == m["fps_with_pose"]
    pairs = rep.tables[2]
    assert [r[0] for r in pairs.rows] == ["tum_desk", "kinect_room"] and pairs.rows[0][1] == "1-2"
    stages = rep.tables[-1]
    assert stages.title.startswith("Static sequence: median milliseconds") and list(stages.columns) == [
        "stage",
        "stride 3",
    ]
    assert {r[0] for r in stages.rows} >= {"pose", "segmentation"} and stages.rows[-1][1] > 0


#: perception-sequence's per-stride targets and the result each one reports.
SEQUENCE_TARGETS = {
    "pose_fraction": "pose_fraction",
    "rot_err_deg": "rot_err_deg_median",
    "trans_err_m": "trans_err_m_median",
    "wrong_estimated": "wrong_estimated",
    "ids_kept": "kept_fraction",
}


def test_perception_sequence_tiny_reports_both_strides_and_their_targets(tiny_run):
    rep = tiny_run("experiment", "perception-sequence").report
    m = rep.metrics
    assert list(m) == ["stride_1", "stride_3"] and [m[k]["stride"] for k in m] == [1, 3]
    assert [m[k]["frames"] for k in m] == [4, 2] and "strides [1, 3]" in rep.notes[0]
    assert [row[0] for row in rep.tables[0].rows] == [1, 3]
    assert list(rep.tables[1].columns) == ["stage", "stride 1", "stride 3"]
    assert [t.name for t in rep.targets] == [
        *(f"seq_s1_{k}" for k in SEQUENCE_TARGETS),
        "seq_s1_rot_beats_still",
        "seq_s1_fps_cpu",
        *(f"seq_s3_{k}" for k in SEQUENCE_TARGETS),
    ]
    for s in (1, 3):
        for name, key in SEQUENCE_TARGETS.items():
            assert rep.target(f"seq_s{s}_{name}").value == pytest.approx(m[f"stride_{s}"][key], abs=1e-12)
    assert rep.target("seq_s1_rot_beats_still").value == pytest.approx(
        m["stride_1"]["rot_better_than_still"], abs=1e-12
    )
    assert rep.target("seq_s1_fps_cpu").value == pytest.approx(m["stride_1"]["fps_cpu"], rel=1e-12)
    # both strides pose objects seen in both frames: every precondition holds and every verdict
    # is the comparison with the threshold
    for t in rep.targets:
        assert t.evaluated and t.verdict == ("met" if t.met else "not met"), t.name
    assert rep.target("seq_s1_wrong_estimated").verdict == "met"


def test_perception_sequence_targets_are_not_evaluated_without_posed_or_seen_objects():
    nothing = {
        "with_pose": 0,
        "seen_in_both": 0,
        "pose_fraction": None,
        "rot_err_deg_median": None,
        "trans_err_m_median": None,
        "wrong_estimated": 0,
        "kept_fraction": None,
        "rot_better_than_still": None,
        "fps_cpu": 20.0,
    }
    seen_unposed = {**nothing, "seen_in_both": 4, "pose_fraction": 0.0, "kept_fraction": 1.0}
    verdicts = {
        t.name: t.verdict for t in perception_sequence.sequence_targets({1: seen_unposed, 3: nothing})
    }
    assert verdicts == {
        "seq_s1_pose_fraction": "not met",
        "seq_s1_rot_err_deg": "not evaluated",
        "seq_s1_trans_err_m": "not evaluated",
        "seq_s1_wrong_estimated": "not evaluated",
        "seq_s1_ids_kept": "met",
        "seq_s1_rot_beats_still": "not evaluated",
        "seq_s1_fps_cpu": "met",
        **{f"seq_s3_{k}": "not evaluated" for k in SEQUENCE_TARGETS},
    }


@pytest.mark.render
@pytest.mark.slow
def test_cli_runs_a1_quick_as_json(capsys):
    sets = ["runs.width=160", "runs.height=120", "runs.fps=3"]
    assert main(["experiment", "a1", "--quick", "--json", *[a for s in sets for a in ("--set", s)]]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["name"] == "a1" and doc["kind"] == "experiment" and doc["seed"] == 0
    assert (
        doc["config"]["runs"]["motions"] == ["box-rotation", "ball-roll"]
        and doc["config"]["runs"]["width"] == 160
    )
    assert [r["motion"] for r in doc["metrics"]["runs"]] == ["box-rotation", "ball-roll"]
    assert {t["name"]: t["met"] for t in doc["targets"]}["ball_usable_trajectories"] is True
    assert set(doc["figures"]) == {"trajectories", "pose_error"}
    assert main(["experiment", "a1", "--quick", "--set", "runs.per_motion=0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "per_motion must be a positive int, got 0" in err
