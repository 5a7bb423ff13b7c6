"""``pal demo``: a sequence of registered quick runs, rendered like every experiment.

1. ``queries``: causal queries on X -> Y -> Z against their closed forms.
2. ``spring``: a finger-like world model learnt from a known nonlinear SCM, then queried.
3. ``b1``, ``b2``: the world model of the MuJoCo finger from motor babbling, its actions
   executed in the simulator from the recorded states.
4. ``a1``: perception of scripted tabletop motions against ground truth.
5. ``loop``: a short closed perception-action loop on the pushing world, filmed.

Each run writes its JSON, markdown and figures to the output directory; the demo ends with
one table of every target and its verdict (met, not met, not measured, or not evaluated when
the target's precondition failed: too few seeds, nothing moved), with their counts (also in
``demo.json``). ``quick=True`` runs the
tiny configurations instead of the quick ones (seconds; the numbers are then not meaningful).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Iterator
from pathlib import Path

from pal.io.files import atomic_write_json
from pal.lab import registry, render
from pal.lab.report import VERDICTS, Report
from pal.lab.runner import RunRecord, execute

__all__ = ["SEQUENCE", "run"]

#: The demo's runs, in order: (kind, name).
SEQUENCE: tuple[tuple[str, str], ...] = (
    ("experiment", "queries"),
    ("experiment", "spring"),
    ("experiment", "b1"),
    ("experiment", "b2"),
    ("experiment", "a1"),
    ("experiment", "loop"),
)


def _config(entry: registry.Entry, out: Path, quick: bool) -> object:
    config = entry.tiny if quick else entry.quick
    if "video" in {f.name for f in dataclasses.fields(config)}:
        config = dataclasses.replace(config, video=str(out / f"{entry.name}.mp4"))
    return config


def run(
    out_dir: str | os.PathLike[str],
    *,
    quick: bool = False,
    progress_bar: bool = False,
    started: Callable[[int, int, str, str], None] | None = None,
) -> Iterator[str]:
    """Run :data:`SEQUENCE`; yields each run's markdown, then the table of all targets.

    Args:
        out_dir: directory for every run's ``NAME.json``, ``NAME.md``, figures and ``demo.json``.
        quick: the tiny configurations (seconds) instead of the quick ones.
        progress_bar: show progress bars of the long steps.
        started: called as ``started(i, n, kind, name)`` before the i-th of n runs (progress).
    """
    out = Path(out_dir)
    records: list[RunRecord] = []
    for i, (kind, name) in enumerate(SEQUENCE, 1):
        if started is not None:
            started(i, len(SEQUENCE), kind, name)
        entry = registry.get(kind, name)
        record = execute(entry, _config(entry, out, quick), progress_bar=progress_bar)
        render.write(record, out)
        records.append(record)
        yield render.markdown(record)
    targets = [(r.name, t) for r in records for t in r.report.targets]
    table = render.targets_table(targets)
    summary = Report(title="pal demo: every target and its verdict", metrics={}, tables=[table])
    yield render.markdown(
        RunRecord(
            "demo", "demo", {"quick": quick}, 0, records[0].versions, sum(r.seconds for r in records), summary
        )
    )
    atomic_write_json(
        out / "demo.json",
        {
            "quick": quick,
            "runs": [render.document(r) for r in records],
            "targets": table.to_dict(),
            "verdicts": {v: sum(t.verdict == v for _, t in targets) for v in VERDICTS},
        },
    )
