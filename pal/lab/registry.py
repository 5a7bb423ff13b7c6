"""The one registry of experiments and benchmarks, filled by the :func:`register` decorator.

An entry holds its frozen ``Config`` type, a quick config (``--quick``, the demo), a tiny
config (the contract test) and its ``run(config, progress_bar) -> Report``. Modules register
themselves on import; :func:`entries` imports every module of :data:`PACKAGE` once, found by
:func:`pkgutil.walk_packages`, so a new module under ``pal/experiments/`` needs no other listing.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from pal.lab.report import Report

__all__ = ["KINDS", "PACKAGE", "Entry", "Pool", "entries", "entry_modules", "get", "register"]

KINDS = ("experiment", "bench")

#: The package whose modules are scanned for entries (every module, subpackages included).
PACKAGE = "pal.experiments"

Run = Callable[[Any, bool], Report]
#: ``pool(config, seeds) -> config``: the config of one run that reports over all of a sweep's
#: ``seeds`` at once from what their runs left (e.g. a store of finished parts), computing nothing
#: new; raises ``ValueError`` (named) when the sweep's config cannot be pooled.
Pool = Callable[[Any, tuple[int, ...]], Any]


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
        pool: optional :data:`Pool`: a sweep of the entry also writes the report of this
            config (:mod:`pal.lab.sweep_pool`), for entries whose report needs every seed at once.
    """

    name: str
    kind: Literal["experiment", "bench"]
    config: type
    quick: Any
    tiny: Any
    run: Run
    summary: str
    pool: Pool | None = None

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
    pool: Pool | None = None,
) -> Callable[[Run], Run]:
    """Decorator: register ``run`` as ``pal <kind> <name>``.

    Args:
        name: command-line name, unique within ``kind``.
        kind: ``"experiment"`` or ``"bench"``.
        config: the frozen dataclass config type; it must have a ``seed`` field.
        quick: the ``config`` instance of ``--quick`` and ``pal demo``.
        tiny: the smallest ``config`` instance that runs every code path (the contract test).
        pool: optional :data:`Pool` (a sweep's report over all its seeds at once).
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

    if pool is not None and not callable(pool):
        raise ValueError(f"{kind} {name!r}: pool must be callable, got {type(pool).__name__}")

    def decorate(run: Run) -> Run:
        key = (kind, name)
        if key in _REGISTRY and _REGISTRY[key].run.__module__ != run.__module__:
            raise ValueError(
                f"{kind} {name!r} is registered twice ({_REGISTRY[key].run.__module__}, {run.__module__})"
            )
        doc = inspect.getdoc(run) or ""
        _REGISTRY[key] = Entry(name, kind, config, quick, tiny, run, doc.split("\n", 1)[0], pool)
        return run

    return decorate


def entries(kind: str | None = None) -> list[Entry]:
    """All registered entries (of ``kind`` if given), in registration order."""
    global _LOADED
    if not _LOADED:
        for module in entry_modules():
            importlib.import_module(module)
        _LOADED = True
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind {kind!r} unknown; expected one of {KINDS}")
    return [e for (k, _), e in _REGISTRY.items() if kind is None or k == kind]


def entry_modules() -> list[str]:
    """The dotted names of every module under :data:`PACKAGE`, in a stable (sorted) order."""
    package = importlib.import_module(PACKAGE)
    found = pkgutil.walk_packages(package.__path__, prefix=PACKAGE + ".")
    return sorted(info.name for info in found if not info.ispkg)


def get(kind: str, name: str) -> Entry:
    """The entry ``pal <kind> <name>``."""
    found = {e.name: e for e in entries(kind)}
    if name not in found:
        raise ValueError(f"unknown {kind} {name!r}; available: {sorted(found)}")
    return found[name]
