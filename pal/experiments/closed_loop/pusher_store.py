"""Finished parts of ``pusher`` seeds on disk, so a protocol too long for one sitting runs in pieces.

A seed of :mod:`pal.experiments.closed_loop.pusher` has three independent parts
(:data:`PARTS`): the agent's rounds and evaluations (``pal``), the PETS-style baseline's
(``baseline``), and the goals run once by the planner's ceiling and random torques
(``reference``). With ``store`` set, each finished part is written to
``store/seed{S}_{part}.json`` and a later run with the same settings reads it back instead of
computing it again. So the parts of the full protocol can run in separate processes, at
different times or on different machines, e.g. (one core each)::

    pal experiment pusher --set store=DIR --set seed=0 --set runs=1 --set 'parts=["pal"]'
    pal experiment pusher --set store=DIR --set seed=0 --set runs=1 --set 'parts=["baseline","reference"]'
    ...
    pal experiment pusher --set store=DIR          # all seeds' parts read back: the full report

Each file holds the part's result, the settings it was computed with (the config without
``seed``, ``runs``, ``workers``, ``threads``, ``store`` and ``parts``, which do not change a
part's numbers), the library versions and the part's CPU and wall seconds. A file computed
with other settings or versions is refused with the differing keys named, never mixed in.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pal.agent.aggregate import Counts, RoundsResult
from pal.agent.snapshot import restore_agent, save_agent, snapshot_metadata
from pal.experiments.closed_loop.pusher_protocol import run_part
from pal.experiments.closed_loop.pusher_runs import Episode
from pal.io.files import FileFormatError, atomic_write_json, read_json, versions
from pal.lab import configs
from pal.lab.report import Report, Table

__all__ = ["FORMAT", "PARTS", "PartStore", "Resume", "StoredPart", "seed_parts", "stored_report"]

log = logging.getLogger(__name__)

#: The format tag of a stored part.
FORMAT = "pal.pusher-part/1"
#: A seed's parts, in the order they are computed.
PARTS = ("pal", "baseline", "reference")
#: Config fields that say how and where a run goes, not what it computes.
_RUN_FIELDS = ("seed", "runs", "workers", "threads", "store", "parts")
#: Stored parts are small (episodes' paths: ~10 kB each); bound the read all the same.
_MAX_BYTES = 256 * 2**20


@dataclasses.dataclass(frozen=True)
class StoredPart:
    """A part read back: its result and what it cost (process CPU and wall seconds)."""

    result: Any
    cpu: float
    wall: float
    computed: bool = False


def settings(config: Any) -> dict[str, Any]:
    """The settings that decide a part's numbers: the config as a dict without :data:`_RUN_FIELDS`."""
    return {k: v for k, v in configs.to_dict(config).items() if k not in _RUN_FIELDS}


