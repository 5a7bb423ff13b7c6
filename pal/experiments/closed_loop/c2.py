"""Experiment C2: goal-directed pushing of the box to 20 targets, judged in the simulator.

After babbling and fitting (:mod:`pal.experiments.closed_loop.setup`), each of ``targets`` episodes puts
the box at a seeded start (``start_radius`` m from the shoulder, within ``bearing_deg`` of the
workspace's central bearing, random yaw), the ball out of reach, the arm at rest, and draws a goal
``distance`` m away in a direction ``cone_deg`` from the arm's sweep direction (the
counter-clockwise tangent about the shoulder; negative angles turn it outwards, away from the body;
pushing the box towards the body needs the hand beyond it, which this arm rarely manages). Three
controllers get ``episode_steps`` steps from the same start:

- ``inferred``: the agent in goal mode (:meth:`pal.agent.Agent.decide`): per step Π, the state
  posterior through the measurement sites, and model-predictive control: the sampling planner
  over ``agent.plan.action.horizon`` steps through the ensemble world model, replanned every step
  (:mod:`pal.agent.plan`); it holds when the model predicts no progress. The goal is given to it
  as the wanted displacement of the box (its perceived start plus the true offset), so the constant
  offset between the perceived point and the box centre does not count against it;
- ``random``: uniform random servo targets;
- ``scripted``: :class:`~pal.baselines.scripted_pusher.ScriptedPusher`, which knows the true state
  and checks its approach moves in the simulator.

``final_err_cm``: true distance of the box centre from the goal after the episode (from the
environment's ``info``; the random and scripted controllers run on a second, camera-less world with
the same starts). For the agent, ``model_err_cm``: the distance to its goal that the world model
predicted for its last executed action (the plan's objective: the members' mean rollout without
noise; optimistic), ``model_expected_err_cm``: the model's expected distance for that plan
(:func:`pal.agent.plan.expected_distance`), and ``belief_err_cm``: the distance of its final state
estimate (posterior mean) from it; ``prediction_factor``: how far the median realized final error
is from the median ``model_expected_err_cm`` (the larger of the two ratios; target ≤ 1.5). For
every executed push (touch), the model's predicted displacement of the box over the step with its
90 % interval is held against the true one (``pushes``, ``push_interval_coverage``: the planner's
own Normal of the step, per component).

Calibration per regime (:mod:`.regimes`, :mod:`.regime_report`): every step the agent took in
goal mode (its planned actions) is a held-out row of each object; the agent's model gives the
displacement its predictive distribution from the actions, joint angles, sensed hand and
perceived position before the step (contact, hand and members sampled,
:func:`inference.predictive_intervals`), and its 90 % interval should cover 85-95 % of the true
displacement components on the contact rows (the planned pushes) and on the no-contact rows,
where the median predicted sd should be at most 1 mm (``regimes``; figure ``calibration``).

Metrics: ``{inferred|random|scripted: {final_err_cm_median, _mean, _p25, _p75, within_2cm}}``,
``model_err_cm_median``, ``model_expected_err_cm_median``, ``belief_err_cm_median``, ``initial_err_cm_median``,
``random_over_inferred``, ``scripted_over_inferred``, ``prediction_factor``, ``regimes`` (regime
-> coverage, median sd and |error| in mm, rows, reliability), ``episodes`` (one record per
target) and ``info``.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pal.agent import Agent, AgentConfig, PlanConfig
from pal.agent.config import PLAN_ACTION
from pal.agent.plan import expected_distance
from pal.baselines.scripted_pusher import ScriptedPusher
from pal.checks import check_int
from pal.experiments.closed_loop.c2_plots import Z90, episodes_figure, paths_figure, pushes_figure
from pal.experiments.closed_loop.push_goals import GoalGeometry, push_goals
from pal.experiments.closed_loop.regime_report import calibration_figure, regime_table, regime_targets
from pal.experiments.closed_loop.regimes import regime_rows, summarize
from pal.experiments.closed_loop.setup import QUICK_SETUP, TINY_SETUP, SetupConfig, babbled_agent, summary
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import ratio
from pal.sim.pushing import PushingEnv

__all__ = [
    "CONDITIONS",
    "REGIMES",
    "SETUP",
    "TARGET_ERR_CM",
    "TARGET_PREDICTION_FACTOR",
    "TARGET_VS_RANDOM",
    "Config",
    "goals",
    "run",
]

log = logging.getLogger(__name__)

CONDITIONS = ("inferred", "random", "scripted")
#: The agent's median final error should be at most this, cm (and below the scripted pusher's) ...
TARGET_ERR_CM = 1.5
#: ... and at least this many times smaller than random babbling's.
TARGET_VS_RANDOM = 5.0
#: A ratio of two conditions' distances counts only if each moved the box this far in an episode, cm.
MOVED_CM = 0.5
#: The agent's median realized final error should be within this factor of its model's median prediction of it.
TARGET_PREDICTION_FACTOR = 1.5
#: The regimes of the agent's goal-mode steps.
REGIMES = ("planned contact", "planned no contact")
#: Where the ball waits during C2 (out of the arm's reach, in view), table frame, m.
BALL_PARK = (-0.22, 0.0, 0.0)


#: C2's agent plans over 4 steps instead of the agent's default 2: a 2-step plan cannot bring the
#: hand round to the box's far side once it is close, so the agent holds or nudges ~2 cm from its
#: goal. Measured (``pal experiment c2 --set seed=S --set setup.agent.plan.action.horizon=H``, 20
#: goals): median final error 2.10 / 2.42 / 3.88 cm at H = 2 for seeds 0 / 1 / 2, 1.74 / 1.61 /
#: 2.70 cm at H = 4 (means 3.43 / 4.60 / 4.24 against 2.15 / 2.25 / 3.04 cm); H = 6 gave 1.88 cm on seed 0.
SETUP = SetupConfig(agent=AgentConfig(plan=PlanConfig(action=replace(PLAN_ACTION, horizon=4))))


@dataclass(frozen=True)
class Config:
    """C2 protocol (module docstring); sizes in metres and degrees.

    Attributes:
        seed: master seed (babbling, fits, episodes, inference).
        setup: babbling and fitting, and the agent's settings (:data:`SETUP`: planning horizon 4).
        targets: goal episodes.
        episode_steps: steps per episode and controller.
        geometry: where the box starts and where its goal lies (m, deg).
        num_samples: draws per planned step of the predictive distribution.
    """

    seed: int = 0
    setup: SetupConfig = SETUP
    targets: int = 20
    episode_steps: int = 15
    geometry: GoalGeometry = GoalGeometry()
    num_samples: int = 200

    def __post_init__(self) -> None:
        check_int("num_samples", self.num_samples, minimum=2)
        check_int("seed", self.seed, minimum=0)
        check_int("targets", self.targets)
        check_int("episode_steps", self.episode_steps)


QUICK = Config(
    setup=replace(QUICK_SETUP, agent=replace(QUICK_SETUP.agent, plan=SETUP.agent.plan)),
    targets=2,
    episode_steps=3,
)
TINY = Config(setup=TINY_SETUP, targets=1, episode_steps=2, num_samples=20)


def goals(config: Config, heading: float, shoulder: np.ndarray) -> list[dict[str, Any]]:
    """The seeded episodes (:func:`pal.experiments.closed_loop.push_goals.push_goals`, stream 62)."""
    return push_goals(config.geometry, config.seed, config.targets, heading, shoulder, stream=62)


def _truth(agent: Agent) -> np.ndarray:
    """The box centre (2,) that the environment reports in ``info`` (evaluation only)."""
    return np.asarray(agent.percept.evaluation["truth"]["box"][:2], dtype=np.float64)


def _inferred(
    agent: Agent, spec: dict[str, Any], goal: np.ndarray, steps: int
) -> tuple[dict[str, Any], list[np.ndarray]]:
    """The agent in goal mode for ``steps`` steps; its record (model and belief errors, modes, pushes) and box path."""
    agent.reset(seed=spec["seed"], options={"objects": {"box": spec["box"], "ball": BALL_PARK}})
    est = agent.estimate.get("box")
    if est is None:
        log.warning("the box was not perceived at the start of an episode; the agent cannot act on it")
        agent.goal = {}
    else:
        agent.goal = {"box": est + (goal - np.asarray(spec["box"][:2]))}
    last, expected, path, pushes, planned = None, None, [], [], []
    modes: Counter[str] = Counter()
    for _ in range(steps):
        before = _truth(agent)
        path.append(before)
        decision = agent.decide("goal")
        modes[decision.mode] += 1
        if decision.mode == "goal":
            last = decision
            planned.append(len(agent.history))  # the row this step appends
            expected = expected_distance(
                agent.model, agent.belief(), decision.sequence, decision.targets, seed=len(agent.history)
            )
        percept = agent.step(decision.action)
        if decision.mode == "goal" and percept.touch[0] > 0 and "box" in decision.step_mean:
            pushes.append([*decision.step_mean["box"], *decision.step_sd["box"], *(_truth(agent) - before)])
    end = agent.estimate.get("box")
    path.append(_truth(agent))
    record = {
        "model_err_cm": None if last is None else 100 * float(last.objective),
        "model_expected_err_cm": None if expected is None else 100 * expected,
        "belief_err_cm": None
        if end is None or not agent.goal
        else 100 * float(np.linalg.norm(end - agent.goal["box"])),
        "modes": dict(modes),
        "pushes": pushes,
        "planned_rows": planned,
    }
    return record, path


def _episode(
    agent: Agent, judge: PushingEnv, spec: dict[str, Any], condition: str, steps: int
) -> tuple[dict[str, Any], np.ndarray]:
    """One episode of ``condition``: its record (``final_err_cm``, cm) and the box centre's path (T + 1, 2), m."""
    goal = np.asarray(spec["goal"], float)
    if condition == "inferred":
        record, path = _inferred(agent, spec, goal, steps)
    else:
        record, path = {}, []
        judge.reset(seed=spec["seed"], options={"objects": {"box": spec["box"], "ball": BALL_PARK}})
        rng = np.random.default_rng(spec["seed"])
        pusher = ScriptedPusher(judge)
        box = lambda: np.asarray(judge.object_positions()["box"][:2], dtype=np.float64)  # noqa: E731
        for _ in range(steps):
            path.append(box())
            judge.step(
                rng.uniform(judge.ctrl_low, judge.ctrl_high) if condition == "random" else pusher.act(goal)[0]
            )
        path.append(box())
    path = np.array(path).reshape(-1, 2)
    record["final_err_cm"] = 100 * float(np.linalg.norm(path[-1] - goal))
    return record, path


