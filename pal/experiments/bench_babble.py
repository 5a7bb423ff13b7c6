"""``pal bench babble``: throughput of the babbling data source against bare ``mj_step``.

Contenders, on the same model, each producing ``steps`` environment steps of uniform
random commands with ``frame_skip`` MuJoCo steps each:

* ``source``: :meth:`pal.sim.babbling.BabblingSource.run` — policy draws, command clipping,
  the full state before every step, q before and after, episode resets.
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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from pal.experiments.timing import markdown_table, measure_interleaved, ratio
from pal.sim.babbling import BabbleConfig, babble, make_source

__all__ = ["TARGET_RATIO", "Config", "Result", "run"]

log = logging.getLogger(__name__)

#: Target of ``ratio`` (issue 3).
TARGET_RATIO = 0.7


@dataclass(frozen=True)
class Config:
    """Benchmark sizes.

    Attributes:
        body: body name or MJCF path.
        steps: environment steps per timed call.
        frame_skip: MuJoCo steps per environment step.
        repeats: timed repeats (median reported) after one warm-up of each contender.
        seed: seed of the commands.
        record: also time ``babble`` to disk (``recorded``).
    """

    body: str = "finger"
    steps: int = 4000
    frame_skip: int = 50
    repeats: int = 3
    seed: int = 0
    record: bool = True

    @classmethod
    def quick(cls) -> Config:
        return cls(steps=300, repeats=1)


@dataclass(frozen=True)
class Result:
    """Throughputs in environment steps (transitions) per second; see the module docstring."""

    transitions_per_s: float
    raw_steps_per_s: float
    ratio: float
    raw_nstep_steps_per_s: float
    ratio_nstep: float
    recorded_transitions_per_s: float | None
    seconds: dict[str, float] = field(default_factory=dict)
    config: Config = field(default_factory=Config)

    def to_dict(self) -> dict[str, Any]:
        return {
            "transitions_per_s": self.transitions_per_s,
            "raw_steps_per_s": self.raw_steps_per_s,
            "ratio": self.ratio,
            "target_ratio": TARGET_RATIO,
            "raw_nstep_steps_per_s": self.raw_nstep_steps_per_s,
            "ratio_nstep": self.ratio_nstep,
            "recorded_transitions_per_s": self.recorded_transitions_per_s,
            "seconds_per_call": dict(self.seconds),
            "body": self.config.body,
            "steps": self.config.steps,
            "frame_skip": self.config.frame_skip,
        }

    def to_markdown(self) -> str:
        c = self.config
        rates = {
            "source": self.transitions_per_s,
            "raw_loop": self.raw_steps_per_s,
            "raw_nstep": self.raw_nstep_steps_per_s,
            "recorded": self.recorded_transitions_per_s,
        }
        rows = [
            [k, self.seconds.get(k), v, ratio(v, self.raw_steps_per_s)]
            for k, v in rates.items()
            if v is not None
        ]
        met = "met" if self.ratio >= TARGET_RATIO else "NOT met"
        return (
            "\n".join(
                [
                    "## Babbling throughput",
                    "",
                    f"body `{c.body}`, {c.steps} environment steps per call, frame skip {c.frame_skip}, "
                    f"uniform commands, median of {c.repeats} repeats.",
                    "",
                    markdown_table(["", "seconds per call", "env steps/s", "/ raw_loop"], rows),
                    "",
                    f"ratio source / raw mj_step loop: **{self.ratio:.3g}** (target >= {TARGET_RATIO}: {met}); "
                    f"against one mj_step(nstep) call per step: {self.ratio_nstep:.3g}.",
                ]
            )
            + "\n"
        )

    def figures(self) -> dict[str, Any]:
        return {}


def run(config: Config, progress_bar: bool = False) -> Result:
    """Time the data source and the raw ``mj_step`` loops alternately."""
    if config.steps < 1 or config.repeats < 1:
        raise ValueError(
            f"steps and repeats must be >= 1, got steps={config.steps}, repeats={config.repeats}"
        )
    babble_cfg = BabbleConfig(
        body=config.body,
        steps=config.steps,
        seed=config.seed,
        frame_skip=config.frame_skip,
        chunk_size=max(1, (config.steps + 1) // 2),
    )
    source = make_source(babble_cfg)
    model = source.env.model
    raw_data = mujoco.MjData(model)
    env = source.env
    commands = np.random.default_rng(config.seed).uniform(
        env.ctrl_low, env.ctrl_high, size=(config.steps, len(env.actuator_ids))
    )
    aidx, fs = env.actuator_ids, config.frame_skip

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
        log.info("timing %d env steps x %d repeats on %s", config.steps, config.repeats, config.body)
        timings = measure_interleaved(fns, repeats=config.repeats, warmup=1)
    seconds = {k: t.median for k, t in timings.items()}
    rate = {k: config.steps / s for k, s in seconds.items()}
    result = Result(
        transitions_per_s=rate["source"],
        raw_steps_per_s=rate["raw_loop"],
        ratio=rate["source"] / rate["raw_loop"],
        raw_nstep_steps_per_s=rate["raw_nstep"],
        ratio_nstep=rate["source"] / rate["raw_nstep"],
        recorded_transitions_per_s=rate.get("recorded"),
        seconds=seconds,
        config=config,
    )
    if result.ratio < TARGET_RATIO:
        log.warning("babbling throughput ratio %.3g is below the target %.2g", result.ratio, TARGET_RATIO)
    return result
