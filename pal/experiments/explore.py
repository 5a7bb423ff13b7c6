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

``pal experiment explore --json`` prints ``steps_to_full_occupancy`` and
``entropy_at_budget``, each with ``curiosity`` and ``random``: the median over seeds of
the exploration steps until every bin was visited (None when the median run never got
there) and the mean over seeds of the entropy after ``budget`` steps.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from inference import CuriositySampler, fit
from pal.experiments.timing import markdown_table
from pal.experiments.wm_data import BodyChoice, JointData
from pal.experiments.wm_setup import build_model, infer_actions
from pal.sim.babbling import BabbleConfig, BabblingSource, make_source

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from models import WorldModel

__all__ = ["CONDITIONS", "Config", "Result", "coverage_curve", "run"]

log = logging.getLogger(__name__)

CONDITIONS = ("curiosity", "random")


@dataclass(frozen=True)
class Config(BodyChoice):
    """Exploration protocol.

    Attributes:
        seeds: one run of both conditions per seed.
        initial: uniform babbling steps before exploring (shared by both conditions).
        budget: exploration steps per condition.
        refit_every: refit period of the world model, steps.
        epochs, batch_size, lr: :func:`inference.fit` schedule of each refit (MSE).
        graph: graph variant of the world model.
        bins, alpha, sigma_fraction: curiosity density (Eq. 5.8-5.9) and coverage bins.
        action_steps, action_lr, action_starts: Alg. 4.2 (projected Adam, clipped to X_a)
            from ``action_starts`` random points of X_a, keeping the best under the model. A
            fixed start would make an agent whose model sees no effect of the action (a flat
            prediction, e.g. after an initial set spent at a joint limit) repeat one action
            forever; random starts leave its action random where the model is flat.
        q_range: ``(low, high)`` support of the bins, rad; default the joint's range.
    """

    seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    initial: int = 20
    budget: int = 300
    refit_every: int = 25
    epochs: int = 200
    batch_size: int = 256
    lr: float = 0.01
    graph: str = "state"
    bins: int = 20
    alpha: float = 0.5
    sigma_fraction: float = 0.1
    action_steps: int = 100
    action_lr: float = 0.05
    action_starts: int = 3
    q_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))
        if not self.seeds:
            raise ValueError("seeds is empty; give at least one seed")
        for key in ("initial", "budget", "refit_every", "epochs", "batch_size", "action_steps"):
            value = getattr(self, key)
            if (
                isinstance(value, bool)
                or not isinstance(value, int)
                or value < (2 if key == "initial" else 1)
            ):
                raise ValueError(f"{key} must be an int >= {2 if key == 'initial' else 1}, got {value!r}")
        if self.graph not in ("thesis", "state"):
            raise ValueError(f"graph {self.graph!r} unknown; expected 'thesis' or 'state'")
        if self.q_range is not None:
            lo, hi = (float(v) for v in self.q_range)
            if not lo < hi:
                raise ValueError(f"q_range must be (low, high) with low < high, got {self.q_range!r}")
            object.__setattr__(self, "q_range", (lo, hi))

    @classmethod
    def quick(cls) -> Config:
        return cls(seeds=(0, 1), initial=10, budget=40, refit_every=20, epochs=100, action_steps=50)


