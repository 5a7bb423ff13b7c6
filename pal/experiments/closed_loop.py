"""``pal loop``: run the closed perception-action loop and film it; plus the short loop of ``pal demo``.

:func:`run_loop` builds the pushing world (:class:`pal.sim.pushing.PushingEnv`) and an
:class:`pal.agent.Agent`, babbles for ``babble`` steps, fits the world model, then runs the rest of
the steps curiosity-driven (or towards a user goal for the box), refitting every ``refit_every``
steps. With ``video`` set, every step's camera frame is written with Π's detections and ids, the
slots, the state estimates, the targets and the model's predicted outcomes overlaid
(:mod:`pal.agent.video`).
"""

from __future__ import annotations

import logging
import os
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from pal.agent import Agent, AgentConfig, Decision, Percept
from pal.agent.curiosity import grid_occupancy
from pal.agent.video import VideoRecorder, overlay
from pal.experiments.output import write_json
from pal.sim.pushing import PushingEnv

__all__ = ["LoopConfig", "loop_demo_lines", "run_loop"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoopConfig:
    """A filmed run of the loop.

    Attributes:
        steps: total loop steps (babbling included).
        babble: babbling steps before the first fit (default: half of ``steps``).
        goal: optional (x, y) goal for the box, table frame, m; default curiosity-driven.
        seed: master seed.
        fps: video frame rate.
        camera_size: (width, height) of the camera, pixels.
        agent: the agent's settings.
    """

    steps: int = 60
    babble: int | None = None
    goal: tuple[float, float] | None = None
    seed: int = 0
    fps: float = 4.0
    camera_size: tuple[int, int] = (320, 240)
    agent: AgentConfig = field(default_factory=AgentConfig)

    def __post_init__(self) -> None:
        if isinstance(self.steps, bool) or not isinstance(self.steps, int) or self.steps < 1:
            raise ValueError(f"steps must be a positive int, got {self.steps!r}")
        if self.babble is not None and not 1 <= self.babble <= self.steps:
            raise ValueError(f"babble must be in [1, steps={self.steps}], got {self.babble}")
        if self.goal is not None and (len(self.goal) != 2 or not np.all(np.isfinite(self.goal))):
            raise ValueError(f"goal must be a finite (x, y) in metres, got {self.goal!r}")


def _frame(agent: Agent, decision: Decision | None, percept: Percept, step: int) -> np.ndarray:
    mode = decision.mode if decision is not None else "start"
    return overlay(
        percept.frame.rgb,
        percept.perception,
        percept.frame.K,
        percept.table_from_camera,
        slots=agent.slots.bound,
        estimates=agent.estimate,
        targets=decision.targets if decision is not None else agent.goal,
        predicted=decision.predicted if decision is not None else None,
        status=f"step {step}  episode {agent.episode}  {mode}",
    )


def run_loop(
    config: LoopConfig, video: str | os.PathLike[str] | None = None, *, progress_bar: bool = False
) -> dict[str, Any]:
    """Run the loop (module docstring); returns a JSON-compatible summary."""
    start = time.perf_counter()
    babble = config.babble if config.babble is not None else max(1, config.steps // 2)
    env = PushingEnv(camera_size=config.camera_size)
    agent_cfg = replace(config.agent, seed=config.seed)
    goal = None if config.goal is None else {agent_cfg.objects[0]: np.asarray(config.goal, float)}
    agent = Agent(env, agent_cfg, goal=goal)
    recorder = VideoRecorder(video, config.fps) if video is not None else None
    modes: Counter[str] = Counter()
    step = 0

    def film(a: Agent, decision: Decision, percept: Percept) -> None:
        nonlocal step
        step += 1
        if step > babble:  # the decisions after the babbling phase
            modes[decision.mode] += 1
        if recorder is not None:
            recorder.write(_frame(a, decision, percept, step))

    try:
        agent.reset()
        if recorder is not None:
            recorder.write(_frame(agent, None, agent.percept, 0))
        agent.run(babble, "babble", callback=film, progress_bar=progress_bar)
        fit_rows = agent.refit()["rows"]
        rest = config.steps - babble
        agent.run(rest, "curious" if goal is None else "goal", callback=film, progress_bar=progress_bar)
    finally:
        path = recorder.close() if recorder is not None else None
        env.close()
    est = agent.history.array("est")
    low, high = agent_cfg.region
    coverage = {}
    for k, o in enumerate(agent_cfg.objects):
        ok = np.isfinite(est[:, k, 0])
        coverage[o] = grid_occupancy(est[ok, k], low, high, agent_cfg.bins) if ok.any() else 0.0
    meas = agent.history.array("meas")
    return {
        "steps": len(agent.history),
        "babble_steps": babble,
        "episodes": agent.episode + 1,
        "modes": dict(modes),  # after babbling: curious / goal / setup / hold, or babble when nothing to gain
        "fit_rows": fit_rows,
        "lost_fraction": {o: float(np.isnan(meas[:, k, 0]).mean()) for k, o in enumerate(agent_cfg.objects)},
        "coverage": coverage,
        "video": None if path is None else str(path),
        "video_frames": None if recorder is None else recorder.frames,
        "seconds": time.perf_counter() - start,
        "config": {k: v for k, v in asdict(config).items() if k != "agent"},
    }


def loop_demo_lines(out_dir: str | os.PathLike[str], quick: bool = False) -> list[str]:
    """The short closed loop of ``pal demo``: babble, fit, a few curiosity-driven steps, filmed.

    Writes ``loop.mp4`` and ``loop.json`` to ``out_dir``; returns the report lines. About 10 s
    with ``quick``, 25 s without, on 2 cores.
    """
    agent = AgentConfig(
        epochs=20 if quick else 40,
        action_starts=8,
        action_steps=30,
        state_steps=30,
        state_lr=0.05,
        reset_every=None,
        refit_every=1000,
    )
    config = LoopConfig(steps=24 if quick else 50, babble=18 if quick else 36, agent=agent)
    out = Path(out_dir)
    summary = run_loop(config, out / "loop.mp4")
    write_json(out / "loop.json", summary)
    return [
        "Closed loop (issue 6): the arm pushes a box and a ball; Π -> measurement sites -> world model -> action",
        f"   {summary['steps']} steps: {summary['babble_steps']} babbling, then curiosity-driven "
        f"({', '.join(f'{k} {v}' for k, v in sorted(summary['modes'].items()))}; 'babble' where the model "
        "saw nothing to gain)",
        f"   world model fitted on {summary['fit_rows']} transitions (arm, and per object the rows where it was seen twice)",
        "   objects lost by perception: "
        + ", ".join(f"{o} {100 * f:.0f} %" for o, f in summary["lost_fraction"].items()),
        f"   video with detections, ids, estimates and targets: {summary['video']} ({summary['video_frames']} frames, "
        f"{summary['seconds']:.1f} s)",
    ]
