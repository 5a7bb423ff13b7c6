"""Sweeps: one registered entry run over a grid of settings × seeds, summarised with mean ± sd.

A sweep is the cartesian product of its grid (``key=v1,v2`` per dotted config path, values
parsed like ``--set``) times its seeds. Every run is one :func:`pal.lab.runner.execute`
of the entry on the base config (default, quick or tiny, plus fixed ``--set`` items) with the
cell's values and ``seed`` set. Layout of the output directory::

    out/sweep.json            the manifest: entry, base, fixed settings, grid, seeds, runs
    out/runs/rNNN.json        a finished run's report (the JSON document of render.document)
    out/runs/rNNN.error.json  a failed run: its one-line error
    out/summary.csv           one row per (cell, metric): n, mean, sd
    out/summary.md            the same table (metric × cell, ``mean ± sd``), failed runs listed
    out/TARGET.png            one figure per target: mean ± sd over the cells

Every scalar number of a report's ``metrics`` (nested keys joined by dots, lists left out),
every target value (``target.NAME``) and the run time (``seconds``) is summarised per cell
over the cell's finished runs: the mean and the sample standard deviation (ddof 1; ``n/a``
for one run; see :mod:`pal.lab.sweep_summary`). A run that raises is recorded with
its error, counted as failed in its cell and listed, never dropped; :func:`run_sweep` with ``retry_failed=True`` runs only the runs without
a report again. Runs go one after the other in this process, in ``workers`` local
processes, or through an ``engine`` (Ray Tune: :mod:`pal.lab.ray_engine`). A sweep holds the
single-writer lock of its directory (``out/writer.lock``, :mod:`pal.io.locks`) from its first
check to its summary, so a second sweep on the same ``out`` is refused before it writes.
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from pal.checks import MAX_SEED
from pal.io.files import atomic_write_json, read_json
from pal.io.locks import LOCK_NAME, DirectoryLock, DirectoryLockedError
from pal.lab import configs, registry, render, runner
from pal.lab.registry import Entry
from pal.lab.sweep_plan import Base, Run, SweepPlan, configure_from, run_config
from pal.lab.sweep_pool import pooled_config, write_pooled
from pal.lab.sweep_summary import MANIFEST, RUNS, SweepResult, summarise

__all__ = [
    "FORMAT",
    "MAX_SEEDS",
    "Engine",
    "Run",
    "SweepError",
    "SweepPlan",
    "SweepResult",
    "compute_run",
    "configure_from",
    "parse_grid",
    "parse_seeds",
    "plan",
    "record_run",
    "run_sweep",
    "summarise",
]

log = logging.getLogger(__name__)

#: Format tag of ``sweep.json``.
FORMAT = "pal.sweep/1"

#: The most seeds one sweep runs (each seed is a run of every cell).
MAX_SEEDS = 10_000
_MAX_SEEDS_TEXT = 10_000  # characters of a --seeds text


class SweepError(ValueError):
    """A sweep that cannot be run: bad seeds, grid, base or output directory."""


def parse_seeds(text: str) -> tuple[int, ...]:
    """Seeds from ``"0-9"`` (inclusive range), ``"0,3,7"`` or ``"4"``; mixed ``"0-2,7"`` too.

    At most :data:`MAX_SEEDS` seeds in all, each in ``[0, MAX_SEED]`` (``pal.checks.MAX_SEED``).

    Raises:
        SweepError: an empty, descending or non-integer range, a seed out of range, more than
            :data:`MAX_SEEDS` seeds, or a repeated seed.
    """
    text = str(text)
    if len(text) > _MAX_SEEDS_TEXT:
        raise SweepError(f"--seeds {text[:40]!r}...: {len(text)} characters, the limit is {_MAX_SEEDS_TEXT}")
    seeds: list[int] = []
    for part in text.split(","):
        first, last = _seed_range(text, part.strip())
        if len(seeds) + last - first + 1 > MAX_SEEDS:
            raise SweepError(
                f"--seeds {text!r}: more than {MAX_SEEDS} seeds (the most one sweep runs); split the sweep"
            )
        seeds.extend(range(first, last + 1))
    counts = Counter(seeds)
    dup = sorted(s for s, n in counts.items() if n > 1)
    if dup:
        raise SweepError(f"--seeds {text!r}: seeds {dup} given twice")
    return tuple(seeds)


def _seed_range(text: str, part: str) -> tuple[int, int]:
    """``part`` of ``--seeds text`` (``N`` or ``FIRST-LAST``) as its first and last seed, checked."""
    lo, sep, hi = part.partition("-") if not part.startswith("-") else (part, "", "")
    try:
        first, last = (int(lo), int(hi)) if sep else (int(part), int(part))
    except ValueError:
        raise SweepError(f"--seeds {text!r}: {part!r} is not N or FIRST-LAST, e.g. 0-9 or 0,3,7") from None
    if last < first:
        raise SweepError(f"--seeds {text!r}: range {part!r} runs backwards; write {last}-{first}")
    if first < 0 or last > MAX_SEED:
        bad = first if first < 0 else last
        raise SweepError(f"--seeds {text!r}: seeds must be in [0, {MAX_SEED}], got {bad}")
    return first, last


def _split_values(text: str) -> list[str]:
    """``"1,2,[3,4]"`` -> ``["1", "2", "[3,4]"]``: commas inside brackets stay."""
    values, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        depth += {"[": 1, "{": 1, "]": -1, "}": -1}.get(ch, 0)
        if ch == "," and depth == 0:
            values.append(text[start:i])
            start = i + 1
    values.append(text[start:])
    return [v.strip() for v in values]


def _leaf_paths(config: Any) -> list[str]:
    return [p for p, v in configs.walk(config) if not configs._is_config(v)]


def parse_grid(items: Sequence[str], base: Any) -> tuple[tuple[str, tuple[Any, ...]], ...]:
    """``["a.b=1,2", "c=x,y"]`` -> ``(("a.b", (1, 2)), ("c", ("x", "y")))``, checked against ``base``.

    Every value is parsed like ``--set`` (JSON or a bare word) and set on ``base`` once, so a
    wrong path, type or range is refused here, before any run.

    Raises:
        SweepError: a malformed item, a key that is not a config field (the message names
            the valid ones), ``seed`` (use the seeds), a repeated key or value, or a value the
            config refuses.
    """
    grid: list[tuple[str, tuple[Any, ...]]] = []
    valid = _leaf_paths(base)
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key or not raw.strip():
            raise SweepError(f"--grid {item!r}: expected KEY=V1,V2,..., e.g. --grid schedule.epochs=5,10")
        if key == "seed":
            raise SweepError("--grid seed=...: give the seeds with --seeds, e.g. --seeds 0-9")
        if key not in valid:
            raise SweepError(
                f"--grid {item!r}: {key!r} is not a config field; valid: {[p for p in valid if p != 'seed']}"
            )
        if key in dict(grid):
            raise SweepError(f"--grid {key!r} given twice; list all its values in one --grid")
        try:
            values = tuple(configs.parse_value(v) for v in _split_values(raw))
        except configs.ConfigError as err:  # too long or too deep
            raise SweepError(f"--grid {key}=...: {err}") from None
        if len({repr(v) for v in values}) != len(values):
            raise SweepError(f"--grid {item!r}: a value is given twice")
        for v in values:
            try:
                configs.override(base, key, v)
            except ValueError as err:
                raise SweepError(f"--grid {item!r}: {err}") from None
        grid.append((key, values))
    return tuple(grid)


def plan(
    name: str,
    grid: Sequence[str],
    seeds: str,
    *,
    kind: str = "experiment",
    base: Base = "default",
    sets: Sequence[str] = (),
) -> SweepPlan:
    """Check a sweep's command-line pieces and build its plan, before any run.

    Raises:
        SweepError: an unknown entry, bad seeds, a bad grid or a refused setting.
    """
    try:
        entry = registry.get(kind, name)
    except ValueError as err:
        raise SweepError(str(err)) from None
    if base not in ("default", "quick", "tiny"):
        raise SweepError(f"base {base!r} unknown; expected default, quick or tiny")
    seed_list = parse_seeds(seeds)
    try:
        start = run_config(entry, base, sets, {}, seed_list[0])
    except ValueError as err:
        raise SweepError(f"pal sweep {name}: {err}") from None
    planned = SweepPlan(kind, name, base, tuple(sets), parse_grid(grid, start), seed_list)
    try:
        pooled_config(planned)
    except ValueError as err:
        raise SweepError(f"pal sweep {name}: its pooled report: {err}") from None
    return planned


Engine = Callable[[SweepPlan, list[Run], Path], None]
"""Runs a sweep's runs to do: ``engine(plan, todo, out)`` leaves a report or an error record for each."""


