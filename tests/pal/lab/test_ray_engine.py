"""``--engine ray``: shards as Ray tasks and sweep runs as Tune trials give the local engine's results."""

from __future__ import annotations

import csv
import importlib
import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from pal.cli import main
from pal.lab import registry, sweep
from pal.lab.registry import Entry
from pal.lab.report import Report, Target
from pal.sim.babbling import BabbleConfig
from pal.sim.shards import babble_sharded

CONFIG = BabbleConfig(body="finger", seed=5, steps=23, frame_skip=5, reset_every=7, chunk_size=6)
NO_RAY = 'Ray is an optional extra: pip install -c constraints.txt ".[ray]"'


@dataclass(frozen=True)
class FailingConfig:
    """A config whose run fails for the scales listed in a file (the cause can be fixed)."""

    seed: int = 0
    scale: float = 1.0
    fail_file: str = ""


def _failing_run(config: FailingConfig, progress_bar: bool = False) -> Report:
    """Metric = scale * (seed + 1); raises for the scales listed in ``fail_file``."""
    with open(config.fail_file) as fh:
        if repr(config.scale) in fh.read().split():
            raise RuntimeError(f"scale {config.scale} exploded")
    value = config.scale * (config.seed + 1)
    return Report("failing", metrics={"value": value}, targets=[Target("small", value, 10.0, "<=", "value")])


@pytest.fixture
def failing(monkeypatch, tmp_path):
    """``ray_failing``: registered here and shipped to the Ray workers by value (no import there)."""
    ray = pytest.importorskip("ray", reason=NO_RAY)
    registry.entries()
    entry = Entry(
        "ray_failing", "experiment", FailingConfig, FailingConfig(), FailingConfig(), _failing_run, ""
    )
    monkeypatch.setitem(registry._REGISTRY, ("experiment", "ray_failing"), entry)
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    fail_file = tmp_path / "fail.txt"
    fail_file.write_text("2.0")
    yield fail_file
    ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def _descendants() -> dict[int, str]:
    """Command lines of this process's children and their children, by pid."""
    psutil = pytest.importorskip("psutil", reason="psutil lists child processes (installed with .[dev])")
    out = {}
    for p in psutil.Process().children(recursive=True):
        try:
            out[p.pid] = " ".join(p.cmdline())
        except psutil.Error:  # ended meanwhile
            pass
    return out


def test_a_silent_address_times_out_in_one_line_and_leaves_no_process(tmp_path, capsys):
    """A port that accepts TCP but never speaks Ray: the probe's child is killed at the timeout."""
    ray = pytest.importorskip("ray", reason=NO_RAY)
    # Ray, Tune and the registry are imported first: the clock times the connection, not the
    # imports (a few seconds on a busy machine).
    importlib.import_module("pal.lab.ray_engine")
    registry.entries()

    was_up, before = ray.is_initialized(), _descendants()
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        address = f"127.0.0.1:{silent.getsockname()[1]}"
        argv = ["sweep", "spring", "--tiny", "--engine", "ray", "--ray-address", address]
        start = time.monotonic()
        assert main([*argv, "--ray-timeout", "3", "--out", str(tmp_path / "s")]) == 2
        seconds = time.monotonic() - start
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"Ray address '{address}' did not answer within 3 s (--ray-timeout)" in err
    assert 3 <= seconds < 3 + 5 and not (tmp_path / "s" / "sweep.json").exists()
    new = {pid: cmd for pid, cmd in _descendants().items() if pid not in before}
    left = {pid: cmd for pid, cmd in new.items() if address in cmd or "raylet" in cmd or "gcs_server" in cmd}
    assert not left, left  # the probe's child and anything it started were killed
    assert ray.is_initialized() == was_up  # no local Ray was started instead
    if not was_up:
        assert not new, new


@pytest.fixture(scope="module")
def engine(tmp_path_factory):
    """The engine's own local Ray with 2 CPUs; a private home shows what it writes there."""
    ray = pytest.importorskip("ray", reason=NO_RAY)
    from pal.lab.ray_engine import RayEngine

    assert not ray.is_initialized()
    home = tmp_path_factory.mktemp("home")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HOME", str(home))
        mp.delenv("RAY_AUTH_TOKEN", raising=False)
        mp.delenv("RAY_AUTH_TOKEN_PATH", raising=False)
        with RayEngine(cpus=2) as eng:
            eng.home, session = home, eng._temp
            yield eng
        assert not ray.is_initialized() and "RAY_AUTH_TOKEN" not in os.environ
        assert not Path(session).exists()  # the session directory went with the Ray


