"""Online exploration: the curiosity loop that the thesis's B3 lacked (§6, Alg. 4.2 + Eq. 5.8-5.9).

Per seed, both conditions start from the same short random-babbling set (``initial``
uniform steps from the body's rest pose) and then take ``budget`` more steps:

- ``curiosity``: at each step (1) draw a target q* from the curiosity density over the
  angles visited so far, localised at the current angle (Eq. 5.8-5.9); (2) infer the
  analysed actuator's command with Alg. 4.2 through the current world model (the
  ``state`` graph by default); (3) execute it in the simulator for one step (other
  actuators babble uniformly); (4) add the transition and its outcome to the counts;
  (5) refit the model from scratch on all transitions every ``refit_every`` steps.
- ``random``: uniform motor babbling for the same number of steps.

Coverage of q over the steps is the occupancy and normalised entropy of all visited
angles (initial set included) over ``bins`` bins of the joint's range.

Metrics: ``steps_to_full_occupancy`` (median over seeds of the exploration steps until
every bin was visited; None when the median run never got there), ``entropy_at_budget`` and
``occupancy_at_budget`` (means over seeds), each per condition, and per seed
``steps_per_seed`` and ``entropy_per_seed``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from inference import FitSchedule
from models.presets import GRAPH_VARIANTS
from pal.checks import check_choice, check_float, check_int
from pal.experiments.world_model.data import BodyChoice, JointData
from pal.experiments.world_model.setup import (
    ActionConfig,
    CuriosityDensity,
    FitConfig,
    build_model,
    fit_model,
    infer_actions,
)
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target
from pal.sim.babbling import BabblingSource, make_source

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from models import WorldModel

__all__ = ["CONDITIONS", "Config", "coverage_curve", "run"]

log = logging.getLogger(__name__)

CONDITIONS = ("curiosity", "random")


@dataclass(frozen=True)
class Config:
    """Exploration protocol.

    Attributes:
        seed: the first seed; run k uses ``seed + k``.
        runs: one run of both conditions per seed.
        body: the body, the analysed joint and the babbling actuators.
        initial: uniform babbling steps before exploring (shared by both conditions).
        budget: exploration steps per condition.
        refit_every: refit period of the world model, steps.
        fit: :func:`inference.fit` schedule of each refit (MSE).
        graph: graph variant of the world model.
        curiosity: the target density (Eq. 5.8-5.9) and the coverage bins.
        action: Alg. 4.2 (projected Adam, clipped to X_a) from ``action.starts`` random points
            of X_a, keeping the best under the model. A fixed start would make an agent whose
            model sees no effect of the action (a flat prediction, e.g. after an initial set
            spent at a joint limit) repeat one action forever; random starts leave its action
            random where the model is flat.
        q_range: ``(low, high)`` support of the bins, rad; default the joint's range.
    """

    seed: int = 0
    runs: int = 5
    body: BodyChoice = BodyChoice()
    initial: int = 20
    budget: int = 300
    refit_every: int = 25
    fit: FitConfig = FitConfig(schedule=FitSchedule(epochs=200, batch_size=256))
    graph: str = "state"
    curiosity: CuriosityDensity = CuriosityDensity()
    action: ActionConfig = ActionConfig(num_steps=100, starts=3)
    q_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        check_int("runs", self.runs)
        check_int("initial", self.initial, minimum=2)
        check_int("budget", self.budget)
        check_int("refit_every", self.refit_every)
        check_choice("graph", self.graph, GRAPH_VARIANTS)
        if self.q_range is not None:
            lo, hi = (check_float("q_range", v) for v in self.q_range)
            if not lo < hi:
                raise ValueError(f"q_range must be (low, high) with low < high, got {self.q_range!r}")
            object.__setattr__(self, "q_range", (lo, hi))

    @property
    def seeds(self) -> tuple[int, ...]:
        """The seeds of the runs."""
        return tuple(range(self.seed, self.seed + self.runs))


def coverage_curve(
    values: np.ndarray, n_initial: int, q_range: tuple[float, float], bins: int
) -> tuple[np.ndarray, np.ndarray]:
    """Occupancy and normalised entropy of ``values[: n_initial + k]`` for k = 0 .. len - n_initial.

    Args:
        values: ``(n,)`` visited angles in visiting order, rad (outside values count in the edge bins).
        n_initial: values visited before exploring.
        q_range: ``(low, high)`` angle range split into the bins, rad.
        bins: number of equal-width angle bins.

    Returns:
        ``(occupancy, entropy)``, each ``(n - n_initial + 1,)``.
    """
    lo, hi = q_range
    idx = np.clip(((np.asarray(values, np.float64) - lo) / (hi - lo) * bins).astype(int), 0, bins - 1)
    counts = np.cumsum(np.eye(bins, dtype=np.int64)[idx], axis=0)[n_initial - 1 :]
    total = counts.sum(1, keepdims=True)
    p = counts / total
    with np.errstate(divide="ignore", invalid="ignore"):
        ent = -np.where(p > 0, p * np.log(p), 0.0).sum(1) / np.log(bins)
    return (counts > 0).mean(1), ent


def _source(config: Config, seed: int) -> BabblingSource:
    total = config.initial + config.budget
    return make_source(config.body.babble_config(total, seed, reset_every=total + 1))


def _refit(
    config: Config, joint: JointData, data: dict[str, list[float]], q_range: tuple[float, float], seed: int
) -> WorldModel:
    model = build_model(joint, config.graph, q_range, seed, config.fit)
    fit_model(model, {k: np.asarray(v, np.float32)[:, None] for k, v in data.items()}, config.fit, seed)
    return model


def _curiosity_run(
    config: Config, joint: JointData, seed: int, q_range: tuple[float, float], progress_bar: bool
) -> np.ndarray:
    """Visited angles (initial set, then ``budget`` curiosity-driven steps), rad."""
    source = _source(config, seed)
    block = source.run(config.initial)
    act, qp, dq, q = joint.names
    dqp = f"dq_prev.{joint.joint}"
    j, a_idx = joint.joint_index, joint.actuator_index
    moves = list(block.q[:, j] - block.q_prev[:, j])
    data = {
        act: list(block.ctrl[:, a_idx]),
        qp: list(block.q_prev[:, j]),
        dqp: [0.0, *moves[:-1]],  # the body starts at rest
        dq: moves,
        q: list(block.q[:, j]),
    }
    lo, hi = q_range
    sampler = config.curiosity.sampler(lo, hi)
    sampler.fit(np.asarray(data[q]))
    rng, start_rng = np.random.default_rng([seed, 4]), np.random.default_rng([seed, 5])
    model = _refit(config, joint, data, q_range, seed)
    env, qidx = source.env, source.env.qpos_indices[j]
    for k in tqdm(range(config.budget), desc=f"curiosity seed {seed}", disable=not progress_bar, leave=False):
        q_now = float(env.data.qpos[qidx])
        target = sampler.sample(rng, current=[q_now])
        action, _, _ = infer_actions(
            model,
            joint,
            {qp: np.array([q_now]), dqp: np.array([data[dq][-1]])}
            if config.graph == "dynamics"
            else {qp: np.array([q_now])},
            target,
            config.action,
            rng=start_rng,
            seed=seed,
        )
        ctrl = source.policy.sample(1)[0].astype(np.float64)
        ctrl[a_idx] = action[0]
        env.step(ctrl)
        q_new = float(env.data.qpos[qidx])
        step = ((act, action[0]), (qp, q_now), (dqp, data[dq][-1]), (dq, q_new - q_now), (q, q_new))
        for name, value in step:
            data[name].append(value)
        sampler.partial_fit([q_new])
        if (k + 1) % config.refit_every == 0 and k + 1 < config.budget:
            model = _refit(config, joint, data, q_range, seed)
    return np.asarray(data[q])


def _random_run(config: Config, joint: JointData, seed: int) -> np.ndarray:
    source = _source(config, seed)
    block = source.run(config.initial + config.budget)
    return block.q[:, joint.joint_index]


def _median_steps(steps: list[int | None]) -> float | None:
    """Median over seeds of the steps to full occupancy; None if the median run never got there."""
    med = float(np.median([np.inf if v is None else v for v in steps]))
    return med if np.isfinite(med) else None


def _explore(
    config: Config, joint: JointData, q_range: Any, progress_bar: bool
) -> tuple[
    dict[str, list[int | None]], dict[str, list[float]], dict, dict[str, list[np.ndarray]], dict[str, float]
]:
    """Both conditions on every seed: steps to full occupancy, final entropy, curves, visited q, seconds."""
    steps: dict[str, list[int | None]] = {c: [] for c in CONDITIONS}
    ent_final: dict[str, list[float]] = {c: [] for c in CONDITIONS}
    curves: dict[str, dict[str, list[np.ndarray]]] = {c: {"occupancy": [], "entropy": []} for c in CONDITIONS}
    visited: dict[str, list[np.ndarray]] = {c: [] for c in CONDITIONS}
    seconds = dict.fromkeys(CONDITIONS, 0.0)
    for seed in config.seeds:
        for cond in CONDITIONS:
            start = time.perf_counter()
            if cond == "curiosity":
                values = _curiosity_run(config, joint, seed, q_range, progress_bar)
            else:
                values = _random_run(config, joint, seed)
            seconds[cond] += time.perf_counter() - start
            occ, ent = coverage_curve(values, config.initial, q_range, config.curiosity.bins)
            full = np.flatnonzero(occ >= 1.0)
            steps[cond].append(int(full[0]) if full.size else None)
            ent_final[cond].append(float(ent[-1]))
            curves[cond]["occupancy"].append(occ)
            curves[cond]["entropy"].append(ent)
            visited[cond].append(values)
        log.info("seed %d: steps to full occupancy %s", seed, {c: steps[c][-1] for c in CONDITIONS})
    return steps, ent_final, curves, visited, seconds


@register(
    "explore",
    config=Config,
    quick=Config(
        runs=2,
        initial=10,
        budget=40,
        refit_every=20,
        fit=FitConfig(schedule=FitSchedule(epochs=100, batch_size=256)),
        action=ActionConfig(num_steps=50, starts=3),
    ),
    tiny=Config(
        runs=1,
        initial=5,
        budget=6,
        refit_every=3,
        curiosity=CuriosityDensity(bins=5),
        fit=FitConfig(schedule=FitSchedule(epochs=5, batch_size=64)),
        action=ActionConfig(num_steps=5, starts=2),
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Online exploration: steps until the curiosity loop and random babbling have visited every bin of q."""
    probe = _source(config, config.seed)
    joint = JointData.from_env(probe.env, config.body.joint, probe.action_ranges)
    q_range = config.q_range or probe.env.joint_ranges[joint.joint]
    if q_range is None:
        raise ValueError(f"joint {joint.joint!r} is unlimited; give the bins' support as q_range=(low, high)")
    steps, ent_final, curves, visited, seconds = _explore(config, joint, q_range, progress_bar)
    q_range = (float(q_range[0]), float(q_range[1]))
    metrics = {
        "steps_to_full_occupancy": {c: _median_steps(steps[c]) for c in CONDITIONS},
        "entropy_at_budget": {c: float(np.mean(ent_final[c])) for c in CONDITIONS},
        "occupancy_at_budget": {
            c: float(np.mean([o[-1] for o in curves[c]["occupancy"]])) for c in CONDITIONS
        },
        "steps_per_seed": steps,
        "entropy_per_seed": ent_final,
        "info": {
            "joint": joint.joint,
            "actuator": joint.actuator,
            "n_actuators": len(probe.env.actuator_names),
            "q_range": list(q_range),
            "seconds": seconds,
        },
    }
    rows = [
        (
            cond,
            metrics["steps_to_full_occupancy"][cond],
            f"{sum(s is not None for s in steps[cond])}/{config.runs}",
            ", ".join("never" if s is None else str(s) for s in steps[cond]),
            metrics["entropy_at_budget"][cond],
            metrics["occupancy_at_budget"][cond],
        )
        for cond in CONDITIONS
    ]
    cur, rnd = (metrics["steps_to_full_occupancy"][c] for c in CONDITIONS)
    advantage = None if cur is None else (config.budget if rnd is None else rnd) - cur
    b = config.curiosity.bins
    stacked = {c: {k: np.stack(v) for k, v in curves[c].items()} for c in CONDITIONS}
    return Report(
        title="Online exploration: curiosity loop vs random babbling",
        metrics=metrics,
        tables=[
            Table(
                "Coverage of q",
                (
                    "condition",
                    f"median steps to {b}/{b} bins",
                    "seeds reaching all bins",
                    "steps per seed",
                    "entropy at budget (mean)",
                    "occupancy at budget (mean)",
                ),
                rows,
            )
        ],
        targets=[
            Target(
                "steps_saved",
                advantage,
                0.0,
                ">",
                "median steps to all bins, random (budget if never) minus curiosity",
            )
        ],
        notes=[
            f"Joint {joint.joint} (actuator {joint.actuator}, {len(probe.env.actuator_names)} actuator(s)), "
            f"{config.runs} seeds, {config.initial} initial random steps, budget {config.budget} steps, "
            f"{config.graph} graph refitted every {config.refit_every} steps, {b} bins over "
            f"[{q_range[0]:.3f}, {q_range[1]:.3f}] rad, alpha {config.curiosity.alpha}, Alg. 4.2 with "
            f"{config.action.num_steps} Adam steps."
        ],
        figures={
            "coverage": _figure(stacked, {c: np.concatenate(v) for c, v in visited.items()}, q_range, b)
        },
    )


