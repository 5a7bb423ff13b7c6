"""``pal sweep``: grid × seeds of a registered experiment, mean ± sd table, figures, failed runs retried."""

from __future__ import annotations

import csv
import json
import logging
import math
import os
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import pytest

from pal.cli import main
from pal.lab import registry, sweep
from pal.lab.registry import Entry
from pal.lab.report import Report, Target


@dataclass(frozen=True)
class FakeConfig:
    """A config whose run fails for chosen seeds (listed in a file)."""

    seed: int = 0
    scale: float = 1.0
    fail_file: str = ""


def _fake_run(config: FakeConfig, progress_bar: bool = False) -> Report:
    """Metric = scale * (seed + 1): an oracle for the table; fails for the seeds in fail_file."""
    if config.fail_file:
        with open(config.fail_file) as fh:
            if str(config.seed) in fh.read().split():
                raise RuntimeError(f"seed {config.seed} exploded\nsecond line of the traceback text")
    value = config.scale * (config.seed + 1)
    return Report(
        "fake",
        metrics={"value": value, "nested": {"double": 2 * value}, "flag": True, "series": [1.0, 2.0]},
        targets=[Target("value_small", value, 10.0, "<=", "the value")],
    )


@pytest.fixture
def fake(monkeypatch, tmp_path):
    registry.entries()
    entry = Entry("sweep_fake", "experiment", FakeConfig, FakeConfig(), FakeConfig(), _fake_run, "fake")
    monkeypatch.setitem(registry._REGISTRY, ("experiment", "sweep_fake"), entry)
    fail_file = tmp_path / "fail.txt"
    fail_file.write_text("1")
    return fail_file


def test_table_holds_mean_and_sd_per_cell_and_failed_runs_are_reported_then_retried(fake, tmp_path, capsys):
    out = tmp_path / "sweep"
    argv = ["sweep", "sweep_fake", "--grid", "scale=1,3", "--seeds", "0-2", "--set", f"fail_file={fake}"]
    assert main([*argv, "--out", str(out)]) == 1  # a failed run: exit 1, reported
    text = capsys.readouterr().out
    assert "2 failed" in text and "RuntimeError: seed 1 exploded" in text and "second line" not in text
    assert sorted(p.name for p in (out / "runs").glob("*.error.json")) == [
        "r001.error.json",
        "r004.error.json",
    ]
    rows = list(csv.DictReader((out / "summary.csv").open()))
    by = {(r["scale"], r["metric"]): r for r in rows}
    # scale 3, seeds 0 and 2 finished: values 3 and 9 -> mean 6, sd sqrt(18)
    assert by[("3", "value")]["n"] == "2"
    assert float(by[("3", "value")]["mean"]) == pytest.approx(6.0, abs=1e-12)
    assert float(by[("3", "value")]["sd"]) == pytest.approx(math.sqrt(18.0), abs=1e-12)
    assert float(by[("1", "nested.double")]["mean"]) == pytest.approx(4.0, abs=1e-12)
    assert float(by[("1", "target.value_small")]["mean"]) == pytest.approx(2.0, abs=1e-12)
    assert float(by[("1", "met.value_small")]["mean"]) == 1.0  # share of runs that met it
    assert ("1", "flag") not in by and ("1", "series") not in by  # bools and lists are not summarised
    assert (out / "value_small.png").read_bytes()[:4] == b"\x89PNG"
    md = (out / "summary.md").read_text()
    assert "| finished runs | 2/3 | 2/3 |" in md and "### Failed runs" in md and "6 ± 4.2" in md

    assert main([*argv, "--out", str(out)]) == 2  # an existing sweep is not overwritten
    assert "already holds a sweep" in capsys.readouterr().err

    fake.write_text("")  # the cause is fixed: retry only the two failed runs
    before = (out / "runs" / "r000.json").read_bytes()
    assert main(["sweep", "sweep_fake", "--retry-failed", "--out", str(out)]) == 0
    assert "0 failed" in capsys.readouterr().out
    assert (out / "runs" / "r000.json").read_bytes() == before  # finished runs are kept, not re-run
    assert not list((out / "runs").glob("*.error.json"))
    rows = {(r["scale"], r["metric"]): r for r in csv.DictReader((out / "summary.csv").open())}
    assert rows[("3", "value")]["n"] == "3"
    assert float(rows[("3", "value")]["mean"]) == pytest.approx(6.0, abs=1e-12)  # 3, 6, 9
    assert float(rows[("3", "value")]["sd"]) == pytest.approx(3.0, abs=1e-12)


