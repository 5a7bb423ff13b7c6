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
EXPERIMENTS: dict[str, str] = {}

#: ``pal bench NAME`` -> module
BENCHMARKS: dict[str, str] = {
    "counterfactual": "pal.experiments.bench_counterfactual",
    "svi": "pal.experiments.bench_svi",
    "action": "pal.experiments.bench_action",
    "babble": "pal.experiments.bench_babble",
}


def load_module(kind: str, name: str) -> ModuleType:
    """Import the module registered as ``name`` in ``EXPERIMENTS`` or ``BENCHMARKS``."""
    registry = {"experiment": EXPERIMENTS, "bench": BENCHMARKS}[kind]
    if name not in registry:
        raise ValueError(f"unknown {kind} {name!r}; available: {sorted(registry)}")
    return importlib.import_module(registry[name])