def _figure(
    curves: dict[str, dict[str, np.ndarray]],
    visited: dict[str, np.ndarray],
    q_range: tuple[float, float],
    bins: int,
) -> Figure:
    """Occupancy and entropy curves (mean, min-max over seeds) and the histogram of visited angles."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    for cond, color in zip(CONDITIONS, ("C3", "0.45"), strict=True):
        for ax, key in zip(axes[:2], ("occupancy", "entropy"), strict=True):
            c = curves[cond][key]
            x = np.arange(c.shape[1])
            ax.plot(x, c.mean(0), color=color, label=f"{cond} (mean)")
            ax.fill_between(x, c.min(0), c.max(0), color=color, alpha=0.2, lw=0)
    axes[0].set(xlabel="exploration step", ylabel="occupancy", title="bins visited (min-max over seeds)")
    axes[1].set(xlabel="exploration step", ylabel="normalised entropy", title="entropy of visited q")
    lo, hi = q_range
    edges = np.linspace(lo, hi, bins + 1)
    for cond, color in zip(CONDITIONS, ("C3", "0.45"), strict=True):
        axes[2].hist(np.clip(visited[cond], lo, hi), bins=edges, alpha=0.5, color=color, label=cond)
    axes[2].set(xlabel="q [rad]", ylabel="visits (all seeds)", title="visited angles at budget")
    for ax in axes:
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