def compute_run(
    entry: Entry, base: Base, sets: Sequence[str], settings: Mapping[str, Any], seed: int
) -> tuple[dict[str, Any] | None, str | None]:
    """Run one cell of ``entry`` with ``seed``: ``(report document, None)`` or ``(None, one-line error)``."""
    try:
        config = run_config(entry, base, sets, settings, seed)
        record = runner.execute(entry, config)
        document = render.document(record)
        _close(record.report.figures.values())  # a sweep keeps each run's JSON, not its figures
    except Exception as err:  # a failed run is recorded and reported, never dropped
        line = f"{type(err).__name__}: {err}".splitlines()[0] if str(err) else type(err).__name__
        return None, line
    return document, None


def record_run(out: Path, run: Run, document: Mapping[str, Any] | None, error: str | None) -> None:
    """Write ``run``'s report (``runs/rNNN.json``) or, if ``document`` is None, its error record."""
    runs = out / RUNS
    if document is None:
        log.warning("sweep run %s (%s, seed %d) failed: %s", run.id, run.settings, run.seed, error)
        atomic_write_json(runs / f"{run.id}.error.json", {"id": run.id, "error": str(error)})
        return
    (runs / f"{run.id}.error.json").unlink(missing_ok=True)
    atomic_write_json(runs / f"{run.id}.json", dict(document))


