"""The README's example of adding an experiment is complete and true: it runs as written."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import pytest

from pal.lab import configs, registry
from pal.lab.runner import execute

README = Path(__file__).resolve().parents[3] / "README.md"


def example_source() -> str:
    """The first Python block of the README's section "Experiments: one protocol"."""
    text = README.read_text()
    section = text[text.index("## Experiments: one protocol") :]
    match = re.search(r"```python\n(.*?)```", section, flags=re.S)
    assert match, "the section has no python block"
    return match.group(1)


@pytest.fixture
def example(monkeypatch):
    """The example as a module, registered in a copy of the registry that the test drops."""
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    module = types.ModuleType("pal.experiments.world_model.slope")
    monkeypatch.setitem(sys.modules, module.__name__, module)
    exec(compile(example_source(), "README.md", "exec"), module.__dict__)
    return module


def test_the_example_registers_and_meets_its_target(example):
    entry = registry.get("experiment", "slope")
    assert entry.config is example.Config
    assert entry.summary.startswith("Slope of Y on X")
    record = execute(entry, entry.quick)
    (target,) = record.report.targets
    assert target.verdict == "met", target
    assert abs(record.report.metrics["slope"] - 2.0) <= 0.2


def test_the_example_config_is_reached_by_its_documented_path(example):
    entry = registry.get("experiment", "slope")
    changed = configs.override(entry.default(), "schedule.epochs", 5)
    assert changed.schedule.epochs == 5
    assert "--set schedule.epochs=5" in example_source()


def test_the_example_target_carries_its_precondition(example):
    entry = registry.get("experiment", "slope")
    (target,) = example.run(entry.tiny, False).targets
    assert target.precondition is not None and target.precondition.holds
    assert target.precondition.reason == "X varies (sd > 0.1)"