def _run_episodes(config: Config, progress_bar: bool) -> tuple[list, dict, dict, list, int, dict]:
    """Every goal under every condition: episode records, distance traces, box paths, goal specs, fitted rows, regimes."""
    agent = babbled_agent(config.setup, config.seed, progress_bar=progress_bar)
    fitted = agent.refit()["rows"]
    env = agent.env.unwrapped
    judge = PushingEnv(camera_size=config.setup.camera_size)
    specs = goals(config, env.workspace_bearing, np.asarray(env.layout.shoulder[:2]))
    episodes: list[dict[str, Any]] = []
    traces: dict[str, list[np.ndarray]] = {c: [] for c in CONDITIONS}
    paths: dict[str, list[np.ndarray]] = {c: [] for c in CONDITIONS}
    for k, spec in enumerate(specs):
        row: dict[str, Any] = {
            "target": k,
            "box_start": list(spec["box"]),
            "goal": spec["goal"].tolist(),
            "initial_err_cm": 100 * float(np.linalg.norm(spec["goal"] - np.asarray(spec["box"][:2]))),
        }
        for c in CONDITIONS:
            row[c], path = _episode(agent, judge, spec, c, config.episode_steps)
            paths[c].append(path)
            traces[c].append(np.linalg.norm(path - spec["goal"], axis=1))
        log.info(
            "C2 target %d: %s",
            k,
            ", ".join(f"{c} {row[c]['final_err_cm']:.2f} cm" for c in CONDITIONS),
        )
        episodes.append(row)
    env.close()
    judge.close()
    planned = [r for e in episodes for r in e["inferred"].pop("planned_rows")]
    regimes: dict[str, Any] = {"rows": 0}
    if planned:
        rows = regime_rows(
            agent.model,
            agent.history,
            np.asarray(planned),
            "planned",
            source="perceived",
            num_samples=config.num_samples,
            seed=config.seed,
        )
        regimes = summarize(rows)
    return episodes, traces, paths, specs, fitted, regimes