def _encode(value: Any) -> Any:
    """JSON of a part's result: episodes tagged, keys as str, non-finite floats as None."""
    if isinstance(value, Episode):
        return {"episode": {k: _encode(v) for k, v in dataclasses.asdict(value).items()}}
    if isinstance(value, dict):
        return {str(k): _encode(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _decode(value: Any) -> Any:
    """The inverse of :func:`_encode` (a run's ``at`` keyed by int again; a missing distance is NaN)."""
    if isinstance(value, list):
        return [_decode(v) for v in value]
    if not isinstance(value, dict):
        return value
    if set(value) == {"episode"}:
        fields = dict(value["episode"])
        if fields.get("min_tip_object") is None:
            fields["min_tip_object"] = float("nan")
        return Episode(**fields)
    out = {k: _decode(v) for k, v in value.items()}
    if "at" in out and isinstance(out["at"], dict):
        out["at"] = {int(k): v for k, v in out["at"].items()}
    return out


def _differences(stored: Any, current: Any, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two settings dicts."""
    if isinstance(stored, dict) and isinstance(current, dict):
        keys = sorted(set(stored) | set(current))
        return [d for k in keys for d in _differences(stored.get(k), current.get(k), f"{prefix}{k}.")]
    return [] if stored == current else [prefix.rstrip(".")]


def _check_settings(path: Path, doc: dict[str, Any], config: Any) -> None:
    """Refuse a stored document computed with other settings or library versions (named)."""
    differ = _differences(doc.get("settings"), settings(config))
    if differ:
        raise ValueError(
            f"{path} was computed with other settings ({', '.join(differ[:8])}); remove it or run with its settings"
        )
    now = versions()
    if doc.get("versions") != now:
        raise ValueError(f"{path} was computed with versions {doc.get('versions')}, these are {now}")


class PartStore:
    """Finished parts of seeds in one directory (module docstring).

    Args:
        directory: created when the first part is written.
    """

    def __init__(self, directory: str | os.PathLike[str]) -> None:
        self.directory = Path(directory)
        if self.directory.exists() and not self.directory.is_dir():
            raise ValueError(f"store {str(self.directory)!r} exists and is not a directory")

    def path(self, seed: int, part: str) -> Path:
        """The file of ``part`` of ``seed``."""
        if part not in PARTS:
            raise ValueError(f"part must be one of {PARTS}, got {part!r}")
        return self.directory / f"seed{seed}_{part}.json"

    def load(self, config: Any, seed: int, part: str) -> StoredPart | None:
        """The stored part, or None when there is none.

        Raises:
            ValueError: the file was computed with other settings or library versions (named).
            FileFormatError: the file is not a stored part.
        """
        path = self.path(seed, part)
        if not path.exists():
            return None
        doc = read_json(path, max_bytes=_MAX_BYTES)
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise FileFormatError(f"{path} is not a stored pusher part (format {FORMAT!r})")
        if doc.get("seed") != seed or doc.get("part") != part:
            raise FileFormatError(
                f"{path} holds seed {doc.get('seed')} part {doc.get('part')!r}, not {seed} {part!r}"
            )
        _check_settings(path, doc, config)
        return StoredPart(_decode(doc["result"]), float(doc["cpu"]), float(doc["wall"]))

    def save(self, config: Any, seed: int, part: str, result: Any, cpu: float, wall: float) -> Path:
        """Write ``part`` of ``seed`` atomically with its settings, versions and cost."""
        path = self.path(seed, part)
        self.directory.mkdir(parents=True, exist_ok=True)
        doc = {
            "format": FORMAT,
            "seed": seed,
            "part": part,
            "settings": settings(config),
            "versions": versions(),
            "cpu": cpu,
            "wall": wall,
            "result": _encode(result),
        }
        return atomic_write_json(path, doc, name=str(path))


class Resume:
    """The ``pal`` part's snapshot after its last round, so a stopped part goes on from there.

    ``store/seed{S}_pal.resume.npz`` (:mod:`pal.agent.snapshot`) holds the agent's learned state
    and, in its metadata, the rounds' result so far, the settings, versions, seed and the CPU
    and wall seconds spent until then. It is rewritten after every round (its refit and any
    checkpoint's evaluation; a few seconds against minutes per round) and
    removed when the part is stored. A snapshot of other settings or versions is refused (named).

    Args:
        store: the store.
        config: the experiment's config.
        seed: the seed whose ``pal`` part runs.
    """

    def __init__(self, store: PartStore, config: Any, seed: int) -> None:
        self.path = store.directory / f"seed{seed}_pal.resume.npz"
        self.config, self.seed = config, seed
        self.cpu, self.wall = 0.0, 0.0  # spent by earlier processes
        self._start = (time.process_time(), time.perf_counter())

    def restore(self, agent: Any) -> RoundsResult | None:
        """Load the snapshot into ``agent`` and return the rounds' result so far; None without one."""
        if not self.path.exists():
            return None
        doc = snapshot_metadata(self.path)
        if doc.get("format") != FORMAT or doc.get("seed") != self.seed:
            raise FileFormatError(f"{self.path} is not the pal part's snapshot of seed {self.seed}")
        _check_settings(self.path, doc, self.config)
        restore_agent(agent, self.path)
        self.cpu, self.wall = float(doc["cpu"]), float(doc["wall"])
        rounds = _decode(doc["result"])
        log.info(
            "pusher seed %d part pal resumed after %d episodes from %s",
            self.seed,
            len(rounds["steps"]),
            self.path,
        )
        return RoundsResult(
            Counts(**rounds["counts"]),
            rounds["episodes"],
            rounds["steps"],
            {int(k): v for k, v in rounds["checkpoints"].items()},
        )

    def spent(self) -> tuple[float, float]:
        """CPU and wall seconds of the part so far, earlier processes included."""
        return (
            self.cpu + time.process_time() - self._start[0],
            self.wall + time.perf_counter() - self._start[1],
        )

    def save(self, agent: Any, result: RoundsResult) -> None:
        """Snapshot ``agent`` with the rounds' ``result`` so far (called after every round)."""
        cpu, wall = self.spent()
        rounds = {
            "counts": result.counts.to_dict(),
            "episodes": result.episodes,
            "steps": result.steps,
            "checkpoints": result.checkpoints,
        }
        doc = {"format": FORMAT, "seed": self.seed, "settings": settings(self.config), "versions": versions()}
        save_agent(agent, self.path, {**doc, "cpu": cpu, "wall": wall, "result": _encode(rounds)})


def seed_parts(config: Any, seed: int) -> dict[str, StoredPart | None]:
    """Each part of ``seed``: read from ``config.store``, else computed (when in ``config.parts``) and stored, else None.

    The ``pal`` part snapshots its agent after every round (:class:`Resume`) and goes on from
    the last snapshot when it was stopped.
    """
    store, out = PartStore(config.store), {}
    for part in PARTS:
        found = store.load(config, seed, part)
        if found is None and part in config.parts:
            resume = Resume(store, config, seed) if part == "pal" else None
            cpu, wall = time.process_time(), time.perf_counter()
            result = run_part(config, seed, part, resume)
            cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
            if resume is not None:
                cpu, wall = resume.spent()
            path = store.save(config, seed, part, result, cpu, wall)
            if resume is not None:
                resume.path.unlink(missing_ok=True)
            log.info(
                "pusher seed %d part %s stored in %s (%.0f s CPU, %.0f s wall)", seed, part, path, cpu, wall
            )
            found = StoredPart(result, cpu, wall, computed=True)
        out[part] = found
    return out


def _cost_table(per_seed: dict[int, dict[str, StoredPart | None]]) -> Table:
    rows = [
        (
            seed,
            part,
            *((p.cpu, p.wall, "computed" if p.computed else "read back") if p else (None, None, "missing")),
        )
        for seed, parts in per_seed.items()
        for part, p in parts.items()
    ]
    return Table(
        "The seeds' parts and what each cost",
        ["seed", "part", "CPU s", "wall s", "this run"],
        rows,
        "Process CPU and wall seconds of each part where it was computed (pal.experiments.closed_loop.pusher_store).",
    )


def stored_report(
    config: Any,
    per_seed: dict[int, dict[str, StoredPart | None]],
    summarise: Callable[[Any, dict[int, dict[str, Any]]], Report],
) -> Report:
    """The full report when every seed's parts are there (with their cost), else what is stored and missing."""
    table = _cost_table(per_seed)
    missing = [(s, p) for s, parts in per_seed.items() for p, v in parts.items() if v is None]
    if not missing:
        merged = {
            s: {"pal": parts["pal"].result, "baseline": parts["baseline"].result} | parts["reference"].result
            for s, parts in per_seed.items()
        }
        report = summarise(config, merged)
        return dataclasses.replace(report, tables=(*report.tables, table))
    total = sum(len(parts) for parts in per_seed.values())
    return Report(
        title=f"Pusher-v5 learning curves: {total - len(missing)} of {total} parts stored, not yet scored",
        metrics={"missing": [{"seed": s, "part": p} for s, p in missing], "store": str(config.store)},
        tables=[table],
        notes=[
            f"Missing: {', '.join(f'seed {s} {p}' for s, p in missing)}. Run them with the same settings and "
            f"store (``--set 'parts=[...]'``, ``--set seed=S --set runs=1``), then once more to score all seeds."
        ],
    )
