"""What a sweep runs: its plan (entry, base config, fixed settings, grid, seeds) and its runs.

Both :mod:`pal.lab.sweep` (which runs a plan) and :mod:`pal.lab.sweep_summary` (which
summarises one) import this module; it imports neither.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from pal.lab import configs, registry
from pal.lab.registry import Entry

__all__ = ["Base", "Run", "SweepPlan", "configure_from", "run_config"]

#: The config a sweep starts from.
Base = Literal["default", "quick", "tiny"]


@dataclass(frozen=True)
class Run:
    """One run of a sweep: an id (``rNNN``), the cell index, the cell's settings and the seed."""

    id: str
    cell: int
    settings: dict[str, Any]
    seed: int


@dataclass(frozen=True)
class SweepPlan:
    """What a sweep runs.

    Attributes:
        kind, name: the registry entry.
        base: the starting config (``default``, ``quick`` or ``tiny``).
        sets: fixed ``KEY=VALUE`` settings applied to the base before the grid.
        grid: ``(dotted path, values)`` per swept setting.
        seeds: the seeds of every cell.
    """

    kind: str
    name: str
    base: Base
    sets: tuple[str, ...]
    grid: tuple[tuple[str, tuple[Any, ...]], ...]
    seeds: tuple[int, ...]

    @property
    def cells(self) -> list[dict[str, Any]]:
        """The grid's cells (settings per cell), first key varying slowest."""
        keys = [k for k, _ in self.grid]
        return [dict(zip(keys, vs, strict=True)) for vs in itertools.product(*(v for _, v in self.grid))]

    @property
    def runs(self) -> list[Run]:
        """Every run: cells × seeds, in order."""
        out = []
        for c, settings in enumerate(self.cells):
            for seed in self.seeds:
                out.append(Run(f"r{len(out):03d}", c, settings, seed))
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (the manifest without the run list)."""
        return {
            "kind": self.kind,
            "name": self.name,
            "base": self.base,
            "sets": list(self.sets),
            "grid": [[k, list(v)] for k, v in self.grid],
            "seeds": list(self.seeds),
        }

    def config(self, run: Run) -> Any:
        """The config of ``run``."""
        return run_config(registry.get(self.kind, self.name), self.base, self.sets, run.settings, run.seed)


def run_config(entry: Entry, base: Base, sets: Sequence[str], settings: Mapping[str, Any], seed: int) -> Any:
    """The config of one run: ``base`` of ``entry``, then ``sets``, the cell's ``settings`` and ``seed``."""
    config = {"default": entry.default, "quick": lambda: entry.quick, "tiny": lambda: entry.tiny}[base]()
    for item in sets:
        config = configure_from(config, item)
    for path, value in settings.items():
        config = configs.override(config, path, value)
    return configs.override(config, "seed", seed)


def configure_from(config: Any, item: str) -> Any:
    """``config`` with one ``KEY=VALUE`` item (``--set``) applied."""
    return configs.apply_set(config, item)
