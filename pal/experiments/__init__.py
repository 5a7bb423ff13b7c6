"""Scripted experiments and benchmarks, one module each.

Every module exposes a frozen ``Config`` dataclass and ``run(config, progress_bar=False)``
returning a result with ``to_dict()`` (JSON-compatible), ``to_markdown()`` and
``figures()`` (name -> matplotlib Figure). :func:`pal.experiments.output.write_outputs`
stores them. The ``pal`` command finds them through the registries below.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["BENCHMARKS", "EXPERIMENTS", "load_module"]

#: ``pal experiment NAME`` -> module
EXPERIMENTS: dict[str, str] = {
    "a1": "pal.experiments.a1_kinematic",
    "a2": "pal.experiments.a2_visual",
    "a3": "pal.experiments.a3_multidomain",
    "b1": "pal.experiments.b1",
    "b2": "pal.experiments.b2",
    "b3": "pal.experiments.b3",
    "explore": "pal.experiments.explore",
    "discovery": "pal.experiments.discovery",
    "active_design": "pal.experiments.active_design",
    "c1": "pal.experiments.c1",
    "c2": "pal.experiments.c2",
    "c3": "pal.experiments.c3",
    "c4": "pal.experiments.c4",
}

#: ``pal bench NAME`` -> module
BENCHMARKS: dict[str, str] = {
    "counterfactual": "pal.experiments.bench_counterfactual",
    "svi": "pal.experiments.bench_svi",
    "action": "pal.experiments.bench_action",
    "babble": "pal.experiments.bench_babble",
    "discovery": "pal.experiments.bench_discovery",
    "perception": "pal.experiments.bench_perception",
}


def load_module(kind: str, name: str) -> ModuleType:
    """Import the module registered as ``name`` in ``EXPERIMENTS`` or ``BENCHMARKS``."""
    registry = {"experiment": EXPERIMENTS, "bench": BENCHMARKS}[kind]
    if name not in registry:
        raise ValueError(f"unknown {kind} {name!r}; available: {sorted(registry)}")
    return importlib.import_module(registry[name])
