"""Parallel babbling: a run split into independent seeded shards, merged into one dataset.

A run of :class:`~pal.sim.babbling.BabbleConfig` with ``workers = N`` is N independent
babbling runs (shards). Shard k babbles ``steps_k`` transitions (``steps`` split as evenly as
possible, the first shards taking the remainder) with the seed :func:`shard_seed`
``(seed, k)`` = ``SeedSequence([seed, 3, k]).generate_state(1)[0]``; everything else is the
run's configuration. The data are therefore a function of the configuration and N, not of
which process ran which shard, or when.

Layout of the output directory ``out``::

    out/shards/shard_000/ ...   each shard: a complete dataset of its own (resumable)
    out/metadata.json, out/chunk_*.npz   the merged dataset, rows of shard 0, then 1, ...

The shards run in local processes (``concurrent.futures``, spawned interpreters), at most
``workers`` at a time, which exit when the process that started them dies, or as Ray tasks (``map_shards``, :mod:`pal.lab.ray_engine`).
``out`` is locked (:mod:`pal.io.locks`) for the whole run, each shard directory by its own
writer. An interrupted run resumes per shard (``resume=True``): finished
shards are kept, unfinished ones continue where their last chunk ended.

Merging is atomic: the merged chunks are written to a staging directory, moved into ``out``,
and ``metadata.json`` (the manifest) is moved in last, so ``out`` is either not a dataset yet
or a complete one. In the merged dataset ``step`` and ``episode`` are offset by the rows and
episodes of the shards before, so they stay unique; ``metadata["shards"]`` lists each shard's
seed, first row and rows.
"""

from __future__ import annotations

import ctypes
import json
import logging
import multiprocessing
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from pal.checks import check_int
from pal.io.dataset import METADATA, DatasetWriter, TransitionDataset
from pal.io.dataset_files import chunk_files, read_metadata
from pal.io.locks import LOCK_NAME, DirectoryLock
from pal.sim.babbling import BabbleConfig, babble, effective_ranges, make_source

__all__ = ["SHARDS_DIR", "ShardMap", "babble_sharded", "run_shard", "shard_configs", "shard_seed"]

logger = logging.getLogger(__name__)

#: Sub-directory of the output that holds the shards.
SHARDS_DIR = "shards"
_STAGING = ".merging"


def shard_seed(seed: int, shard: int) -> int:
    """The master seed of shard ``shard`` of a run seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, 3, shard]).generate_state(1)[0])


def shard_configs(config: BabbleConfig, workers: int) -> list[BabbleConfig]:
    """The shards of ``config`` split over ``workers``: their steps and derived seeds.

    Raises:
        ValueError: ``workers`` < 1, more workers than steps, or ``effective_range`` (each
            shard would probe its own range).
    """
    workers = check_int("workers", workers)
    if workers > config.steps:
        raise ValueError(f"workers={workers} exceeds steps={config.steps}; every shard needs >= 1 step")
    if config.effective_range and workers > 1:
        raise ValueError("effective_range cannot be split over workers > 1; give the ranges (--action-range)")
    base, extra = divmod(config.steps, workers)
    return [
        replace(config, steps=base + (k < extra), seed=shard_seed(config.seed, k)) for k in range(workers)
    ]


ShardMap = Callable[[Callable[..., int], Sequence[tuple[Any, ...]]], list[int]]
"""Runs ``fn(*args)`` for every ``args`` (each shard) somewhere, returning the results in order."""


def run_shard(config: BabbleConfig, out_dir: str, resume: bool, backend: str) -> int:
    """Babble one shard into ``out_dir`` (in a worker process or a Ray task); returns its rows."""
    return len(babble(config, out_dir, resume=resume, backend=backend))


#: ``prctl`` option: the signal the kernel sends this process when its parent dies (Linux).
_PR_SET_PDEATHSIG = 1


def _die_with_parent(parent: int, interval: float = 0.5) -> None:
    """Worker initializer: end this worker when ``parent`` (the process that started it) dies.

    On Linux the kernel sends SIGKILL on the parent's death (``prctl(PR_SET_PDEATHSIG)``);
    elsewhere, or if that call fails, a daemon thread polls ``os.getppid()`` every ``interval``
    seconds and exits when the worker has been re-parented. A worker killed half-way leaves its
    shard resumable (``--resume``): its lock is stale and its chunks are checksummed.
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError) as err:
            logger.debug("prctl(PR_SET_PDEATHSIG) unavailable (%s); polling the parent instead", err)
            armed = False
        if armed:
            if os.getppid() != parent:  # the parent died before the signal was armed
                os._exit(1)
            return
    threading.Thread(target=_watch_parent, args=(parent, interval), daemon=True).start()


def _watch_parent(parent: int, interval: float) -> None:
    """Exit the process as soon as its parent is no longer ``parent``."""
    while os.getppid() == parent:
        time.sleep(interval)
    logger.warning("the process that started this babbling worker (pid %d) died; exiting", parent)
    os._exit(1)


def _shard_dir(out: Path, k: int) -> Path:
    return out / SHARDS_DIR / f"shard_{k:03d}"