@dataclass(frozen=True)
class Result:
    """Coverage of both conditions.

    Attributes:
        steps_to_full: condition -> per seed, exploration steps until all bins were
            visited (None: not within the budget).
        entropy_at_budget: condition -> per seed, normalised entropy after the budget.
        occupancy, entropy: condition -> ``(n_seeds, budget + 1)`` curves (step 0: the
            initial set only).
        visited: condition -> all visited angles of all seeds, rad (for the histogram).
        q_range: support of the bins, rad.
        info: joint, actuator, seconds per condition.
    """

    steps_to_full: dict[str, list[int | None]]
    entropy_at_budget: dict[str, list[float]]
    occupancy: dict[str, np.ndarray]
    entropy: dict[str, np.ndarray]
    visited: dict[str, np.ndarray]
    q_range: tuple[float, float]
    info: dict[str, Any]
    config: Config = field(default_factory=Config)

    def median_steps(self, cond: str) -> float | None:
        """Median over seeds of the steps to full occupancy; None if that run never got there."""
        steps = [np.inf if s is None else s for s in self.steps_to_full[cond]]
        med = float(np.median(steps))
        return med if np.isfinite(med) else None

    def to_dict(self) -> dict[str, Any]:
        return {
            "steps_to_full_occupancy": {c: self.median_steps(c) for c in CONDITIONS},
            "entropy_at_budget": {c: float(np.mean(self.entropy_at_budget[c])) for c in CONDITIONS},
        }

    def target_met(self) -> bool:
        """Curiosity reaches all bins (median run) in fewer steps than random babbling."""
        cur, rnd = self.median_steps("curiosity"), self.median_steps("random")
        return cur is not None and (rnd is None or cur < rnd)

    def to_markdown(self) -> str:
        c, d = self.config, self.to_dict()
        rows = []
        for cond in CONDITIONS:
            reached = [s for s in self.steps_to_full[cond] if s is not None]
            rows.append(
                [
                    cond,
                    d["steps_to_full_occupancy"][cond],
                    f"{len(reached)}/{len(c.seeds)}",
                    ", ".join("never" if s is None else str(s) for s in self.steps_to_full[cond]),
                    d["entropy_at_budget"][cond],
                    float(self.occupancy[cond][:, -1].mean()),
                ]
            )
        header = [
            "condition",
            "median steps to 20/20 bins" if c.bins == 20 else f"median steps to {c.bins}/{c.bins} bins",
            "seeds reaching all bins",
            "steps per seed",
            "entropy at budget (mean)",
            "occupancy at budget (mean)",
        ]
        return "\n".join(
            [
                "## Online exploration: curiosity loop vs random babbling",
                "",
                f"Joint `{self.info['joint']}` (actuator `{self.info['actuator']}`, {self.info['n_actuators']} "
                f"actuator(s)), {len(c.seeds)} seeds, {c.initial} initial random steps, budget {c.budget} steps, "
                f"`{c.graph}` graph refitted every {c.refit_every} steps, {c.bins} bins over "
                f"[{self.q_range[0]:.3f}, {self.q_range[1]:.3f}] rad, alpha {c.alpha}, Alg. 4.2 with "
                f"{c.action_steps} Adam steps.",
                "",
                markdown_table(header, rows),
                "",
                f"Target: all bins reached in fewer steps than random babbling: "
                f"{'met' if self.target_met() else 'NOT met'}.",
                "",
            ]
        )

    def figures(self) -> dict[str, Figure]:
        return {"coverage": _figure(self)}


