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

Figures: ``transitions_per_s`` (source), ``raw_steps_per_s`` (raw_loop, env steps per s),
``ratio`` = transitions_per_s / raw_steps_per_s (target >= 0.7), and beside them the
``raw_nstep`` rate, its ratio, the recorded rate and median seconds per call. The
contenders alternate inside each repeat so load changes hit all of them.
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import mujoco
import numpy as np

from pal.checks import check_int
from pal.experiments.registry import register
from pal.experiments.report import Report, Table, Target
from pal.experiments.timing import measure_interleaved, ratio
from pal.experiments.wm_data import BodyChoice
from pal.sim.babbling import babble, make_source

__all__ = ["TARGET_RATIO", "Config", "run"]

log = logging.getLogger(__name__)

#: Target of ``ratio``: the data source keeps at least this share of raw mj_step throughput.
TARGET_RATIO = 0.7


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
    """

    seed: int = 0
    body: BodyChoice = BodyChoice()
    steps: int = 4000
    repeats: int = 3
    record: bool = True

    def __post_init__(self) -> None:
        for key in ("steps", "repeats"):
            check_int(key, getattr(self, key))


@register(
    "babble",
    kind="bench",
    config=Config,
    quick=Config(steps=300, repeats=1),
    tiny=Config(body=BodyChoice(frame_skip=5), steps=40, repeats=1),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Babbling throughput: the data source against a bare mj_step loop on the same model."""
    babble_cfg = config.body.babble_config(
        config.steps, config.seed, chunk_size=max(1, (config.steps + 1) // 2)
    )
    source = make_source(babble_cfg)
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

    fns = {"source": source_run, "raw_loop": raw_loop, "raw_nstep": raw_nstep}
    with tempfile.TemporaryDirectory(prefix="pal-bench-babble-") as tmp:
        counter = iter(range(10**9))
        if config.record:
            fns["recorded"] = lambda: babble(replace(babble_cfg), Path(tmp) / f"run{next(counter)}")
        log.info("timing %d env steps x %d repeats on %s", config.steps, config.repeats, config.body.source)
        timings = measure_interleaved(fns, repeats=config.repeats, warmup=1)
    seconds = {k: t.median for k, t in timings.items()}
    rate = {k: config.steps / sec for k, sec in seconds.items()}
    order = ("source", "raw_loop", "raw_nstep", "recorded")
    rows = [(k, seconds[k], rate[k], ratio(rate[k], rate["raw_loop"])) for k in order if k in rate]
    c = config
    return Report(
        title="Babbling throughput",
        metrics={
            "transitions_per_s": rate["source"],
            "raw_steps_per_s": rate["raw_loop"],
            "ratio": rate["source"] / rate["raw_loop"],
            "raw_nstep_steps_per_s": rate["raw_nstep"],
            "ratio_nstep": rate["source"] / rate["raw_nstep"],
            "recorded_transitions_per_s": rate.get("recorded"),
            "seconds_per_call": seconds,
            "body": env.loaded.name,
            "frame_skip": env.frame_skip,
        },
        tables=[
            Table("Environment steps per second", ("", "seconds per call", "env steps/s", "/ raw_loop"), rows)
        ],
        targets=[
            Target(
                "ratio",
                rate["source"] / rate["raw_loop"],
                TARGET_RATIO,
                ">=",
                "transitions/s of the data source / env steps/s of a bare mj_step loop",
            )
        ],
        notes=[
            f"Body {env.loaded.name}, {c.steps} environment steps per call, frame skip {env.frame_skip} "
            f"({env.dt:.3g} s per step), uniform commands, median of {c.repeats} repeats."
        ],
    )