def _run_one(kind: str, name: str, base: Base, sets: Sequence[str], run: Run, out_dir: str) -> str | None:
    """Run ``run`` and write its report or its error; returns the one-line error or ``None``."""
    document, error = compute_run(registry.get(kind, name), base, sets, run.settings, run.seed)
    record_run(Path(out_dir), run, document, error)
    return error


def _close(figures: Any) -> None:
    import matplotlib.pyplot as plt

    for fig in figures:
        plt.close(fig)


def _run_in_worker(
    kind: str, name: str, base: Base, sets: list[str], run: Run, out_dir: str, level: int
) -> str | None:
    import torch

    torch.set_num_threads(1)
    runner.log_like(level)  # a spawned process starts without the sweep's logging
    return _run_one(kind, name, base, sets, run, out_dir)


def _read_plan(out: Path) -> SweepPlan:
    data = read_json(out / MANIFEST)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise SweepError(f"{out / MANIFEST} is not a {FORMAT} manifest")
    return SweepPlan(
        data["kind"],
        data["name"],
        data["base"],
        tuple(data["sets"]),
        tuple((k, tuple(v)) for k, v in data["grid"]),
        tuple(data["seeds"]),
    )


def run_sweep(
    sweep: SweepPlan | None,
    out_dir: str | os.PathLike[str],
    *,
    retry_failed: bool = False,
    workers: int = 1,
    engine: Engine | None = None,
) -> SweepResult:
    """Run a sweep into ``out_dir`` (or only its failed runs again), then summarise it.

    Args:
        sweep: the plan; with ``retry_failed`` it may be ``None`` (read from ``out_dir``),
            and if given it must equal the plan stored there.
        out_dir: the sweep's directory (see the module docstring).
        retry_failed: run again only the runs of ``out_dir`` that have no report.
        workers: local processes; 1 runs in this process, one run after the other.
        engine: runs the runs to do instead of the local processes (``--engine ray``:
            :meth:`pal.lab.ray_engine.RayEngine.sweep_runs`); ``workers`` is then unused.

    Raises:
        SweepError: ``out_dir`` already holds a sweep (without ``retry_failed``), holds none
            or a different one (with it), another sweep runs in it (the message names the
            directory and that process), or ``workers`` < 1.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise SweepError(f"--workers must be >= 1, got {workers}")
    out = Path(out_dir)
    try:
        lock = DirectoryLock(out, LOCK_NAME).acquire()
    except DirectoryLockedError as err:
        raise SweepError(f"--out {str(out)!r}: another sweep runs in it: {err}") from None
    try:
        return _run_locked(sweep, out, retry_failed, workers, engine)
    finally:
        lock.release()


def _run_locked(
    sweep: SweepPlan | None, out: Path, retry_failed: bool, workers: int, engine: Engine | None
) -> SweepResult:
    """:func:`run_sweep` while this process holds the lock of ``out``."""
    manifest = out / MANIFEST
    if retry_failed:
        if not manifest.is_file():
            raise SweepError(f"--retry-failed: {out} holds no sweep ({MANIFEST} missing)")
        stored = _read_plan(out)
        if sweep is not None and sweep.to_dict() != stored.to_dict():
            raise SweepError(
                f"--retry-failed: {out} holds a different sweep {stored.to_dict()}; give the same one or none"
            )
        sweep = stored
    elif manifest.exists():
        raise SweepError(f"{out} already holds a sweep; pass --retry-failed or choose another --out")
    if sweep is None:
        raise SweepError("no sweep given")
    (out / RUNS).mkdir(parents=True, exist_ok=True)
    if not retry_failed:
        runs_doc = [{"id": r.id, "cell": r.cell, "settings": r.settings, "seed": r.seed} for r in sweep.runs]
        atomic_write_json(manifest, {"format": FORMAT, **sweep.to_dict(), "runs": runs_doc})
    todo = [r for r in sweep.runs if not (out / RUNS / f"{r.id}.json").is_file()]
    log.info("sweep %s: %d of %d runs to do", sweep.name, len(todo), len(sweep.runs))
    args = (sweep.kind, sweep.name, sweep.base, list(sweep.sets))
    if engine is not None:
        if todo:
            engine(sweep, todo, out)
    elif workers == 1 or len(todo) <= 1:
        for i, r in enumerate(todo):
            log.info(
                "sweep %s: run %s (%d/%d) %s seed %d", sweep.name, r.id, i + 1, len(todo), r.settings, r.seed
            )
            _run_one(*args, r, str(out))
    else:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx) as pool:
            level = logging.getLogger().getEffectiveLevel()
            futures = [(r, pool.submit(_run_in_worker, *args, r, str(out), level)) for r in todo]
            for r, f in futures:
                try:
                    f.result()
                except BrokenProcessPool as err:  # the worker died: the run is failed, not dropped
                    record_run(out, r, None, f"worker process died ({err})".splitlines()[0])
    result = summarise(sweep, out, ran=tuple(r.id for r in todo))
    return _pool(sweep, out, result)


def _pool(sweep: SweepPlan, out: Path, result: SweepResult) -> SweepResult:
    """``result`` with the pooled report's paths (:mod:`pal.lab.sweep_pool`), or its failure among the failed."""
    try:
        result.paths.update(write_pooled(sweep, out))
    except Exception as err:  # the runs are kept and summarised; the pooled report's failure is listed
        line = f"{type(err).__name__}: {err}".splitlines()[0]
        log.error("sweep %s: the pooled report failed: %s", sweep.name, line)
        result.failed["pooled"] = ({}, sweep.seeds[0], line)
    return result
