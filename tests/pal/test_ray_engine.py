"""``--engine ray``: shards as Ray tasks and sweep runs as Tune trials give the local engine's results."""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import pytest

from pal.cli import main
from pal.experiments import sweep
from pal.sim.babbling import BabbleConfig
from pal.sim.shards import babble_sharded

CONFIG = BabbleConfig(body="finger", seed=5, steps=23, frame_skip=5, reset_every=7, chunk_size=6)


@pytest.fixture(scope="module")
def engine():
    ray = pytest.importorskip(
        "ray", reason='Ray is an optional extra: pip install -c constraints.txt ".[ray]"'
    )
    from pal.experiments.ray_engine import RayEngine

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    with RayEngine() as eng:
        yield eng
    ray.shutdown()


def test_sharded_babbling_on_ray_equals_the_local_engine(engine, tmp_path):
    a = babble_sharded(CONFIG, tmp_path / "ray", workers=2, map_shards=engine.map)
    b = babble_sharded(CONFIG, tmp_path / "local", workers=2, processes=False)
    assert np.array_equal(a.states, b.states) and np.array_equal(a.ctrl, b.ctrl)
    assert np.array_equal(a.step, b.step) and np.array_equal(a.episode, b.episode)
    assert all(np.array_equal(a.columns[k], b.columns[k]) for k in b.columns)
    assert a.metadata["shards"] == b.metadata["shards"]


def test_a_sweep_through_ray_tune_gives_the_local_reports_and_no_tune_files(engine, tmp_path):
    plan = sweep.plan("spring", ["epochs=1"], "0-1", base="tiny")
    ray_result = sweep.run_sweep(plan, tmp_path / "ray", engine=engine.sweep_runs)
    assert not sweep.run_sweep(plan, tmp_path / "local").failed
    assert not ray_result.failed and len(ray_result.ran) == 2
    for i in range(2):
        a = json.loads((tmp_path / "ray" / "runs" / f"r{i:03d}.json").read_text())
        b = json.loads((tmp_path / "local" / "runs" / f"r{i:03d}.json").read_text())
        assert a["config"] == b["config"] and a["targets"] == b["targets"] and a["metrics"] == b["metrics"]
    names = sorted(p.name for p in (tmp_path / "ray").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "local").iterdir())  # Tune's temp dir is gone


def test_an_address_that_does_not_answer_is_one_line_within_the_timeout(tmp_path, capsys):
    pytest.importorskip("ray", reason='Ray is an optional extra: pip install -c constraints.txt ".[ray]"')
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
    monkeypatch.delitem(sys.modules, "pal.experiments.ray_engine", raising=False)
    assert main(["babble", "--steps", "10", "--engine", "ray", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == 'pal babble: --engine ray needs Ray, an optional extra: pip install ".[ray]"'