def test_the_local_ray_has_its_own_session_directory_and_token_and_writes_no_home_files(engine):
    assert Path(engine._temp).name.startswith("pal-ray-") and Path(engine._temp).parent != Path("/tmp/ray")
    assert any(p.name.startswith("session_") for p in Path(engine._temp).iterdir())
    assert len(os.environ["RAY_AUTH_TOKEN"]) == 64 and not (engine.home / ".ray").exists()


def test_sharded_babbling_on_ray_equals_the_local_engine(engine, tmp_path):
    a = babble_sharded(CONFIG, tmp_path / "ray", workers=2, map_shards=engine.map)
    b = babble_sharded(CONFIG, tmp_path / "local", workers=2, processes=False)
    assert np.array_equal(a.states, b.states) and np.array_equal(a.ctrl, b.ctrl)
    assert np.array_equal(a.step, b.step) and np.array_equal(a.episode, b.episode)
    assert all(np.array_equal(a.columns[k], b.columns[k]) for k in b.columns)
    assert a.metadata["shards"] == b.metadata["shards"]


def test_a_sweep_through_ray_tune_gives_the_local_reports_and_no_tune_files(engine, tmp_path):
    plan = sweep.plan("spring", ["schedule.epochs=1"], "0-1", base="tiny")
    ray_result = sweep.run_sweep(plan, tmp_path / "ray", engine=engine.sweep_runs)
    assert not sweep.run_sweep(plan, tmp_path / "local").failed
    assert not ray_result.failed and len(ray_result.ran) == 2
    for i in range(2):
        a = json.loads((tmp_path / "ray" / "runs" / f"r{i:03d}.json").read_text())
        b = json.loads((tmp_path / "local" / "runs" / f"r{i:03d}.json").read_text())
        assert a["config"] == b["config"] and a["targets"] == b["targets"] and a["metrics"] == b["metrics"]
    names = sorted(p.name for p in (tmp_path / "ray").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "local").iterdir())  # Tune's temp dir is gone


def test_a_failed_ray_run_is_reported_not_dropped_and_retry_reruns_only_it(engine, failing, tmp_path, capsys):
    out, runs = tmp_path / "sweep", tmp_path / "sweep" / "runs"
    argv = ["sweep", "ray_failing", "--grid", "scale=1,2,3", "--seeds", "0", "--set", f"fail_file={failing}"]
    assert main([*argv, "--engine", "ray", "--workers", "2", "--out", str(out)]) == 1
    text = capsys.readouterr().out
    assert "1 failed" in text and "RuntimeError: scale 2.0 exploded" in text
    assert sorted(p.name for p in runs.glob("*.json")) == ["r000.json", "r001.error.json", "r002.json"]
    md = (out / "summary.md").read_text()
    assert "| finished runs | 1/1 | 0/1 | 1/1 |" in md and "### Failed runs" in md
    kept = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in runs.glob("r00[02].json")}

    failing.write_text("")  # the cause is fixed: only the failed cell runs again, on Ray
    assert main(["sweep", "ray_failing", "--retry-failed", "--engine", "ray", "--out", str(out)]) == 0
    assert "0 failed" in capsys.readouterr().out
    assert {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in runs.glob("r00[02].json")} == kept
    assert sorted(p.name for p in runs.glob("*.json")) == ["r000.json", "r001.json", "r002.json"]
    rows = {(r["scale"], r["metric"]): r for r in csv.DictReader((out / "summary.csv").open())}
    assert rows[("2", "value")]["n"] == "1"
    assert float(rows[("2", "value")]["mean"]) == pytest.approx(2.0, abs=1e-12)  # scale 2 * (seed 0 + 1)
    assert not list(out.glob(".tune-*"))


def test_an_address_that_does_not_answer_is_one_line_within_the_timeout(tmp_path, capsys):
    pytest.importorskip("ray", reason=NO_RAY)
    start = time.monotonic()
    argv = [
        "sweep",
        "spring",
        "--tiny",
        "--engine",
        "ray",
        "--ray-address",
        "127.0.0.1:1",
        "--ray-timeout",
        "2",
    ]
    assert main([*argv, "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Ray address '127.0.0.1:1' does not answer" in err
    assert time.monotonic() - start < 10 and not (tmp_path / "s" / "sweep.json").exists()


def test_engine_ray_without_the_extra_names_the_install(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)
    monkeypatch.delitem(sys.modules, "pal.lab.ray_engine", raising=False)
    assert main(["babble", "--steps", "10", "--engine", "ray", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == 'pal babble: --engine ray needs Ray, an optional extra: pip install ".[ray]"'
