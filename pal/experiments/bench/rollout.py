"""``pal bench rollout``: batched replay from recorded states against the serial loop.

Realized evaluation (B2, B3) executes one command from each of many recorded simulator
states. On the same in-memory babbling recording, each contender replays the same ``targets``
(row, command) pairs, uniform commands over the analysed actuator's range:

* ``serial`` (the baseline): :meth:`pal.experiments.world_model.data.Realizer.outcomes` with
  ``batched=False``, one :func:`pal.sim.babbling.replay` (restore the state, one
  ``env.step``) per target.
* ``batched``: the same call with ``batched=True``: all targets in one ``mujoco.rollout``
  call on the calling thread (:class:`pal.sim.batched.BatchReplayer`).
* ``batched_threads`` (with ``threads`` > 0): one rollout on a pool of ``threads`` threads.
* ``bare loop``: the same replays as a bare Python loop of ``mj_setState`` and ``mj_step``
  (no checks, no copies): what is left of the serial loop when its overheads are gone.

Figures: ``speedup`` = serial seconds / batched seconds (target >= 3 for 128 targets), and
``identical``: every batched angle equals the serial one bit for bit (``np.array_equal``).
The physics itself (``targets * frame_skip`` MuJoCo steps) is the same on both sides, so the
speed-up on one thread is bounded by the share of the serial time spent outside the physics;
``physics_share`` (bare loop seconds / serial seconds) estimates it: the one-thread speed-up
stays near ``1 / physics_share``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from pal.checks import check_int
from pal.experiments.world_model.data import BodyChoice, JointData, Realizer, pick_rows
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import Timing, measure_interleaved, ratio
from pal.sim.babbling import collect
from pal.sim.batched import BatchReplayer
from pal.sim.env import STATE_SPEC

__all__ = ["TARGET_SPEEDUP", "Config", "run"]

log = logging.getLogger(__name__)

#: Target of ``speedup`` (batched realized evaluation against the serial loop).
TARGET_SPEEDUP = 3.0


@dataclass(frozen=True)
class Config:
    """Benchmark sizes.

    Attributes:
        seed: seed of the recording, the rows and the commands.
        body: the body, its babbling actuators, command ranges and frame skip.
        steps: transitions of the recording the targets are drawn from.
        targets: (row, command) pairs replayed per timed call (the issue's figure: 128).
        repeats: timed repeats (median reported) after one warm-up of each contender.
        threads: threads of the ``batched_threads`` contender (0: leave it out).
    """

    seed: int = 0
    body: BodyChoice = BodyChoice()
    steps: int = 1000
    targets: int = 128
    repeats: int = 5
    threads: int = 0

    def __post_init__(self) -> None:
        for key in ("steps", "targets", "repeats"):
            check_int(key, getattr(self, key))
        check_int("threads", self.threads, minimum=0)


def _time(config: Config) -> tuple[dict[str, Timing], np.ndarray, Any]:
    """Record, pick the targets and time the replays: (timings, rows, the realizer's env)."""
    dataset = collect(config.body.babble_config(config.steps, config.seed, chunk_size=config.steps))
    joint = JointData.select(dataset, config.body.joint)
    realizer = Realizer(dataset, joint, config.body.source)
    rows = pick_rows(len(dataset), config.targets, config.seed)
    if len(rows) < config.targets:
        rows = np.resize(rows, config.targets)  # more targets than rows: rows repeat
    low, high = joint.action_range
    actions = np.random.default_rng(config.seed).uniform(low, high, size=len(rows))
    env = realizer.env
    bare = mujoco.MjData(env.model)
    bare_ctrls = dataset.ctrl[rows].astype(np.float64)
    bare_ctrls[:, joint.actuator_index] = actions
    bare_ctrls = np.clip(bare_ctrls, env.ctrl_low, env.ctrl_high)

    def bare_loop() -> None:  # the same replays with nothing but mj_setState and mj_step
        m, aidx = env.model, env.actuator_ids
        for i, c in zip(rows, bare_ctrls, strict=True):
            mujoco.mj_setState(m, bare, dataset.states[i], STATE_SPEC)
            bare.ctrl[aidx] = c
            mujoco.mj_step(m, bare, env.frame_skip)

    fns = {
        "serial": lambda: realizer.outcomes(rows, actions, batched=False),
        "batched": lambda: realizer.outcomes(rows, actions),
        "bare loop": bare_loop,
    }
    pool = BatchReplayer(env, threads=config.threads) if config.threads else None
    if pool is not None:
        ctrls = dataset.ctrl[rows].astype(np.float64)
        ctrls[:, joint.actuator_index] = actions
        fns["batched_threads"] = lambda: pool.step(dataset.states[rows], ctrls)[:, joint.joint_index]
    try:
        log.info("timing %d targets x %d repeats on %s", len(rows), config.repeats, config.body.source)
        timings = measure_interleaved(fns, repeats=config.repeats, warmup=1)
    finally:
        if pool is not None:
            pool.close()
    return timings, rows, env


@register(
    "rollout",
    kind="bench",
    config=Config,
    quick=Config(steps=300, targets=128, repeats=3),
    tiny=Config(body=BodyChoice(frame_skip=5), steps=40, targets=8, repeats=1, threads=2),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Realized evaluation: batched ``mujoco.rollout`` replay against the one-by-one loop."""
    timings, rows, env = _time(config)
    serial = timings["serial"].result
    identical = {
        k: bool(np.array_equal(timings[k].result, serial))
        for k in ("batched", "batched_threads")
        if k in timings
    }
    seconds = {k: t.median for k, t in timings.items()}
    speedup = {k: ratio(seconds["serial"], seconds[k]) for k in seconds}
    rows_out = [
        (k, seconds[k], len(rows) / seconds[k], speedup[k], identical.get(k, k == "serial" or None))
        for k in ("serial", "batched", "batched_threads", "bare loop")
        if k in seconds
    ]
    all_identical = all(identical.values())
    return Report(
        title="Batched replay from recorded states",
        metrics={
            "speedup": speedup["batched"],
            "speedup_threads": speedup.get("batched_threads"),
            "identical": all_identical,
            "physics_share": seconds["bare loop"] / seconds["serial"],
            "seconds_per_call": seconds,
            "targets": len(rows),
            "threads": config.threads,
            "cpu_count": os.cpu_count(),
            "load_average_1min": os.getloadavg()[0],
            "body": env.loaded.name,
            "frame_skip": env.frame_skip,
        },
        tables=[
            Table(
                "Realized evaluation, one call",
                ("", "seconds per call", "targets/s", "serial / this", "identical to serial"),
                rows_out,
            )
        ],
        targets=[
            Target(
                "speedup",
                speedup["batched"],
                TARGET_SPEEDUP,
                ">=",
                f"serial seconds / batched seconds, {len(rows)} targets, one thread",
                Precondition.nonzero(seconds["serial"], "the serial seconds"),
            ),
            Target(
                "identical",
                float(all_identical),
                1.0,
                ">=",
                "batched angles equal the serial ones bit for bit",
            ),
        ],
        notes=[
            f"Body {env.loaded.name}, frame skip {env.frame_skip}, {len(rows)} targets from a {config.steps}-step "
            f"recording, median of {config.repeats} repeats; {os.cpu_count()} cores, 1-min load average "
            f"{os.getloadavg()[0]:.2f} at the end of the run.",
            "The physics is the same on both sides: on one thread the speed-up stays near "
            "1 / physics_share (bare loop seconds / serial seconds).",
        ],
    )