def _metrics(episodes: list[dict[str, Any]], pushes: np.ndarray, fitted: int) -> dict[str, Any]:
    inside = np.abs(pushes[:, 4:] - pushes[:, :2]) <= Z90 * pushes[:, 2:4]
    metrics: dict[str, Any] = {}
    for c in CONDITIONS:
        errors = [e[c]["final_err_cm"] for e in episodes]
        s = summary(errors)
        metrics[c] = {
            "final_err_cm_median": s["median"],
            "final_err_cm_mean": s["mean"],
            "final_err_cm_p25": s["p25"],
            "final_err_cm_p75": s["p75"],
            "within_2cm": float(np.mean(np.array(errors) <= TARGET_ERR_CM)),
        }
    inferred = [e["inferred"] for e in episodes]
    for key in ("model_err_cm", "model_expected_err_cm", "belief_err_cm"):
        metrics[f"{key}_median"] = summary([r[key] for r in inferred if r[key] is not None])["median"]
    metrics["inferred"]["model_err_cm_median"] = metrics["model_err_cm_median"]
    metrics["initial_err_cm_median"] = summary([e["initial_err_cm"] for e in episodes])["median"]
    med = {c: metrics[c]["final_err_cm_median"] for c in CONDITIONS}
    metrics["random_over_inferred"] = ratio(med["random"], med["inferred"])
    metrics["prediction_factor"] = _factor(med["inferred"], metrics["model_expected_err_cm_median"])
    metrics["scripted_over_inferred"] = ratio(med["scripted"], med["inferred"])
    metrics["inferred_modes"] = dict(sum((Counter(r["modes"]) for r in inferred), Counter()))
    metrics["pushes"] = {
        "n": len(pushes),
        "predicted_cm": (100 * pushes[:, :2]).tolist(),
        "sd_cm": (100 * pushes[:, 2:4]).tolist(),
        "realized_cm": (100 * pushes[:, 4:]).tolist(),
    }
    metrics["push_interval_coverage"] = float(inside.mean()) if len(pushes) else None
    metrics["episodes"] = episodes
    metrics["info"] = {"fitted_rows": fitted}
    return metrics


