"""The one registry of experiments and benchmarks, filled by the :func:`register` decorator.

An entry holds its frozen ``Config`` type, a quick config (``--quick``, the demo), a tiny
config (the contract test) and its ``run(config, progress_bar) -> Report``. Modules register
themselves on import; :func:`entries` imports the modules listed in :data:`MODULES` once.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from pal.experiments.report import Report

__all__ = ["KINDS", "MODULES", "Entry", "entries", "get", "register"]

KINDS = ("experiment", "bench")

#: Modules that register entries (imported lazily by :func:`entries`).
MODULES: tuple[str, ...] = (
    "pal.experiments.queries",
    "pal.experiments.spring",
    "pal.experiments.b1",
    "pal.experiments.b2",
    "pal.experiments.b3",
    "pal.experiments.explore",
    "pal.experiments.a1_kinematic",
    "pal.experiments.a2_visual",
    "pal.experiments.a3_multidomain",
    "pal.experiments.discovery_synthetic",
    "pal.experiments.discovery_body",
    "pal.experiments.active_design",
    "pal.experiments.closed_loop",
    "pal.experiments.c1",
    "pal.experiments.c2",
    "pal.experiments.c3",
    "pal.experiments.c4",
    "pal.experiments.pusher",
    "pal.experiments.lot",
    "pal.experiments.hierarchy_compare",
    "pal.experiments.bench_counterfactual",
    "pal.experiments.bench_svi",
    "pal.experiments.bench_action",
    "pal.experiments.bench_babble",
    "pal.experiments.bench_rollout",
    "pal.experiments.bench_discovery",
    "pal.experiments.bench_perception",
    "pal.experiments.bench_fuzz",
)

Run = Callable[[Any, bool], Report]


@dataclass(frozen=True)
class Entry:
    """One registered experiment or benchmark.

    Attributes:
        name: the name on the command line (``pal experiment NAME`` / ``pal bench NAME``).
        kind: ``"experiment"`` or ``"bench"``.
        config: the frozen dataclass type of its configuration (default: the full protocol).
        quick: the small configuration of ``--quick`` and ``pal demo``.
        tiny: the smallest configuration that runs every code path (the contract test).
        run: ``run(config, progress_bar=False) -> Report``.
        summary: one line on what it measures.
    """

    name: str
    kind: Literal["experiment", "bench"]
    config: type
    quick: Any
    tiny: Any
    run: Run
    summary: str

    def default(self) -> Any:
        """The full-protocol configuration."""
        return self.config()


_REGISTRY: dict[tuple[str, str], Entry] = {}
_LOADED = False


def register(
    name: str,
    *,
    kind: Literal["experiment", "bench"] = "experiment",
    config: type,
    quick: Any,
    tiny: Any,
) -> Callable[[Run], Run]:
    """Decorator: register ``run`` as ``pal <kind> <name>``.

    Args:
        name: command-line name, unique within ``kind``.
        kind: ``"experiment"`` or ``"bench"``.
        config: the frozen dataclass config type; it must have a ``seed`` field.
        quick: the ``config`` instance of ``--quick`` and ``pal demo``.
        tiny: the smallest ``config`` instance that runs every code path (the contract test).
    """
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r} unknown; expected one of {KINDS}")
    if not (isinstance(config, type) and dataclasses.is_dataclass(config)):
        raise ValueError(f"{kind} {name!r}: config must be a dataclass type, got {config!r}")
    if "seed" not in {f.name for f in dataclasses.fields(config)}:
        raise ValueError(f"{kind} {name!r}: {config.__qualname__} has no 'seed' field")
    for label, value in (("quick", quick), ("tiny", tiny)):
        if not isinstance(value, config):
            raise ValueError(
                f"{kind} {name!r}: {label} config is a {type(value).__name__}, not {config.__name__}"
            )

    def decorate(run: Run) -> Run:
        key = (kind, name)
        if key in _REGISTRY and _REGISTRY[key].run.__module__ != run.__module__:
            raise ValueError(
                f"{kind} {name!r} is registered twice ({_REGISTRY[key].run.__module__}, {run.__module__})"
            )
        doc = inspect.getdoc(run) or ""
        _REGISTRY[key] = Entry(name, kind, config, quick, tiny, run, doc.split("\n", 1)[0])
        return run

    return decorate


def entries(kind: str | None = None) -> list[Entry]:
    """All registered entries (of ``kind`` if given), in registration order."""
    global _LOADED
    if not _LOADED:
        for module in MODULES:
            importlib.import_module(module)
        _LOADED = True
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind {kind!r} unknown; expected one of {KINDS}")
    return [e for (k, _), e in _REGISTRY.items() if kind is None or k == kind]


def get(kind: str, name: str) -> Entry:
    """The entry ``pal <kind> <name>``."""
    found = {e.name: e for e in entries(kind)}
    if name not in found:
        raise ValueError(f"unknown {kind} {name!r}; available: {sorted(found)}")
    return found[name]