def test_retry_refuses_a_different_sweep(fake, tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main(["sweep", "sweep_fake", "--grid", "scale=1,2", "--seeds", "0", "--out", str(out)]) == 0
    capsys.readouterr()
    assert (
        main(
            [
                "sweep",
                "sweep_fake",
                "--grid",
                "scale=1,5",
                "--seeds",
                "0",
                "--retry-failed",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "holds a different sweep" in err


@pytest.mark.parametrize(
    ("text", "seeds"), [("0-2", (0, 1, 2)), ("4", (4,)), ("0,3,7", (0, 3, 7)), ("0-1,5", (0, 1, 5))]
)
def test_seeds_parse(text, seeds):
    assert sweep.parse_seeds(text) == seeds


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("5-2", "runs backwards"),
        ("a", "is not N or FIRST-LAST"),
        ("1,1", "given twice"),
        ("0-1000000000000", r"seeds must be in \[0, 4294967295\], got 1000000000000"),
        ("-3", "is not N or FIRST-LAST|seeds must be in"),
        ("0-10000", "more than 10000 seeds"),
        ("0-9998,0", r"seeds \[0\] given twice"),
        ("1" * 20_000, "20000 characters, the limit is 10000"),
    ],
)
def test_bad_seeds_are_refused(text, message):
    with pytest.raises(sweep.SweepError, match=message):
        sweep.parse_seeds(text)


def test_grid_values_keep_json_lists_and_are_checked_against_the_config():
    base = registry.get("experiment", "spring").tiny
    assert sweep.parse_grid(["schedule.epochs=1,2"], base) == (("schedule.epochs", (1, 2)),)
    with pytest.raises(sweep.SweepError, match=r"'nope' is not a config field; valid: \['transitions'"):
        sweep.parse_grid(["nope=1"], base)
    with pytest.raises(sweep.SweepError, match="epochs must be a positive int, got 0"):
        sweep.parse_grid(["schedule.epochs=1,0"], base)
    assert sweep._split_values("1,[2,3],x") == ["1", "[2,3]", "x"]


@pytest.fixture(scope="module")
def spring_sweep(tmp_path_factory):
    """2 configs x 2 seeds of the spring experiment's tiny config, in this process."""
    out = tmp_path_factory.mktemp("spring") / "sweep"
    plan = sweep.plan("spring", ["schedule.epochs=1,2"], "0-1", base="tiny")
    return sweep.run_sweep(plan, out)


@pytest.mark.slow
def test_a_real_experiment_2_configs_x_2_seeds_gives_one_table_and_a_figure_per_target(spring_sweep):
    result = spring_sweep
    out = result.paths["manifest"].parent
    assert not result.failed and len(result.ran) == 4
    targets = {t["name"] for t in json.loads((out / "runs" / "r000.json").read_text())["targets"]}
    assert targets == {"q_mse_ratio", "realized_mae_state", "curiosity_entropy_gain"}
    for name in targets:
        assert result.paths[name].read_bytes()[:4] == b"\x89PNG", name
    rows = list(csv.DictReader((out / "summary.csv").open()))
    cells = {r["schedule.epochs"] for r in rows}
    assert cells == {"1", "2"}
    for name in targets:
        for epochs in cells:
            row = next(r for r in rows if r["schedule.epochs"] == epochs and r["metric"] == f"target.{name}")
            assert row["n"] == "2" and math.isfinite(float(row["mean"])) and float(row["sd"]) >= 0
    # each cell's mean is the mean of its two run reports
    docs = [json.loads((out / "runs" / f"r{i:03d}.json").read_text()) for i in range(2)]
    assert [d["config"]["schedule"]["epochs"] for d in docs] == [1, 1]
    assert [d["seed"] for d in docs] == [0, 1]
    value = [next(t["value"] for t in d["targets"] if t["name"] == "q_mse_ratio") for d in docs]
    row = next(r for r in rows if r["schedule.epochs"] == "1" and r["metric"] == "target.q_mse_ratio")
    assert float(row["mean"]) == pytest.approx(sum(value) / 2, rel=1e-12)
    assert "| finished runs | 2/2 | 2/2 |" in (out / "summary.md").read_text()


@pytest.mark.slow
def test_two_local_workers_give_the_same_reports_as_one_process(spring_sweep, tmp_path, caplog, capfd):
    caplog.set_level(logging.INFO)  # the workers log at the sweep's level, to their (inherited) stderr
    plan = sweep.plan("spring", ["schedule.epochs=1"], "0-1", base="tiny")
    result = sweep.run_sweep(plan, tmp_path / "par", workers=2)
    assert not result.failed
    assert capfd.readouterr().err.count("INFO pal.lab.runner: experiment spring took") == 2
    serial = spring_sweep.paths["manifest"].parent / "runs"
    for i in range(2):
        a = json.loads((tmp_path / "par" / "runs" / f"r{i:03d}.json").read_text())
        b = json.loads((serial / f"r{i:03d}.json").read_text())
        assert a["config"] == b["config"] and a["targets"] == b["targets"] and a["metrics"] == b["metrics"]


def test_a_not_evaluated_target_counts_as_not_met_and_its_value_is_left_out():
    from pal.lab.report import Precondition
    from pal.lab.sweep_summary import _values

    targets = [
        Target("ratio", 1.0, 1.0, "<=", "r", Precondition(False, "something moved")).to_dict(),
        Target("mse", 0.1, 1.0, "<=", "m").to_dict(),
        Target("gap", None, 1.0, "<=", "g").to_dict(),
    ]
    values = _values({"metrics": {}, "targets": targets, "seconds": 1.0})
    assert "target.ratio" not in values and values["met.ratio"] == 0.0
    assert values["target.mse"] == 0.1 and values["met.mse"] == 1.0 and values["met.gap"] == 0.0


def _blocking_entry(monkeypatch, release: threading.Event) -> None:
    def run(config: FakeConfig, progress_bar: bool = False) -> Report:
        release.wait(10.0)  # holds the sweep (and its lock) until the other start has been answered
        return _fake_run(config)

    registry.entries()
    entry = Entry("sweep_block", "experiment", FakeConfig, FakeConfig(), FakeConfig(), run, "blocks")
    monkeypatch.setitem(registry._REGISTRY, ("experiment", "sweep_block"), entry)


def test_two_sweeps_started_at_once_on_one_directory_run_one_and_refuse_the_other(monkeypatch, tmp_path):
    release = threading.Event()
    _blocking_entry(monkeypatch, release)
    plan = sweep.plan("sweep_block", [], "0")
    for attempt in range(20):
        out = tmp_path / f"s{attempt}"
        release.clear()
        barrier = threading.Barrier(2)
        results: list[object] = []

        def start(out=out, barrier=barrier, results=results) -> None:
            barrier.wait()
            try:
                results.append(sweep.run_sweep(plan, out))
            except sweep.SweepError as err:
                results.append(err)
                release.set()

        threads = [threading.Thread(target=start) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(30.0)
        errors = [r for r in results if isinstance(r, sweep.SweepError)]
        assert len(results) == 2 and len(errors) == 1, results
        message = str(errors[0])
        assert f"--out {str(out)!r}: another sweep runs in it" in message
        assert f"is being written by pid {os.getpid()}" in message
        assert not (out / "writer.lock").exists()  # released by the sweep that ran
        assert len(json.loads((out / "sweep.json").read_text())["runs"]) == 1


_SWEEP_PROCESS = """
import sys, time
from pal.lab import registry, sweep
from pal.lab.registry import Entry
from pal.lab.report import Report
from tests.pal.lab.test_sweep import FakeConfig, _fake_run

def run(config, progress_bar=False):
    time.sleep(3.0)
    return _fake_run(config)

registry._LOADED = True  # this entry alone: no scan of the experiments
registry._REGISTRY[("experiment", "sweep_slow")] = Entry(
    "sweep_slow", "experiment", FakeConfig, FakeConfig(), FakeConfig(), run, "slow")
try:
    sweep.run_sweep(sweep.plan("sweep_slow", [], "0"), sys.argv[1])
except sweep.SweepError as err:
    print(err, file=sys.stderr)
    sys.exit(2)
"""


def test_a_second_sweep_process_on_the_same_directory_is_refused_naming_the_holder(tmp_path):
    out = tmp_path / "sweep"
    root = Path(__file__).resolve().parents[3]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _SWEEP_PROCESS, str(out)], env=env, stderr=subprocess.PIPE, text=True
        )
        for _ in range(2)
    ]
    answers = sorted((p.wait(120), p.stderr.read()) for p in procs)
    assert [code for code, _ in answers] == [0, 2], answers
    holder = next(p.pid for p in procs if p.returncode == 0)
    assert f"--out {str(out)!r}: another sweep runs in it" in answers[1][1]
    assert f"pid {holder}" in answers[1][1]