def babble_sharded(
    config: BabbleConfig,
    out_dir: str | os.PathLike[str],
    *,
    workers: int,
    resume: bool = False,
    backend: str = "loop",
    processes: bool = True,
    map_shards: ShardMap | None = None,
) -> TransitionDataset:
    """Run ``config`` as ``workers`` seeded shards and merge them into one dataset in ``out_dir``.

    Args:
        config: the run (its seed is the run seed the shard seeds derive from).
        out_dir: the output directory (see the module docstring for its layout).
        workers: shards, and local processes running them at a time (>= 1).
        resume: continue an interrupted run: finished shards are kept, the others resume.
        backend: the babbling stepping backend of every shard.
        processes: run the shards in worker processes (False: one after the other in this one,
            with the same result).
        map_shards: runs :func:`run_shard` over the shards' arguments instead of the local
            processes (``--engine ray``: :meth:`pal.lab.ray_engine.RayEngine.map`); the
            shard directories must then be reachable at the same path by every worker.

    Returns:
        The merged dataset, loaded back from ``out_dir``.

    Raises:
        ValueError: bad ``workers`` (see :func:`shard_configs`), ``out_dir`` holds a dataset or
            shards and not ``resume``, a dataset of another worker count (or of one process),
            or a stored shard has another configuration.
        DirectoryLockedError: another run writes ``out_dir``.
    """
    shards = shard_configs(config, workers)
    out = Path(out_dir)
    with DirectoryLock(out, LOCK_NAME):  # the one writer of out, as for babble()
        existing = (out / METADATA).exists() or (out / SHARDS_DIR).exists()
        if existing and not resume:
            raise ValueError(
                f"{out} already holds a dataset or shards; pass resume=True (pal babble --resume) to continue it"
            )
        if (out / METADATA).exists():
            stored = read_metadata(out).get("workers")
            if stored != len(shards):
                what = "a single-process dataset" if stored is None else f"a run over workers={stored}"
                raise ValueError(f"{out} holds {what}; it cannot be resumed with workers={len(shards)}")
        dirs = [_shard_dir(out, k) for k in range(len(shards))]
        args = [(c, str(d), resume and d.exists(), backend) for c, d in zip(shards, dirs, strict=True)]
        if map_shards is not None:  # absolute paths: a Ray worker runs in its own directory
            rows = map_shards(run_shard, [(c, str(Path(d).resolve()), *rest) for c, d, *rest in args])
        elif processes and len(shards) > 1:
            ctx = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(
                max_workers=len(shards), mp_context=ctx, initializer=_die_with_parent, initargs=(os.getpid(),)
            ) as pool:
                rows = list(pool.map(run_shard, *zip(*args, strict=True)))
        else:
            rows = [run_shard(*a) for a in args]
        logger.info("shards done: %s rows", rows)
        _merge(config, shards, dirs, out)
    return TransitionDataset.load(out)


def _merge(config: BabbleConfig, shards: list[BabbleConfig], dirs: list[Path], out: Path) -> None:
    """Write the shards as one dataset in a staging directory, then move it into ``out``."""
    staging = out / _STAGING
    if staging.exists():
        shutil.rmtree(staging)  # an interrupted merge: it is rebuilt from the shards
    meta = make_source(replace(config, steps=1)).metadata(config)
    table, row, episode = [], 0, 0
    datasets = [TransitionDataset.load(d) for d in dirs]
    for k, (c, ds) in enumerate(zip(shards, datasets, strict=True)):
        table.append(
            {
                "index": k,
                "seed": c.seed,
                "steps": c.steps,
                "start": row,
                "dir": f"{SHARDS_DIR}/{dirs[k].name}",
            }
        )
        row += len(ds)
    meta.update(
        shards=table,
        workers=len(shards),
        seed_derivation=meta["seed_derivation"]
        + "; shard k: SeedSequence([seed, 3, k]).generate_state(1)[0], "
        "whose own policy and reset seeds derive from it as above",
        config=json.loads(json.dumps({k: v for k, v in asdict(config).items() if k != "steps"})),
    )
    with DatasetWriter(staging, meta) as writer:
        row = 0
        for k, ds in enumerate(datasets):
            for lo in range(0, len(ds), config.chunk_size):
                part = ds.subset(slice(lo, lo + config.chunk_size))
                writer.write_chunk(
                    part.columns,
                    {
                        "ctrl": part.ctrl,
                        "state": part.states,
                        "step": part.step + row,
                        "episode": part.episode + episode,
                    },
                    {"shard": k, "shard_row": lo},
                )
            row += len(ds)
            episode += int(ds.episode.max()) + 1
        merged = TransitionDataset.load(staging, allow_incomplete=True)
        writer.finish(config.steps, extra={"effective_ranges": effective_ranges(merged)})
    if (out / METADATA).exists():
        (out / METADATA).unlink()  # from here until the manifest moves in, out is no dataset
    for old in chunk_files(out):
        old.unlink()
    for path in chunk_files(staging):
        path.replace(out / path.name)
    (staging / METADATA).replace(out / METADATA)
    shutil.rmtree(staging)