def _factor(realized: float | None, predicted: float | None) -> float | None:
    """``max(r, 1 / r)`` of ``r = realized / predicted`` (1: equal), None without two positive values."""
    r = ratio(realized, predicted)
    return None if r is None or r <= 0 else float(max(r, 1 / r))


def _moved_cm(paths: list[np.ndarray]) -> float:
    """The largest displacement of the box from its start over the episodes' ``paths`` (T + 1, 2), cm."""
    return max((100 * float(np.max(np.linalg.norm(p - p[0], axis=1))) for p in paths if len(p)), default=0.0)


def _targets(metrics: dict[str, Any]) -> list[Target]:
    """The targets; a ratio of two conditions' distances counts only if both moved the box."""

    def moved(a: str, b: str) -> Precondition:
        return Precondition(
            metrics[a]["max_box_displacement_cm"] > MOVED_CM
            and metrics[b]["max_box_displacement_cm"] > MOVED_CM,
            f"the box moved > {MOVED_CM:g} cm in an episode of {a} and of {b}",
        )

    return [
        Target(
            "inferred_final_err_cm",
            metrics["inferred"]["final_err_cm_median"],
            TARGET_ERR_CM,
            "<=",
            "median over goals of the true box centre's final distance from the goal, inferred actions, cm",
        ),
        Target(
            "inferred_below_scripted",
            metrics["scripted_over_inferred"],
            1.0,
            ">",
            "median final distance of the scripted pusher / of the agent (> 1: the agent is closer)",
            moved("inferred", "scripted"),
        ),
        Target(
            "prediction_factor",
            metrics["prediction_factor"],
            TARGET_PREDICTION_FACTOR,
            "<=",
            "median realized final distance of the agent against its model's median prediction of it (the "
            "expected distance at the horizon of its last planned step, over sampled rollouts of every "
            "member): the larger of the two ratios",
            Precondition(
                metrics["inferred"]["max_box_displacement_cm"] > MOVED_CM,
                f"the agent moved the box > {MOVED_CM:g} cm in an episode",
            ),
        ),
        *regime_targets(metrics["regimes"], "planned"),
        Target(
            "random_over_inferred",
            metrics["random_over_inferred"],
            TARGET_VS_RANDOM,
            ">=",
            "median final distance from the goal of random babbling / of inferred actions",
            moved("inferred", "random"),
        ),
    ]