@dataclass(frozen=True)
class PooledConfig:
    """A config whose pooled run reports the sum of its seeds' values (``first`` .. ``first + n - 1``)."""

    seed: int = 0
    n: int = 1
    broken: bool = False


def _pooled_run(config: PooledConfig, progress_bar: bool = False) -> Report:
    if config.broken and config.n > 1:
        raise RuntimeError("the pooled run broke")
    total = sum(s + 1 for s in range(config.seed, config.seed + config.n))
    return Report("pooled fake", metrics={"total": total, "n": config.n})


def _pool(config: PooledConfig, seeds: tuple[int, ...]) -> PooledConfig:
    if seeds[0] != 0:
        raise ValueError(f"seeds must start at 0, got {list(seeds)}")
    return PooledConfig(seed=seeds[0], n=len(seeds), broken=config.broken)


@pytest.fixture
def pooled_fake(monkeypatch):
    registry.entries()
    entry = Entry(
        "pool_fake", "experiment", PooledConfig, PooledConfig(), PooledConfig(), _pooled_run, "fake", _pool
    )
    monkeypatch.setitem(registry._REGISTRY, ("experiment", "pool_fake"), entry)


def test_an_entry_with_a_pool_gets_one_report_over_all_the_sweeps_seeds(pooled_fake, tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main(["sweep", "pool_fake", "--seeds", "0-3", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    doc = json.loads((out / "pooled" / "pool_fake.json").read_text())
    assert doc["metrics"] == {"total": 1 + 2 + 3 + 4, "n": 4}  # one run over the 4 seeds
    assert doc["config"] == {"seed": 0, "n": 4, "broken": False}
    assert "pooled fake" in text and "pooled" + os.sep + "pool_fake.md" in text
    assert len(list((out / "runs").glob("r*.json"))) == 4  # the per-seed runs as before


def test_a_sweep_its_pool_refuses_is_refused_before_any_run_and_a_failed_pool_is_listed(
    pooled_fake, tmp_path, capsys
):
    out = tmp_path / "refused"
    assert main(["sweep", "pool_fake", "--seeds", "1-2", "--out", str(out)]) == 2
    assert "its pooled report: seeds must start at 0, got [1, 2]" in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())
    broken = tmp_path / "broken"
    assert main(["sweep", "pool_fake", "--seeds", "0-1", "--set", "broken=true", "--out", str(broken)]) == 1
    result = sweep.summarise(sweep._read_plan(broken), broken)  # the runs themselves are fine
    assert not result.failed and len(list((broken / "runs").glob("r*.json"))) == 2
    assert not (broken / "pooled" / "pool_fake.json").exists()
    assert "RuntimeError: the pooled run broke" in capsys.readouterr().out
