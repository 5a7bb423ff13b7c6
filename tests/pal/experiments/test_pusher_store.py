"""Finished parts of pusher seeds on disk: computed in pieces, read back, scored as one run (tiny budgets)."""

import math
from dataclasses import replace

import pytest

from pal.experiments.closed_loop import pusher, pusher_store
from pal.experiments.closed_loop.pusher_runs import Episode
from pal.experiments.closed_loop.pusher_store import PartStore, _decode, _encode
from pal.io.files import read_json
from pal.lab.registry import get
from pal.lab.runner import execute


def _untimed(tree):
    """``tree`` without its timings (which differ between runs of the same numbers)."""
    if isinstance(tree, dict):
        return {k: _untimed(v) for k, v in tree.items() if k != "step_cpu_seconds"}
    if isinstance(tree, list):
        return [_untimed(v) for v in tree]
    if isinstance(tree, Episode):
        return replace(tree, cpu=None, wall=None)
    return tree


def _run(config):
    return execute(get("experiment", "pusher"), config)


@pytest.mark.slow
def test_parts_run_apart_and_read_back_score_as_the_whole_run(tmp_path, tiny_run):
    config = replace(pusher.TINY, store=str(tmp_path))
    first = _run(replace(config, parts=("pal",))).report
    assert first.title.startswith("Pusher-v5 learning curves: 1 of 3 parts stored")
    assert first.metrics["missing"] == [{"seed": 0, "part": "baseline"}, {"seed": 0, "part": "reference"}]
    assert not first.targets
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seed0_pal.json"]
    second = _run(replace(config, parts=("baseline", "reference"))).report
    cost = second.tables[-1]
    assert [(r[1], r[4]) for r in cost.rows] == [
        ("pal", "read back"),
        ("baseline", "computed"),
        ("reference", "computed"),
    ]
    assert all(r[2] > 0 and r[3] > 0 for r in cost.rows)
    whole = tiny_run("experiment", "pusher").report
    # the same numbers as the run computed in one piece (episodes seeded, JSON floats exact), but for time
    assert _untimed(second.metrics["at"]) == _untimed(whole.metrics["at"])
    assert [(t.name, t.verdict) for t in second.targets] == [(t.name, t.verdict) for t in whole.targets]
    third = _run(config).report  # everything read back
    assert [r[4] for r in third.tables[-1].rows] == ["read back"] * 3
    assert third.metrics["at"] == second.metrics["at"]
    # the spending table reads the counts by name (a part read back has its keys sorted)
    spent = next(t for t in third.tables if t.title.startswith("What aggregation spent"))
    assert [r[2:] for r in spent.rows] == [
        r[2:] for r in next(t for t in whole.tables if t.title.startswith("What aggregation spent")).rows
    ]
    assert spent.rows[0][2] == pusher.TINY.aggregation.budget  # env steps


@pytest.mark.slow
def test_a_part_computed_with_other_settings_is_refused_naming_them(tmp_path):
    config = replace(pusher.TINY, store=str(tmp_path), parts=("reference",))
    _run(config)
    with pytest.raises(ValueError, match=r"other settings \(eval_goals\)"):
        _run(replace(config, eval_goals=2))
    # how a run goes (seeds, workers, threads, parts) is not a setting of the part
    assert PartStore(tmp_path).load(replace(config, threads=2, parts=pusher.Config.parts), 0, "reference")


class Stopped(Exception):
    """Stands for a process killed right after the pal part's first snapshot."""


@pytest.mark.slow
def test_a_stopped_pal_part_goes_on_from_its_snapshot_to_the_same_result(tmp_path, monkeypatch):
    whole, pieces = tmp_path / "whole", tmp_path / "pieces"
    config = replace(pusher.TINY, store=str(whole), parts=("pal",))
    _run(config)
    save = pusher_store.Resume.save

    def save_then_stop(self, agent, result):
        save(self, agent, result)
        raise Stopped

    monkeypatch.setattr(pusher_store.Resume, "save", save_then_stop)
    with pytest.raises(Stopped):
        _run(replace(config, store=str(pieces)))
    assert sorted(p.name for p in pieces.iterdir()) == ["seed0_pal.resume.npz"]
    with pytest.raises(
        ValueError, match=r"seed0_pal\.resume\.npz was computed with other settings \(eval_goals\)"
    ):
        _run(replace(config, store=str(pieces), eval_goals=2))
    monkeypatch.setattr(pusher_store.Resume, "save", save)
    _run(replace(config, store=str(pieces)))
    assert sorted(p.name for p in pieces.iterdir()) == ["seed0_pal.json"]  # the snapshot is gone
    expected = PartStore(whole).load(config, 0, "pal")
    resumed = PartStore(pieces).load(config, 0, "pal")
    assert expected is not None and resumed is not None
    assert _untimed(resumed.result) == _untimed(expected.result)
    assert sorted(resumed.result["at"]) == [3, 6] and resumed.cpu > 0