@register("c2", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """C2: pushing the box to goals, inferred actions vs random and scripted, in the simulator."""
    episodes, traces, paths, specs, fitted, regimes = _run_episodes(config, progress_bar)
    pushes = np.array([p for e in episodes for p in e["inferred"].pop("pushes")]).reshape(-1, 6)
    metrics = _metrics(episodes, pushes, fitted)
    metrics["regimes"] = regimes
    metrics["form"] = config.setup.agent.model.displacement
    for c in CONDITIONS:
        metrics[c]["max_box_displacement_cm"] = _moved_cm(paths[c])
    return Report(
        title="C2: pushing the box to targets (realized in the simulator)",
        metrics=metrics,
        tables=_tables(metrics),
        targets=_targets(metrics),
        notes=[
            f"{config.targets} goal{'s' * (config.targets != 1)}, {config.episode_steps} steps each, after {config.setup.babble_steps} "
            f"babbling steps (seed {config.seed}).",
            "Errors are the true box centre's distance from the goal at the end of the episode, cm.",
        ],
        figures={
            "episodes": episodes_figure(traces, TARGET_ERR_CM),
            "paths": paths_figure(paths, specs),
            "pushes": pushes_figure(pushes),
            "calibration": calibration_figure(
                {metrics["form"]: regimes}, REGIMES, "C2: reliability of the planned steps' displacement"
            ),
        },
    )


def _tables(m: dict[str, Any]) -> list[Table]:
    controllers = [
        [
            c,
            m[c]["final_err_cm_median"],
            m[c]["final_err_cm_p25"],
            m[c]["final_err_cm_p75"],
            m[c]["final_err_cm_mean"],
            m[c]["within_2cm"],
        ]
        for c in CONDITIONS
    ]
    agent = [
        ["start-to-goal distance, median [cm]", m["initial_err_cm_median"]],
        [
            "model-internal predicted error of the last plan (members' mean, no noise), median [cm]",
            m["model_err_cm_median"],
        ],
        [
            "model's expected error of the last plan (sampled rollouts), median [cm]",
            m["model_expected_err_cm_median"],
        ],
        ["final belief (posterior mean) to goal, median [cm]", m["belief_err_cm_median"]],
        ["random / inferred", m["random_over_inferred"]],
        ["scripted / inferred", m["scripted_over_inferred"]],
        ["pushes inside the planner's own 90 % Normal (step sd), per component", m["push_interval_coverage"]],
    ]
    agent += [[f"agent decisions: {mode}", n] for mode, n in sorted(m["inferred_modes"].items())]
    episodes = [
        [e["target"], e["initial_err_cm"], *[e[c]["final_err_cm"] for c in CONDITIONS]] for e in m["episodes"]
    ]
    return [
        Table(
            "Final distance of the box from the goal [cm]",
            ["controller", "median", "25th pct", "75th pct", "mean", "share within 2 cm"],
            controllers,
            caption="The thesis has no number for this.",
        ),
        Table("The agent's own view", ["quantity", "value"], agent),
        Table("Episodes [cm]", ["goal", "start", *CONDITIONS], episodes),
        regime_table({m["form"]: m["regimes"]}, REGIMES),
    ]
