"""A sweep's pooled report: one run over all its seeds at once, for entries registered with a ``pool``.

Some reports need every seed together (the ``pusher`` experiment's learning curves are pooled
over seeds × goals). A sweep of such an entry computes one seed per run, and the runs leave
their results where one pooled run reads them back (the ``pusher``'s store of finished parts).
After the runs the sweep executes ``entry.pool(config, seeds)`` on the sweep's base config with
its fixed settings (not a grid's: there the grid splits the work, such as the ``pusher``'s
``parts``) and writes its report to ``out/pooled/`` (``NAME.json``, ``NAME.md``, its figures).
The hook is asked once before any run, so a sweep that cannot be pooled is refused up front.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from pal.lab import registry, render, runner
from pal.lab.sweep_plan import SweepPlan, run_config

__all__ = ["POOLED", "pooled_config", "write_pooled"]

log = logging.getLogger(__name__)

#: The subdirectory of a sweep's output that holds its pooled report.
POOLED = "pooled"


def pooled_config(sweep: SweepPlan) -> Any | None:
    """The config of the sweep's pooled run, or None when its entry has no ``pool``.

    Raises:
        ValueError: the entry's hook refuses the sweep's config or seeds (its message).
    """
    entry = registry.get(sweep.kind, sweep.name)
    if entry.pool is None:
        return None
    base = run_config(entry, sweep.base, sweep.sets, {}, sweep.seeds[0])
    return entry.pool(base, tuple(sweep.seeds))


def write_pooled(sweep: SweepPlan, out: Path) -> dict[str, Path]:
    """Run the pooled config (if any) and write its report to ``out / POOLED``: ``{"pooled.json": path, ...}``."""
    config = pooled_config(sweep)
    if config is None:
        return {}
    entry = registry.get(sweep.kind, sweep.name)
    log.info("sweep %s: the pooled report over seeds %s", sweep.name, list(sweep.seeds))
    record = runner.execute(entry, config)
    directory = out / POOLED
    directory.mkdir(exist_ok=True)
    return {f"pooled.{key}": path for key, path in render.write(record, directory).items()}