def test_episodes_survive_the_round_trip_with_a_missing_distance_as_nan():
    e = Episode(0.1, 0.12, 0.2, None, 0.4, 0.5, [[0.0, 1.0]], [[1.0, 2.0]], [0.3, 0.4], float("nan"), 0.01)
    run = {"at": {1500: {"episodes": [e], "ranking": {"rho": float("nan"), "probes": 0}}}, "training": [e]}
    back = _decode(_encode(run))
    assert list(back["at"]) == [1500] and back["at"][1500]["ranking"] == {"rho": None, "probes": 0}
    got = back["at"][1500]["episodes"][0]
    assert math.isnan(got.min_tip_object) and replace(got, min_tip_object=0.0) == replace(
        e, min_tip_object=0.0
    )
    assert back["training"][0].path == [[0.0, 1.0]]


def test_parts_other_than_all_need_a_store_and_known_names(tmp_path):
    with pytest.raises(ValueError, match="set store"):
        replace(pusher.TINY, parts=("pal",))
    with pytest.raises(ValueError, match=r"parts must be distinct names of .*'walk'"):
        replace(pusher.TINY, store=str(tmp_path), parts=("walk",))
    with pytest.raises(ValueError, match="part must be one of"):
        PartStore(tmp_path).path(0, "walk")
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is not a directory"):
        PartStore(tmp_path / "file")


def test_a_file_of_another_format_is_refused(tmp_path):
    from pal.io.files import FileFormatError, atomic_write_json

    atomic_write_json(tmp_path / "seed0_pal.json", {"format": "x"})
    with pytest.raises(FileFormatError, match="not a stored pusher part"):
        PartStore(tmp_path).load(pusher.TINY, 0, "pal")


@pytest.mark.slow
def test_a_sweep_computes_the_seeds_parts_and_pools_them_into_one_report(tmp_path):
    from pal.lab import sweep

    store, out = tmp_path / "store", tmp_path / "sweep"
    planned = sweep.plan(
        "pusher",
        ['parts=["pal"],["baseline","reference"]'],
        "0-1",
        base="tiny",
        sets=[f"store={store}", "runs=1"],
    )
    result = sweep.run_sweep(planned, out)
    assert not result.failed
    assert len(list((out / "runs").glob("r*.json"))) == 4  # 2 cells x 2 seeds, one seed each
    assert sorted(p.name for p in store.iterdir()) == [
        f"seed{s}_{p}.json" for s in (0, 1) for p in ("baseline", "pal", "reference")
    ]
    pooled = read_json(result.paths["pooled.json"])
    assert pooled["config"]["seed"] == 0 and pooled["config"]["runs"] == 2 and pooled["config"]["parts"] == []
    at = pooled["metrics"]["at"]
    last = str(pusher.TINY.aggregation.checkpoints[-1])
    assert at[last]["pal"]["episodes"] == 2 * pusher.TINY.eval_goals  # both seeds' goals in one report
    assert [r[4] for r in pooled["tables"][-1]["rows"]] == ["read back"] * 6  # nothing computed again
    assert "missing" not in pooled["metrics"]


@pytest.mark.parametrize(
    ("sets", "seeds", "message"),
    [
        (["runs=1"], "0-1", "set --set store=DIR"),
        (["store=S", "runs=2"], "0-1", "set --set runs=1, got runs=2"),
        (["store=S", "runs=1"], "0,2", r"consecutive seeds, got \[0, 2\]"),
    ],
)
def test_a_pusher_sweep_that_cannot_be_pooled_is_refused_before_any_run(tmp_path, sets, seeds, message):
    from pal.lab import sweep

    sets = [s.replace("store=S", f"store={tmp_path}") for s in sets]
    with pytest.raises(sweep.SweepError, match=message):
        sweep.plan("pusher", [], seeds, base="tiny", sets=sets)
    assert not list(tmp_path.iterdir())


def test_a_read_only_pusher_run_needs_a_store():
    with pytest.raises(ValueError, match=r"parts \[\] leave out"):
        replace(pusher.TINY, parts=())
