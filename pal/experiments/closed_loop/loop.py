"""``pal loop`` (= ``pal experiment loop``): run the closed perception-action loop and film it.

The run builds the pushing world (:class:`pal.sim.pushing.PushingEnv`, its camera view in
``info``) and an :class:`pal.agent.Agent` over it (:func:`pal.agent.pushing_spec`), babbles for
``babble`` steps, fits the world model, then runs the rest of the steps curiosity-driven (or
towards a user goal for the box), refitting every ``agent.learn.refit_every`` steps. With ``video`` set, every step's camera frame is written there with
Π's detections and ids, the slots, the state estimates, the targets and the model's predicted
outcomes overlaid (:mod:`pal.agent.video`). Its quick configuration is the loop of ``pal demo``.

Metrics: ``steps``, ``babble_steps``, ``episodes``, ``modes`` (decisions after babbling: curious /
goal / setup / hold, or babble where the model saw nothing to gain), ``fit_rows`` (arm, and per
object the rows where it was seen twice), ``lost_fraction`` and ``coverage`` per object (share
of frames perception lost it; share of the curiosity grid its estimates visited), ``video`` and
``video_frames``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from inference import SamplingConfig
from pal.agent import (
    Agent,
    AgentConfig,
    CuriosityConfig,
    Decision,
    EstimateConfig,
    LearnConfig,
    ModelConfig,
    Percept,
    PlanConfig,
    pushing_spec,
)
from pal.agent.config import ESTIMATE_SVI, MODEL_SCHEDULE, PLAN_ACTION, PLAN_SAMPLING
from pal.agent.curiosity import grid_occupancy
from pal.agent.video import VideoRecorder, overlay
from pal.checks import MAX_LOOP_STEPS, check_float, check_int
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target
from pal.sim.pushing import PushingEnv

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["MAX_LOST_FRACTION", "Config", "run"]

#: Perception should keep track of each object in at least this share of the frames (1 - lost).
MAX_LOST_FRACTION = 0.25


@dataclass(frozen=True)
class Config:
    """A filmed run of the loop.

    Attributes:
        seed: master seed of the agent (world resets, actions, fits, inference).
        steps: total loop steps (babbling included), at most :data:`pal.checks.MAX_LOOP_STEPS`.
        babble: babbling steps before the first fit, in [1, steps] (default: half of ``steps``).
        goal: optional (x, y) goal for the box, table frame, m; default curiosity-driven.
        video: optional mp4 path; the annotated video is written there.
        fps: video frame rate.
        camera_size: (width, height) of the camera, pixels.
        agent: the agent's settings.
    """

    seed: int = 0
    steps: int = 60
    babble: int | None = None
    goal: tuple[float, float] | None = None
    video: str | None = None
    fps: float = 4.0
    camera_size: tuple[int, int] = (320, 240)
    agent: AgentConfig = AgentConfig()

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        check_int("steps", self.steps, maximum=MAX_LOOP_STEPS)
        if self.babble is not None:
            check_int("babble", self.babble)
            if self.babble > self.steps:
                raise ValueError(
                    f"babble must be in [1, steps={self.steps}], got {self.babble}; lower babble or raise steps"
                )
        if self.goal is not None:
            if len(self.goal) != 2:
                raise ValueError(f"goal must be a finite (x, y) in metres, got {self.goal!r}")
            object.__setattr__(self, "goal", tuple(check_float("goal", v) for v in self.goal))
        if self.video is not None and not str(self.video).endswith(".mp4"):
            raise ValueError(f"video {self.video!r}: expected a path ending in .mp4")
        check_float("fps", self.fps, 0.0, open_low=True)
        if len(self.camera_size) != 2:
            raise ValueError(f"camera_size must be (width, height) in pixels, got {self.camera_size!r}")
        object.__setattr__(
            self, "camera_size", tuple(check_int("camera_size", v, 16) for v in self.camera_size)
        )

    @property
    def babble_steps(self) -> int:
        """Babbling steps of the run: ``babble``, or half of ``steps`` (at least 1)."""
        return self.babble if self.babble is not None else max(1, self.steps // 2)


#: The agent of the demo's loop: a short fit, light inference, one episode, no refit.
QUICK_AGENT = AgentConfig(
    model=ModelConfig(members=3, schedule=replace(MODEL_SCHEDULE, epochs=40)),
    estimate=EstimateConfig(num_steps=30, svi=replace(ESTIMATE_SVI, lr=0.05)),
    plan=PlanConfig(
        action=replace(
            PLAN_ACTION,
            sampling=replace(PLAN_SAMPLING, population=32, elites=4, iterations=2, refine_steps=10),
        )
    ),
    curiosity=CuriosityConfig(sampling=SamplingConfig(population=32, elites=4, iterations=2)),
    learn=LearnConfig(refit_every=1000),
    reset_every=None,
)
QUICK = Config(steps=50, babble=36, agent=QUICK_AGENT)
TINY = Config(
    steps=12,
    babble=8,
    camera_size=(240, 180),
    agent=replace(
        QUICK_AGENT,
        model=ModelConfig(
            members=2, hidden=(16,), schedule=replace(MODEL_SCHEDULE, epochs=10, patience=None)
        ),
        plan=PlanConfig(
            action=replace(
                PLAN_ACTION,
                sampling=replace(PLAN_SAMPLING, population=8, elites=2, iterations=1, refine_steps=3),
            )
        ),
        curiosity=CuriosityConfig(
            sampling=SamplingConfig(population=8, elites=2, iterations=1), influence_samples=4
        ),
        learn=LearnConfig(refit_every=10),
        reset_every=6,
    ),
)


def _frame(agent: Agent, decision: Decision | None, percept: Percept, step: int) -> np.ndarray:
    mode = decision.mode if decision is not None else "start"
    return overlay(
        percept.frame.rgb,
        percept.perception,
        percept.frame.K,
        percept.table_from_camera,
        slots=agent.senses.slots.bound,
        estimates=agent.estimate,
        targets=decision.targets if decision is not None else agent.goal,
        predicted=decision.predicted if decision is not None else None,
        status=f"step {step}  episode {agent.episode}  {mode}",
    )


def _tables(metrics: dict[str, Any], objects: tuple[str, ...]) -> list[Table]:
    fit_rows, lost, coverage = metrics["fit_rows"], metrics["lost_fraction"], metrics["coverage"]
    summary = [
        ["loop steps", metrics["steps"]],
        ["babbling steps", metrics["babble_steps"]],
        ["episodes", metrics["episodes"]],
        ["arm transitions fitted", fit_rows["arm"]],
        *[[f"decisions after babbling: {m}", n] for m, n in sorted(metrics["modes"].items())],
        ["video", metrics["video"]],
        ["video frames", metrics["video_frames"]],
    ]
    return [
        Table("Run", ["quantity", "value"], summary),
        Table(
            "Objects",
            ["object", "frames lost [share]", "estimate coverage [share of cells]", "transitions fitted"],
            [[o, lost[o], coverage[o], fit_rows.get(o)] for o in objects],
            caption="Transitions fitted: the babbling steps in which the object was perceived before and after.",
        ),
    ]


@register("loop", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """The closed loop: babble, fit, then curiosity-driven (or goal-directed) pushing, filmed."""
    babble = config.babble_steps
    cfg = config.agent
    env = PushingEnv(camera_size=config.camera_size, camera=True)
    spec = pushing_spec()
    goal = None if config.goal is None else {spec.object_names[0]: np.asarray(config.goal, float)}
    agent = Agent(env, spec, cfg, seed=config.seed, goal=goal)
    recorder = VideoRecorder(config.video, config.fps) if config.video is not None else None
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
        mode = "curious" if goal is None else "goal"
        agent.run(config.steps - babble, mode, callback=film, progress_bar=progress_bar)
    finally:
        path = recorder.close() if recorder is not None else None
        env.close()
    history = agent.history
    est, meas, truth = (history.array(f) for f in ("est", "meas", "truth"))
    low, high = cfg.curiosity.region
    lost, coverage = {}, {}
    for k, o in enumerate(spec.object_names):
        ok = np.isfinite(est[:, k, 0])
        coverage[o] = grid_occupancy(est[ok, k], low, high, cfg.curiosity.bins) if ok.any() else 0.0
        lost[o] = float(np.isnan(meas[:, k, 0]).mean())
    metrics = {
        "steps": len(history),
        "babble_steps": babble,
        "episodes": agent.episode + 1,
        "modes": dict(modes),
        "fit_rows": fit_rows,
        "lost_fraction": lost,
        "coverage": coverage,
        "video": None if path is None else str(path),
        "video_frames": None if recorder is None else recorder.frames,
    }
    return Report(
        title="The closed perception-action loop: Π -> measurement sites -> world model -> action",
        metrics=metrics,
        tables=_tables(metrics, spec.object_names),
        targets=[
            Target(
                f"lost_fraction.{o}",
                lost[o],
                MAX_LOST_FRACTION,
                "<=",
                f"share of the frames in which perception lost the {o}",
            )
            for o in spec.object_names
        ],
        notes=[
            f"The arm pushes {' and '.join(spec.object_names)} for {metrics['steps']} steps (seed {config.seed}): "
            f"{babble} babbling steps, then {'curiosity-driven' if goal is None else 'goal-directed'} steps.",
        ],
        figures={"paths": _paths_figure(history.objects, history.array("episode"), est, truth)},
    )


def _paths_figure(
    objects: tuple[str, ...], episode: np.ndarray, est: np.ndarray, truth: np.ndarray
) -> Figure:
    """True paths (a line per episode) and state estimates (dots) of every object, table plane."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.8, 3.8))
    for k, o in enumerate(objects):
        colour = f"C{k}"
        for i, e in enumerate(np.unique(episode)):
            rows = episode == e
            label = f"{o}, true" if i == 0 else None
            ax.plot(truth[rows, k, 0], truth[rows, k, 1], color=colour, lw=1, label=label)
        ax.plot(est[:, k, 0], est[:, k, 1], color=colour, ls="none", marker=".", ms=4, label=f"{o}, estimate")
    ax.set(xlabel="x, m", ylabel="y, m", title="object positions on the table", aspect="equal")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
