"""Reports, the renderer, nested config overrides and output checks."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import pytest

from pal.lab import configs, render
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.runner import OutputError, RunRecord, check_output_dir


@dataclass(frozen=True)
class Inner:
    epochs: int = 3
    hidden: tuple[int, ...] = (8, 8)
    mode: str = "a"

    def __post_init__(self) -> None:
        if self.epochs < 1:
            raise ValueError(f"epochs must be >= 1, got {self.epochs}")


@dataclass(frozen=True)
class Outer:
    seed: int = 0
    lr: float = 0.1
    inner: Inner = Inner()
    goal: tuple[float, float] | None = None


def test_override_reaches_nested_fields_and_coerces():
    c = configs.override(Outer(), "inner.epochs", 7)
    assert c.inner.epochs == 7 and c.inner.hidden == (8, 8)
    c = configs.override(c, "inner.hidden", [4, 5, 6])
    assert c.inner.hidden == (4, 5, 6)
    assert configs.override(c, "lr", 1).lr == 1.0 and isinstance(configs.override(c, "lr", 1).lr, float)
    assert configs.override(c, "goal", [0.1, 0.2]).goal == (0.1, 0.2)
    assert configs.override(c, "goal", None).goal is None
    assert configs.to_dict(c) == {
        "seed": 0,
        "lr": 0.1,
        "inner": {"epochs": 7, "hidden": [4, 5, 6], "mode": "a"},
        "goal": None,
    }


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("nope", 1, "unknown setting 'nope'"),
        ("inner.nope", 1, "unknown setting 'nope'"),
        ("seed.x", 1, "'seed' is a value, not a group"),
        ("inner", 3, "inner is a group of settings"),
        ("seed", 1.5, "seed: 1.5 is not an int"),
        ("seed", True, "seed: True is not an int"),
        ("lr", "fast", "lr: 'fast' is not a number"),
        ("inner.hidden", 4, "inner.hidden|hidden: 4 is not a list"),
        ("inner.hidden", [4, "x"], r"hidden\[1\]: 'x' is not an int"),
        ("goal", [1.0], "goal"),
        ("inner.mode", 3, "mode: 3 is not a string"),
        ("seed", 2**70, rf"seed: {2**70} is out of range; an int setting is within"),
        ("seed", -1, r"seed must be an int in \[0, 4294967295\], got -1"),
        ("seed", 2**32, r"seed must be an int in \[0, 4294967295\], got 4294967296"),
        ("inner.hidden", [2**63], rf"hidden\[0\]: {2**63} is out of range"),
    ],
)
def test_override_errors_name_the_path_and_value(path, value, message):
    with pytest.raises(configs.ConfigError, match=message):
        configs.override(Outer(), path, value)


def test_override_runs_the_configs_own_checks():
    with pytest.raises(ValueError, match="epochs must be >= 1, got 0"):
        configs.override(Outer(), "inner.epochs", 0)


def test_parse_value():
    assert configs.parse_value("3") == 3 and configs.parse_value("[1, 2]") == [1, 2]
    assert configs.parse_value("null") is None and configs.parse_value("state") == "state"
    deep = "[" * configs.MAX_VALUE_DEPTH + "]" * configs.MAX_VALUE_DEPTH
    assert configs.parse_value(deep) == eval(deep)  # at the limit: parsed
    assert configs.parse_value('["[[[[", {"a": "]]"}]') == ["[[[[", {"a": "]]"}]  # brackets in strings


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        ("[" * 5000 + "]" * 5000, "nests 5000 levels deep; the limit is 32"),
        ('{"a":' * 33 + "1" + "}" * 33, "nests 33 levels deep; the limit is 32"),
        ("x" * 10_001, "has 10001 characters; the limit is 10000"),
        ("9" * 5000, "Exceeds the limit"),
    ],
)
def test_parse_value_refuses_values_too_long_or_too_deep(raw, message):
    with pytest.raises(configs.ConfigError, match=message):
        configs.parse_value(raw)


def test_apply_set_names_the_item_in_every_refusal():
    with pytest.raises(configs.ConfigError, match=r"^--set 'seed=-1': seed must be an int in"):
        configs.apply_set(Outer(), "seed=-1")
    with pytest.raises(configs.ConfigError, match=r"^--set 'seed': expected KEY=VALUE"):
        configs.apply_set(Outer(), "seed")
    with pytest.raises(ValueError, match=r"^--set 'inner.epochs=0': epochs must be >= 1, got 0"):
        configs.apply_set(Outer(), "inner.epochs=0")


def test_target_verdicts():
    assert Target("a", 0.5, 1.0, "<=").met is True
    assert Target("a", 1.0, 1.0, "<").met is False
    assert Target("a", 2.0, 1.0, ">=").met is True
    assert Target("a", None, 1.0, ">").met is None
    assert Target("a", math.nan, 1.0, ">").met is None
    assert Target("a", np.float32(3.0), 1, ">").to_dict()["value"] == 3.0
    with pytest.raises(ValueError, match="direction '=='"):
        Target("a", 1.0, 1.0, "==")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="threshold nan is not finite"):
        Target("a", 1.0, math.nan, "<")
    with pytest.raises(ValueError, match="value 'x' is not a number"):
        Target("a", "x", 1.0, "<")  # type: ignore[arg-type]


def test_a_target_whose_precondition_fails_is_not_evaluated_and_not_met():
    moved = Precondition(False, "the object moved > 5 mm")
    failed = Target("ratio", 1.0, 1.0, "<=", "pal / baseline", moved)  # 1.0 <= 1.0, but nothing moved
    assert failed.verdict == "not evaluated" and failed.met is False and not failed.evaluated
    held = Target("ratio", 1.0, 1.0, "<=", "pal / baseline", Precondition(np.bool_(True), "moved"))
    assert held.verdict == "met" and held.met is True and held.precondition.holds is True
    assert Target("x", None, 1.0, "<", "", moved).verdict == "not evaluated"
    assert [Target("a", 2.0, 1.0, "<").verdict, Target("a", None, 1.0, "<").verdict] == [
        "not met",
        "not measured",
    ]
    with pytest.raises(ValueError, match="is not a bool"):
        Precondition("yes", "x")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="is not a Precondition"):
        Target("a", 1.0, 1.0, "<", "", True)  # type: ignore[arg-type]

    rep = Report("R", {}, targets=[failed, Target("ok", 0.5, 1.0, "<=", "fine")])
    md = render.markdown(_record(rep))
    assert "| ratio | pal / baseline | 1 | <= 1 | not evaluated |" in md
    assert "1 of 2 targets met (1 not evaluated)." in md
    assert "`ratio` not evaluated: requires the object moved > 5 mm" in md
    doc = render.document(_record(rep))["targets"][0]
    assert doc["met"] is False and doc["verdict"] == "not evaluated"
    assert doc["precondition"] == {"holds": False, "reason": "the object moved > 5 mm"}
    table = render.targets_table([("pusher", failed), ("b1", Target("ok", 0.5, 1.0, "<="))])
    assert [r[-1] for r in table.rows] == ["not evaluated", "met"]
    assert table.caption.startswith("1 of 2 targets met (1 not evaluated).")
    assert "pusher: `ratio` not evaluated" in table.caption


def test_table_and_report_checks():
    with pytest.raises(ValueError, match="row 1 has 1 cells, expected 2"):
        Table("t", ("a", "b"), [(1, 2), (3,)])
    with pytest.raises(ValueError, match="is not str, number or None"):
        Table("t", ("a",), [([1, 2],)])
    t = Table("t", ("a", "b"), [(np.float64(1.5), math.inf)])
    assert t.rows == ((1.5, None),)
    with pytest.raises(ValueError, match=r"duplicate target names \['x'\]"):
        Report("r", {}, targets=[Target("x", 1, 2, "<"), Target("x", 1, 2, "<")])
    with pytest.raises(KeyError, match="has no target 'y'"):
        Report("r", {}).target("y")


def _record(report: Report) -> RunRecord:
    return RunRecord("demo_run", "experiment", {"seed": 0}, 0, {"python": "3"}, 1.25, report)


def test_markdown_and_json_come_from_one_renderer():
    rep = Report(
        "Title",
        {"a": np.float32(0.5), "b": [1, None], "c": {"d": np.arange(2)}},
        tables=[Table("T", ("x", "y"), [("p|q", None), ("r", 0.123456)])],
        targets=[Target("t1", 0.1, 0.2, "<=", "what"), Target("t2", None, 1.0, ">", "missing")],
        notes=["One sentence."],
    )
    md = render.markdown(_record(rep))
    assert "## Title\n\nOne sentence." in md
    assert "| p\\|q | n/a |" in md and "| r | 0.1235 |" in md
    assert "| t1 | what | 0.1 | <= 0.2 | met |" in md and "| t2 | missing | n/a | > 1 | not measured |" in md
    doc = render.document(_record(rep))
    assert doc["metrics"] == {"a": 0.5, "b": [1, None], "c": {"d": [0, 1]}}
    assert doc["targets"][0]["met"] is True and doc["targets"][1]["met"] is None
    assert doc["tables"][0]["rows"] == [["p|q", None], ["r", 0.123456]]


def test_json_refuses_non_finite_metrics_by_path():
    rep = Report("Title", {"state": {"q_mse": math.nan}})
    with pytest.raises(ValueError, match=r"metrics\.state\.q_mse is nan"):
        render.document(_record(rep))
    with pytest.raises(ValueError, match=r"metrics\.x is a object"):
        render.jsonable({"x": object()})


def test_targets_table_collects_runs():
    table = render.targets_table(
        [("b1", Target("r", 0.05, 0.1, "<=", "ratio")), ("b2", Target("m", 0.3, 0.05, "<=", "mae"))]
    )
    assert table.columns == ("run", "target", "what", "value", "goal", "verdict")
    assert [r[-1] for r in table.rows] == ["met", "**NOT met**"]


def test_check_output_dir(tmp_path):
    assert check_output_dir(tmp_path / "a" / "b").is_dir()
    afile = tmp_path / "file"
    afile.write_text("x")
    with pytest.raises(OutputError, match="is a file, expected a directory"):
        check_output_dir(afile)
    with pytest.raises(OutputError, match="is a file, expected a directory"):
        check_output_dir(afile / "sub")
    if os.geteuid() != 0:  # root may write anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        with pytest.raises(OutputError, match="is not writable"):
            check_output_dir(ro)


def test_the_baseline_of_a_ratio_must_be_finite_and_nonzero():
    assert Precondition.nonzero(np.float64(0.2), "the persistence q MSE").holds
    for bad in (0.0, math.nan, math.inf):
        pre = Precondition.nonzero(bad, "the persistence q MSE")
        assert not pre.holds and pre.reason.startswith("the persistence q MSE finite and nonzero (was ")
    missing = Target("over_peer", None, 1.0, "<=", "", Precondition.nonzero(None, "the peer's time"))
    assert missing.evaluated and missing.verdict == "not measured"  # a peer that was not run