def coverage_curve(
    values: np.ndarray, n_initial: int, q_range: tuple[float, float], bins: int
) -> tuple[np.ndarray, np.ndarray]:
    """Occupancy and normalised entropy of ``values[: n_initial + k]`` for k = 0 .. len - n_initial.

    Args:
        values: ``(n,)`` visited angles in visiting order, rad (outside values count in the edge bins).
        n_initial: values visited before exploring.

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
    return make_source(
        BabbleConfig(
            body=config.source, actuators=config.actuator, steps=total, seed=seed, reset_every=total + 1
        )
    )


def _refit(
    config: Config, joint: JointData, data: dict[str, list[float]], q_range: tuple[float, float], seed: int
) -> WorldModel:
    model = build_model(joint, config.graph, q_range, seed)
    cols = {k: np.asarray(v, np.float32)[:, None] for k, v in data.items()}
    fit(model, cols, loss="mse", epochs=config.epochs, batch_size=config.batch_size, lr=config.lr, seed=seed)
    return model


def _curiosity_run(
    config: Config, joint: JointData, seed: int, q_range: tuple[float, float], progress_bar: bool
) -> np.ndarray:
    """Visited angles (initial set, then ``budget`` curiosity-driven steps), rad."""
    source = _source(config, seed)
    block = source.run(config.initial)
    act, qp, dq, q = joint.names
    j, a_idx = joint.joint_index, joint.actuator_index
    data = {
        act: list(block.ctrl[:, a_idx]),
        qp: list(block.q_prev[:, j]),
        dq: list(block.q[:, j] - block.q_prev[:, j]),
        q: list(block.q[:, j]),
    }
    lo, hi = q_range
    sampler = CuriositySampler(
        lo, hi, bins=config.bins, alpha=config.alpha, sigma=config.sigma_fraction * (hi - lo)
    )
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
            np.array([q_now]),
            target,
            config.action_steps,
            config.action_lr,
            config.action_starts,
            rng=start_rng,
        )
        ctrl = source.policy.sample(1)[0].astype(np.float64)
        ctrl[a_idx] = action[0]
        env.step(ctrl)
        q_new = float(env.data.qpos[qidx])
        for name, value in ((act, action[0]), (qp, q_now), (dq, q_new - q_now), (q, q_new)):
            data[name].append(value)
        sampler.partial_fit([q_new])
        if (k + 1) % config.refit_every == 0 and k + 1 < config.budget:
            model = _refit(config, joint, data, q_range, seed)
    return np.asarray(data[q])


def _random_run(config: Config, joint: JointData, seed: int) -> np.ndarray:
    source = _source(config, seed)
    block = source.run(config.initial + config.budget)
    return block.q[:, joint.joint_index]


def run(config: Config, progress_bar: bool = False) -> Result:
    """Run both conditions for every seed and compare their coverage of q."""
    probe = _source(config, config.seeds[0])
    joint = JointData.from_env(probe.env, config.joint)
    q_range = config.q_range or probe.env.joint_ranges[joint.joint]
    if q_range is None:
        raise ValueError(f"joint {joint.joint!r} is unlimited; give the bins' support as q_range=(low, high)")
    steps: dict[str, list[int | None]] = {c: [] for c in CONDITIONS}
    ent_final: dict[str, list[float]] = {c: [] for c in CONDITIONS}
    occ_curves: dict[str, list[np.ndarray]] = {c: [] for c in CONDITIONS}
    ent_curves: dict[str, list[np.ndarray]] = {c: [] for c in CONDITIONS}
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
            occ, ent = coverage_curve(values, config.initial, q_range, config.bins)
            full = np.flatnonzero(occ >= 1.0)
            steps[cond].append(int(full[0]) if full.size else None)
            ent_final[cond].append(float(ent[-1]))
            occ_curves[cond].append(occ)
            ent_curves[cond].append(ent)
            visited[cond].append(values)
        log.info("seed %d: steps to full occupancy %s", seed, {c: steps[c][-1] for c in CONDITIONS})
    info = {
        "joint": joint.joint,
        "actuator": joint.actuator,
        "n_actuators": len(probe.env.actuator_names),
        "seconds": seconds,
        "config": asdict(config),
    }
    return Result(
        steps,
        ent_final,
        {c: np.stack(v) for c, v in occ_curves.items()},
        {c: np.stack(v) for c, v in ent_curves.items()},
        {c: np.concatenate(v) for c, v in visited.items()},
        (float(q_range[0]), float(q_range[1])),
        info,
        config,
    )


def _figure(result: Result) -> Figure:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    for cond, color in zip(CONDITIONS, ("C3", "0.45"), strict=True):
        for ax, curves in zip(axes[:2], (result.occupancy[cond], result.entropy[cond]), strict=True):
            x = np.arange(curves.shape[1])
            ax.plot(x, curves.mean(0), color=color, label=f"{cond} (mean)")
            ax.fill_between(x, curves.min(0), curves.max(0), color=color, alpha=0.2, lw=0)
    axes[0].set(xlabel="exploration step", ylabel="occupancy", title="bins visited (min-max over seeds)")
    axes[1].set(xlabel="exploration step", ylabel="normalised entropy", title="entropy of visited q")
    lo, hi = result.q_range
    edges = np.linspace(lo, hi, result.config.bins + 1)
    for cond, color in zip(CONDITIONS, ("C3", "0.45"), strict=True):
        axes[2].hist(np.clip(result.visited[cond], lo, hi), bins=edges, alpha=0.5, color=color, label=cond)
    axes[2].set(xlabel="q [rad]", ylabel="visits (all seeds)", title="visited angles at budget")
    for ax in axes:
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
