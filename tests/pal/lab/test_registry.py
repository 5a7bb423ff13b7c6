"""The experiment protocol: every registered entry runs on its tiny config and returns a well-formed report.

The tiny runs are the session's ``tiny_run`` records (tests/pal/conftest.py), which the experiment
tests also read, so each entry's tiny run costs its time once.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from pal.lab import configs, registry, render
from pal.lab.report import DIRECTIONS, VERDICTS, Report, Table, Target

ENTRIES = registry.entries()
REPORT_KEYS = {
    "format",
    "name",
    "kind",
    "title",
    "notes",
    "metrics",
    "tables",
    "targets",
    "figures",
    "config",
    "seed",
    "versions",
    "seconds",
}


def test_every_registered_module_registers_something():
    modules = {e.run.__module__ for e in ENTRIES}
    assert modules <= set(registry.entry_modules())
    names = [(e.kind, e.name) for e in ENTRIES]
    assert len(names) == len(set(names))


@pytest.mark.parametrize("entry", ENTRIES, ids=lambda e: f"{e.kind}-{e.name}")
def test_config_contract(entry):
    """Frozen, nested configs with a seed; no ``Any`` fields; quick and tiny are instances."""
    for config in (entry.default(), entry.quick, entry.tiny):
        assert isinstance(config, entry.config)
        with pytest.raises(dataclasses.FrozenInstanceError):
            config.seed = 1  # type: ignore[misc]
        for path, value in configs.walk(config):
            if dataclasses.is_dataclass(value):
                assert type(value).__dataclass_params__.frozen, path  # type: ignore[attr-defined]
    hints = {f.name: f.type for f in dataclasses.fields(entry.config)}
    assert "Any" not in " ".join(str(t) for t in hints.values()), hints
    # the seed reaches the config through --set, and a bad type is refused by name
    assert configs.override(entry.tiny, "seed", 3).seed == 3
    with pytest.raises(configs.ConfigError, match="seed"):
        configs.override(entry.tiny, "seed", "three")


@pytest.mark.parametrize("entry", ENTRIES, ids=lambda e: f"{e.kind}-{e.name}")
@pytest.mark.slow
def test_tiny_run_report_schema(entry, tiny_run, tmp_path: Path):
    record = tiny_run(entry.kind, entry.name)
    report = record.report
    assert isinstance(report, Report) and report.title
    assert all(isinstance(t, Table) for t in report.tables) and report.tables, (
        "a report shows at least one table"
    )
    for table in report.tables:
        assert table.rows and all(len(r) == len(table.columns) for r in table.rows)
    assert report.targets, "every entry states at least one target"
    for target in report.targets:
        assert isinstance(target, Target) and target.direction in DIRECTIONS and target.description
        assert target.met in (True, False, None) and target.verdict in VERDICTS
        not_measured = target.value is None or not math.isfinite(target.value)
        assert (target.met is None) == (not_measured and target.evaluated)
        assert (target.verdict == "not evaluated") == (not target.evaluated)
    paths = render.write(record, tmp_path)
    doc = json.loads(Path(paths["json"]).read_text())
    assert set(doc) == REPORT_KEYS
    assert doc["name"] == entry.name and doc["kind"] == entry.kind and doc["seed"] == entry.tiny.seed
    assert doc["config"] == configs.to_dict(entry.tiny)
    assert {"python", "torch", "numpy"} <= set(doc["versions"])
    assert [t["name"] for t in doc["targets"]] == [t.name for t in report.targets]
    assert all(
        set(t) == {"name", "value", "threshold", "direction", "met", "verdict", "precondition", "description"}
        for t in doc["targets"]
    )
    md = Path(paths["markdown"]).read_text()
    assert md.startswith(f"## {report.title}") and "Targets:" in md
    for name in report.figures:
        png = tmp_path / f"{entry.name}_{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
