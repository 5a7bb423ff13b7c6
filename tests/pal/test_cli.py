"""The ``pal`` command: the demo, and one-line usage errors (exit 2) before any work starts."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

import pal.lab.runner as runner
from pal.cli import main


# the quick agents' state estimates run few SVI steps on purpose
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
@pytest.mark.slow
def test_demo_quick_writes_every_report_and_the_target_table(tmp_path, capsys, caplog):
    caplog.set_level(logging.INFO)  # as a bare interpreter would after basicConfig(INFO): the demo lowers it
    assert main(["demo", "--quick", "--out", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "INFO" not in out + captured.err and "INFO" not in caplog.text  # quiet without -v
    assert not [r for r in caplog.records if r.levelno < logging.WARNING]
    assert "pal demo: experiment queries (1/6) ..." in captured.err
    assert "## Causal queries on X -> Y -> Z against closed forms" in out
    assert "## pal demo: every target and its verdict" in out
    summary = json.loads((tmp_path / "demo.json").read_text())
    names = [r["name"] for r in summary["runs"]]
    assert names == ["queries", "spring", "b1", "b2", "a1", "loop"]
    rows = summary["targets"]["rows"]
    assert len(rows) == sum(len(r["targets"]) for r in summary["runs"])
    assert {r[-1] for r in rows} <= {"met", "**NOT met**", "not measured", "not evaluated"}
    assert sum(summary["verdicts"].values()) == len(rows)
    queries = summary["runs"][0]
    exact = next(t for t in queries["targets"] if t["name"] == "exact_counterfactual_error")
    assert exact["met"] is True and exact["value"] <= 1e-5
    for name in names:
        assert (tmp_path / f"{name}.json").is_file() and (tmp_path / f"{name}.md").is_file()
    for png in ("spring_action_inference.png", "b2_fig5_6.png", "spring_curiosity.png"):
        assert (tmp_path / png).read_bytes()[:4] == b"\x89PNG", png
    assert (tmp_path / "loop.mp4").stat().st_size > 0


def test_list_names_every_entry(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ("b1", "queries", "loop", "c2", "discovery", "counterfactual"):
        assert f" {name} " in out


def test_tiny_runs_the_entrys_tiny_config(capsys):
    from pal.lab.configs import to_dict
    from pal.lab.registry import get

    assert main(["experiment", "queries", "--tiny", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (
        doc["config"]
        == to_dict(get("experiment", "queries").tiny)
        != to_dict(get("experiment", "queries").quick)
    )
    with pytest.raises(ValueError, match="choose one of quick and tiny"):
        runner.configure(get("experiment", "queries"), quick=True, tiny=True)


@pytest.fixture
def a_file(tmp_path) -> Path:
    path = tmp_path / "taken"
    path.write_text("not a directory")
    return path


#: (argv, text the one-line message must contain); ``{file}`` is an existing regular file.
BAD_INVOCATIONS = [
    ([], "required: command"),
    (["nope"], "invalid choice: 'nope'"),
    (["experiment"], "required: name"),
    (["experiment", "nope"], "unknown experiment 'nope'"),
    (["bench", "nope"], "unknown bench 'nope'"),
    (["--threads", "0", "list"], "--threads must be >= 1 and <= 1024, got 0"),
    (["--threads", str(10**20), "list"], f"--threads must be >= 1 and <= 1024, got {10**20}"),
    (["--threads", "x", "list"], "invalid int value: 'x'"),
    (["experiment", "b1", "--set"], "expected one argument"),
    (["experiment", "b1", "--set", "seed"], "--set 'seed': expected KEY=VALUE"),
    (["experiment", "b1", "--set", "nope=1"], "unknown setting 'nope'"),
    (["experiment", "b1", "--set", "seed=abc"], "seed: 'abc' is not an int"),
    (["experiment", "b1", "--set", "protocol.fit.schedule.epochs=0"], "epochs must be a positive int, got 0"),
    (["experiment", "b1", "--set", "protocol.fit=3"], "protocol.fit|fit is a group of settings"),
    (["experiment", "b1", "--set", "protocol.fit.epochs=40"], "unknown setting 'epochs'"),
    (["experiment", "b1", "--set", 'protocol.graphs=["fancy"]'], "graphs ['fancy'] invalid"),
    (["experiment", "b1", "--set", "protocol.split=1.5"], "split must be < 1.0, got 1.5"),
    (["experiment", "b2", "--set", "targets=-3"], "targets must be a positive int, got -3"),
    (["experiment", "b1", "--body", "hand"], "unknown body 'hand'"),
    (["experiment", "b1", "--joint", "a", "--joint", "b"], "--joint given 2 times"),
    (["bench", "svi", "--mjcf", "x.xml"], "--mjcf: pal bench svi has no body setting"),
    (["experiment", "queries", "--body", "arm"], "--body: pal experiment queries has no body setting"),
    (["experiment", "b1", "--out", "{file}"], "is a file, expected a directory"),
    (["experiment", "b1", "--out", "{file}/sub"], "is a file, expected a directory"),
    (["bench", "action", "--out", "{file}"], "is a file, expected a directory"),
    (["demo", "--out", "{file}"], "is a file, expected a directory"),
    (["babble", "--steps", "10"], "required: --out"),
    (["babble", "--out", "{file}"], "is a file, expected a dataset directory"),
    (["babble", "--body", "finger", "--mjcf", "x.xml", "--out", "d"], "either --body or --mjcf"),
    (["babble", "--policy", "wild", "--out", "d"], "invalid choice: 'wild'"),
    (["babble", "--steps", "x", "--out", "d"], "argument --steps: 'x' is not an int"),
    (["babble", "--action-range", "finger", "--out", "d"], "is not NAME=LOW,HIGH"),
    (["experiment", "b1", "--frame-skip", "0"], "frame_skip must be a positive int, got 0"),
    (["experiment", "b1", "--action-range", "finger=-2,0"], "outside the ctrlrange [-1.0, 0.33]"),
    (["experiment", "b1", "--joint", "elbow"], "unknown joint 'elbow'"),
    (["bench", "babble", "--dataset", "d"], "--dataset: pal bench babble has no dataset setting"),
    (
        ["experiment", "queries", "--frame-skip", "5"],
        "--frame-skip: pal experiment queries has no body setting",
    ),
    (["record", "--out", "d"], "required: --motion"),
    (["record", "--motion", "dance", "--out", "d"], "dance"),
    (["loop", "--goal", "1"], "--goal '1': expected two numbers"),
    (["loop", "--goal", "a,b"], "--goal 'a,b': expected X,Y in metres"),
    (["loop", "--video", "x.avi"], "--video 'x.avi': expected a path ending in .mp4"),
    (["loop", "--steps", "0"], "steps must be an int in [1, 100000], got 0"),
    (["loop", "--steps", str(10**15)], f"steps must be an int in [1, 100000], got {10**15}"),
    (["loop", "--out", "{file}"], "is a file, expected a directory"),
    (["list", "--bogus"], "unrecognized arguments: --bogus"),
    (["sweep", "queries", "--seeds", "5-2", "--out", "d"], "--seeds '5-2': range '5-2' runs backwards"),
    (["sweep", "queries", "--seeds", "x", "--out", "d"], "--seeds 'x': 'x' is not N or FIRST-LAST"),
    (["sweep", "nope", "--out", "d"], "unknown experiment 'nope'"),
    (
        ["sweep", "queries", "--grid", "nope=1,2", "--out", "d"],
        "'nope' is not a config field; valid: ['num_samples'",
    ),
    (["sweep", "queries", "--grid", "num_samples", "--out", "d"], "expected KEY=V1,V2"),
    (["sweep", "queries", "--grid", "num_samples=50,5", "--out", "d"], "num_samples"),
    (["sweep", "queries", "--grid", "seed=1,2", "--out", "d"], "give the seeds with --seeds"),
    (["sweep", "queries", "--workers", "0", "--out", "d"], "--workers must be >= 1, got 0"),
    (["sweep", "queries", "--ray-address", "127.0.0.1:1", "--out", "d"], "--ray-address needs --engine ray"),
    (["sweep", "queries", "--retry-failed", "--out", "d"], "holds no sweep"),
    (["sweep", "queries", "--out", "{file}"], "is a file, expected a directory"),
    (["sweep", "queries", "--quick", "--tiny", "--out", "d"], "not allowed with argument"),
    (["experiment", "queries", "--quick", "--tiny"], "not allowed with argument"),
    # values past the documented limits: refused naming the flag and the value
    (
        ["experiment", "b1", "--set", f"protocol.fit.schedule.epochs={'[' * 5000}{']' * 5000}"],
        "nests 5000 levels",
    ),
    (["experiment", "b1", "--set", f"protocol.graphs={'x' * 20_000}"], "has 20000 characters; the limit is"),
    (["experiment", "b1", "--set", f"seed={2**70}"], f"--set 'seed={2**70}': seed: {2**70} is out of range"),
    (
        ["experiment", "b1", "--set", "seed=-1"],
        "--set 'seed=-1': seed must be an int in [0, 4294967295], got -1",
    ),
    (["experiment", "b1", "--set", f"protocol.data.steps={10**39}"], f"steps: {10**39} is out of range"),
    (
        ["experiment", "b1", "--set", f"protocol.data.steps={10**15}"],
        "steps must be an int in [10, 100000000]",
    ),
    (["experiment", "b1", "--set", f"protocol.data.steps={'9' * 5000}"], "protocol.data.steps=99999"),
    (["record", "--motion", "box-rotation", "--fps", "inf", "--out", "d"], "--fps: 'inf' is not a finite"),
    (["record", "--motion", "box-rotation", "--fps", "nan", "--out", "d"], "--fps: 'nan' is not a finite"),
    (["record", "--motion", "box-rotation", "--fps", "0", "--out", "d"], "--fps: '0' is not a finite number"),
    (["record", "--motion", "box-rotation", "--seed", "-1", "--out", "d"], "--seed: -1 is not an int in"),
    (
        ["record", "--motion", "box-rotation", "--depth-noise", "inf", "--out", "d"],
        "depth_noise must be finite",
    ),
    (
        ["record", "--motion", "box-rotation", "--rgb-noise", "-1", "--out", "d"],
        "rgb_noise must be >= 0.0, got -1",
    ),
    (["record", "--motion", "box-rotation", "--out", ""], "argument --out: '' is empty"),
    (["sweep", "queries", "--seeds", "0-1000000000000", "--out", "d"], "got 1000000000000"),
    (["sweep", "queries", "--seeds", "0-99999", "--out", "d"], "--seeds '0-99999': more than 10000 seeds"),
    (["sweep", "queries", "--seeds", "0-9998,5", "--out", "d"], "--seeds '0-9998,5': seeds [5] given twice"),
    (["sweep", "queries", "--seeds", "9" * 5000, "--out", "d"], "is not N or FIRST-LAST"),
    (
        ["sweep", "queries", "--grid", f"num_samples={'[' * 100}", "--out", "d"],
        "--grid num_samples=...: value",
    ),
    (["sweep", "queries", "--out", ""], "argument --out: '' is empty"),
    (["babble", "--seed", "-1", "--out", "d"], "argument --seed: -1 is not an int in [0, 4294967295]"),
    (["babble", "--seed", str(2**70), "--out", "d"], f"argument --seed: {2**70} is not an int"),
    (
        ["babble", "--steps", str(10**15), "--out", "d"],
        f"argument --steps: {10**15} is not an int in [1, 100000000]",
    ),
    (["babble", "--steps", "10**15", "--out", "d"], "argument --steps: '10**15' is not an int"),
    (["babble", "--steps", "9" * 5000, "--out", "d"], "argument --steps: '9999"),
    (["babble", "--out", ""], "argument --out: '' is empty"),
    (
        ["babble", "--out", "{junk}"],
        "is a non-empty directory that is not a pal dataset (1 entry no dataset holds",
    ),
    (["loop", "--seed", "-1"], "argument --seed: -1 is not an int"),
    (["experiment", "b1", "--out", ""], "argument --out: '' is empty"),
    (["demo", "--out", " "], "argument --out: ' ' is empty"),
]


@pytest.fixture
def a_junk_dir(tmp_path) -> Path:
    path = tmp_path / "junk"
    path.mkdir()
    (path / "notes.txt").write_text("not a dataset")
    return path


@pytest.mark.parametrize(
    ("argv", "message"), BAD_INVOCATIONS, ids=[" ".join(a)[:80] or "<none>" for a, _ in BAD_INVOCATIONS]
)
def test_usage_errors_are_one_line_exit_2_before_any_work(
    argv, message, a_file, a_junk_dir, tmp_path, capsys, monkeypatch
):
    def no_run(*args, **kwargs):
        raise AssertionError("the run started although the command line is unusable")

    monkeypatch.setattr(runner, "execute", no_run)
    monkeypatch.chdir(tmp_path)
    argv = [a.replace("{file}", str(a_file)).replace("{junk}", str(a_junk_dir)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err, err
    assert err.startswith("pal"), err
    assert any(m in err for m in message.split("|")), (message, err)
    assert "Traceback" not in err
    if str(a_junk_dir) in argv:  # nothing written into the unrelated directory
        assert sorted(p.name for p in a_junk_dir.iterdir()) == ["notes.txt"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["babble", "--steps", "0", "--out", "d"], "steps"),
        (["babble", "--body", "hand", "--out", "d"], "'hand' does not exist"),
        (["babble", "--frame-skip", "0", "--out", "d"], "frame_skip"),
        (["babble", "--mjcf", "/nonexistent/body.xml", "--out", "d"], "/nonexistent/body.xml"),
        (["babble", "--action-range", "finger=-2,0", "--out", "d"], "outside the ctrlrange [-1.0, 0.33]"),
        (["babble", "--name", " ", "--out", "d"], "is not a usable name"),
        (["babble", "--actuator", "thumb", "--out", "d"], "unknown actuator name(s) ['thumb']"),
        (["record", "--motion", "box-rotation", "--width", "0", "--out", "d"], "width"),
    ],
)
def test_bad_body_and_recording_settings_are_refused_before_work(
    argv, message, tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err, err
    assert not (tmp_path / "d" / "chunk_000000.npz").exists()


def test_babble_refuses_an_existing_dataset_without_resume(tmp_path, capsys):
    out = str(tmp_path / "data")
    assert main(["babble", "--steps", "20", "--chunk-size", "10", "--out", out, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["rows"] == 20
    assert main(["babble", "--steps", "20", "--out", out]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "already holds a dataset" in err
