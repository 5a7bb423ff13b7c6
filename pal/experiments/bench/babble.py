"""``pal bench babble``: throughput of the babbling data source against bare ``mj_step``.

Contenders, on the same model (any body: ``--mjcf``, ``--actuator``, ``--frame-skip``,
``--action-range`` as for ``pal babble``), each producing ``steps`` environment steps of
uniform random commands with ``frame_skip`` MuJoCo steps each:

* ``source``: :meth:`pal.sim.babbling.BabblingSource.run` — policy draws, command clipping,
  the full state before every step, q before and after, the previous displacement, episode
  resets.
* ``raw_loop`` (the baseline): a bare Python loop that sets ``data.ctrl`` from pre-drawn
  commands and calls ``mujoco.mj_step`` ``frame_skip`` times per environment step,
  recording nothing.
* ``raw_nstep``: the same with one ``mujoco.mj_step(model, data, nstep=frame_skip)`` call.
* ``recorded``: :func:`pal.sim.babbling.babble` to a temporary directory (two chunk files,
  ``.npz`` + JSON, atomic writes), i.e. the source plus storage.
* ``mujoco.rollout`` (the second baseline): the whole pre-drawn command sequence (each command
  held for ``frame_skip`` steps) in one ``mujoco.rollout`` call on the calling thread, from the
  reset state, recording its FULLPHYSICS state after every MuJoCo step.
* ``workers`` (with ``workers`` > 0): :func:`pal.sim.shards.babble_sharded` over that many
  local processes, ``worker_steps`` transitions merged to disk, against ``one process``: the
  same transitions with :func:`pal.sim.babbling.babble` (``workers_speedup``, target >= 1.7
  for 2 workers on 2 cores; process start-up and the merge are included).
* ``source_rollout``: the data source with ``backend="rollout"`` (one ``mujoco.rollout`` call
  per environment step, :func:`pal.sim.batched.rollout_steps`; the same transitions).

Figures: ``transitions_per_s`` (source), ``raw_steps_per_s`` (raw_loop, env steps per s),
``ratio`` = transitions_per_s / raw_steps_per_s (target >= 0.7), and beside them the
``raw_nstep`` rate, its ratio, the recorded rate and median seconds per call;
``ratio_rollout`` = transitions_per_s / the ``mujoco.rollout`` rate (target >= 0.8, one
core) and ``ratio_source_rollout`` the same for ``source_rollout``. The contenders alternate
inside each repeat so load changes hit all of them.
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import mujoco
import mujoco.rollout
import numpy as np

from pal.checks import check_int
from pal.experiments.world_model.data import BodyChoice
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import Timing, measure_interleaved, ratio
from pal.sim.babbling import babble, make_source
from pal.sim.batched import FULLPHYSICS
from pal.sim.shards import babble_sharded

__all__ = ["TARGET_RATIO", "TARGET_ROLLOUT_RATIO", "Config", "run"]

log = logging.getLogger(__name__)

#: Target of ``ratio``: the data source keeps at least this share of raw mj_step throughput.
TARGET_RATIO = 0.7
#: Target of ``ratio_rollout``: the data source keeps this share of ``mujoco.rollout`` throughput.
TARGET_ROLLOUT_RATIO = 0.8


@dataclass(frozen=True)
class Config:
    """Benchmark sizes.

    Attributes:
        seed: seed of the commands.
        body: the body (shipped name or MJCF path), its babbling actuators, command ranges
            and frame skip (MuJoCo steps per environment step).
        steps: environment steps per timed call.
        repeats: timed repeats (median reported) after one warm-up of each contender.
        record: also time ``babble`` to disk (``recorded``).
        workers: local worker processes of the sharded contender (0: leave it out).
        worker_steps: transitions of a sharded run and of its one-process baseline (default
            ``4 * steps``: long enough for the processes' start-up to matter less).
    """

    seed: int = 0
    body: BodyChoice = BodyChoice()
    steps: int = 4000
    repeats: int = 3
    record: bool = True
    workers: int = 2
    worker_steps: int | None = None

    def __post_init__(self) -> None:
        for key in ("steps", "repeats"):
            check_int(key, getattr(self, key))
        check_int("workers", self.workers, minimum=0)
        if self.worker_steps is not None:
            check_int("worker_steps", self.worker_steps)

    @property
    def sharded_steps(self) -> int:
        """Transitions of the sharded contender: ``worker_steps``, or ``4 * steps`` when unset."""
        return self.worker_steps if self.worker_steps is not None else 4 * self.steps


def _time_workers(config: Config, tmp: Path) -> dict[str, Timing]:
    """Time a sharded run over ``config.workers`` processes against one ``babble`` process."""
    cfg = config.body.babble_config(
        config.sharded_steps, config.seed, chunk_size=max(1, config.sharded_steps // (2 * config.workers))
    )
    counter = iter(range(10**9))
    fns = {
        "one process": lambda: babble(cfg, tmp / f"one{next(counter)}"),
        "workers": lambda: babble_sharded(cfg, tmp / f"sharded{next(counter)}", workers=config.workers),
    }
    log.info("timing %d transitions on %d workers against one process", config.sharded_steps, config.workers)
    return measure_interleaved(fns, repeats=config.repeats, warmup=1)


def _calls(config: Config, babble_cfg: Any, source: Any) -> tuple[dict[str, Callable[[], Any]], Any]:
    """The timed calls on one model (the source, bare mj_step loops, mujoco.rollout) and the rollout pool."""
    model = source.env.model
    raw_data = mujoco.MjData(model)
    env = source.env
    commands = np.random.default_rng(config.seed).uniform(
        source.policy.low, source.policy.high, size=(config.steps, len(env.actuator_ids))
    )
    aidx, fs = env.actuator_ids, env.frame_skip

    def raw_loop() -> None:
        mujoco.mj_resetData(model, raw_data)
        for a in commands:
            raw_data.ctrl[aidx] = a
            for _ in range(fs):
                mujoco.mj_step(model, raw_data)

    def raw_nstep() -> None:
        mujoco.mj_resetData(model, raw_data)
        for a in commands:
            raw_data.ctrl[aidx] = a
            mujoco.mj_step(model, raw_data, fs)

    def source_run() -> None:
        source.run(config.steps)

    rollout_source = make_source(babble_cfg, backend="rollout")
    mujoco.mj_resetData(model, raw_data)
    mujoco.mj_forward(model, raw_data)
    initial = np.empty((1, mujoco.mj_stateSize(model, FULLPHYSICS)))
    mujoco.mj_getState(model, raw_data, initial[0], FULLPHYSICS)
    control = np.zeros((config.steps, model.nu))
    control[:, aidx] = commands
    control = np.ascontiguousarray(np.repeat(control, fs, axis=0)[None])  # (1, steps * fs, nu)
    out = np.empty((1, config.steps * fs, initial.shape[1]))
    warm = np.zeros((1, model.nv))
    pool = mujoco.rollout.Rollout(nthread=0)

    def native() -> None:
        pool.rollout(
            [model], [raw_data], initial, control, initial_warmstart=warm, state=out, nstep=out.shape[1]
        )

    fns = {
        "source": source_run,
        "raw_loop": raw_loop,
        "raw_nstep": raw_nstep,
        "mujoco.rollout": native,
        "source_rollout": lambda: rollout_source.run(config.steps),
    }
    return fns, pool


def _tables(config: Config, seconds: dict, rate: dict, worker_rate: dict, sharded: dict) -> list[Table]:
    order = ("source", "raw_loop", "raw_nstep", "recorded")
    rows = [(k, seconds[k], rate[k], ratio(rate[k], rate["raw_loop"])) for k in order if k in rate]
    native_rows = [
        (k, seconds[k], rate[k], ratio(rate[k], rate["mujoco.rollout"]))
        for k in ("source", "source_rollout", "mujoco.rollout")
    ]
    return [
        Table("Environment steps per second", ("", "seconds per call", "env steps/s", "/ raw_loop"), rows),
        Table(
            "Against mujoco.rollout (one thread)",
            ("", "seconds per call", "env steps/s", "/ mujoco.rollout"),
            native_rows,
        ),
        Table(
            f"Local worker processes ({config.sharded_steps} transitions to disk)",
            ("", "seconds per call", "transitions/s", "/ one process"),
            [
                (k, t.median, worker_rate[k], ratio(worker_rate[k], worker_rate["one process"]))
                for k, t in sharded.items()
            ],
        ),
    ]


def _targets(config: Config, rate: dict, worker_rate: dict, worker_speedup: float | None) -> list[Target]:
    return [
        Target(
            "ratio",
            rate["source"] / rate["raw_loop"],
            TARGET_RATIO,
            ">=",
            "transitions/s of the data source / env steps/s of a bare mj_step loop",
            Precondition.nonzero(rate["raw_loop"], "the bare mj_step loop's steps/s"),
        ),
        Target(
            "ratio_rollout",
            rate["source"] / rate["mujoco.rollout"],
            TARGET_ROLLOUT_RATIO,
            ">=",
            "transitions/s of the data source / env steps/s of one mujoco.rollout call, one core",
            Precondition.nonzero(rate["mujoco.rollout"], "mujoco.rollout's steps/s"),
        ),
        Target(
            "workers_speedup",
            worker_speedup,
            1.7,
            ">=",
            f"transitions/s of a {config.workers}-worker sharded run (merged to disk) / one babble() "
            f"process, {config.sharded_steps} transitions, {os.cpu_count()} cores",
            Precondition.nonzero(worker_rate.get("one process"), "the one-process transitions/s"),
        ),
    ]


@register(
    "babble",
    kind="bench",
    config=Config,
    quick=Config(steps=300, repeats=1, worker_steps=2000),
    tiny=Config(body=BodyChoice(frame_skip=5), steps=40, repeats=1, worker_steps=40),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Babbling throughput: the data source against a bare mj_step loop on the same model."""
    babble_cfg = config.body.babble_config(
        config.steps, config.seed, chunk_size=max(1, (config.steps + 1) // 2)
    )
    source = make_source(babble_cfg)
    env = source.env
    fns, pool = _calls(config, babble_cfg, source)
    with tempfile.TemporaryDirectory(prefix="pal-bench-babble-") as tmp:
        counter = iter(range(10**9))
        if config.record:
            fns["recorded"] = lambda: babble(replace(babble_cfg), Path(tmp) / f"run{next(counter)}")
        log.info("timing %d env steps x %d repeats on %s", config.steps, config.repeats, config.body.source)
        try:
            timings = measure_interleaved(fns, repeats=config.repeats, warmup=1)
        finally:
            pool.close()
        sharded = _time_workers(config, Path(tmp)) if config.workers else {}
    seconds = {k: t.median for k, t in timings.items()}
    rate = {k: config.steps / sec for k, sec in seconds.items()}
    worker_rate = {k: config.sharded_steps / t.median for k, t in sharded.items()}
    worker_speedup = worker_rate["workers"] / worker_rate["one process"] if sharded else None
    c = config
    return Report(
        title="Babbling throughput",
        metrics={
            "transitions_per_s": rate["source"],
            "raw_steps_per_s": rate["raw_loop"],
            "ratio": rate["source"] / rate["raw_loop"],
            "raw_nstep_steps_per_s": rate["raw_nstep"],
            "ratio_nstep": rate["source"] / rate["raw_nstep"],
            "rollout_steps_per_s": rate["mujoco.rollout"],
            "ratio_rollout": rate["source"] / rate["mujoco.rollout"],
            "source_rollout_transitions_per_s": rate["source_rollout"],
            "ratio_source_rollout": rate["source_rollout"] / rate["mujoco.rollout"],
            "workers": config.workers,
            "worker_transitions_per_s": worker_rate,
            "workers_speedup": worker_speedup,
            "cpu_count": os.cpu_count(),
            "load_average_1min": os.getloadavg()[0],
            "recorded_transitions_per_s": rate.get("recorded"),
            "seconds_per_call": seconds,
            "body": env.loaded.name,
            "frame_skip": env.frame_skip,
        },
        tables=_tables(config, seconds, rate, worker_rate, sharded),
        targets=_targets(config, rate, worker_rate, worker_speedup),
        notes=[
            f"Body {env.loaded.name}, {c.steps} environment steps per call, frame skip {env.frame_skip} "
            f"({env.dt:.3g} s per step), uniform commands, median of {c.repeats} repeats; "
            f"{os.cpu_count()} cores, 1-min load average {os.getloadavg()[0]:.2f} at the end of the run."
        ],
    )
