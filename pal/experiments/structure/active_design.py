"""Experiment ``active_design``: sample efficiency of active experimental design.

World: the spring finger of :func:`pal.experiments.world_model.spring.spring_finger` (a known SCM in
which dq depends on the action and the previous angle). ``agents`` babbling agents run in
parallel; each transition the agent's angle q becomes its next q_prev, so an agent chooses
its action but not its state. Strategies:

- ``random``: a ~ Uniform(X_a) (motor babbling, §5.2.1);
- ``curiosity``: a target q* ~ p_tar (Eq. 5.8-5.9, 20 bins, alpha 0.5) and the action
  inferred for it on the current model (Alg. 4.2, 50 Adam steps);
- ``active``: of ``choice.candidates`` uniform actions, the one with the largest ensemble
  information about the mechanism of dq (:class:`inference.ensemble.Ensemble`); the
  agents of a round choose in turn with the batch-diversity damping ``choice.spread``.

All three train the same kind of ensemble (``ensemble.members`` MLPs 2 x 16 on the state
graph, bootstrap resamples, warm refits of ``ensemble.schedule.epochs`` epochs after every round).
The mechanism error is the MSE between the ensemble-mean f_dq and the true one on a
40 x 40 grid over X_a x X_q, in rad². Sample efficiency: the transitions a strategy needs
until its mean curve (over seeds) first reaches random babbling's final error, as a share
of the budget. Target: at most 70 % of the budget.

Metrics: ``transitions``, ``mechanism_mse`` (mean curve per strategy), ``final_mse``,
``fraction_to_random_final`` (None: never reached), ``per_seed`` curves, ``seconds``, ``seeds``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from tqdm import tqdm

from inference import ActionOptions, CuriositySampler, FitSchedule, infer_action
from inference.ensemble import Ensemble
from models import WorldModel, finger_graph
from models.presets import FINGER_ACTION_RANGE
from pal.checks import check_choice, check_float, check_int
from pal.experiments.world_model.spring import Q_RANGE, spring_finger
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["STRATEGIES", "ChoiceConfig", "Config", "EnsembleConfig", "run"]

log = logging.getLogger(__name__)

STRATEGIES = ("random", "curiosity", "active")
J = "finger"
ACT, QP, DQ, Q = f"act.{J}", f"q_prev.{J}", f"dq.{J}", f"q.{J}"
#: Largest share of the budget a strategy may need to reach random babbling's final error.
TARGET = 0.7


@dataclass(frozen=True)
class EnsembleConfig:
    """The learner of every strategy: an ensemble of state-graph world models.

    Attributes:
        members: ensemble members (>= 2), MLPs 2 x 16.
        schedule: the warm refit after every round.
    """

    members: int = 4
    schedule: FitSchedule = FitSchedule(epochs=15, batch_size=256)

    def __post_init__(self) -> None:
        check_int("members", self.members, minimum=2)
        if not isinstance(self.schedule, FitSchedule):
            raise ValueError(f"schedule must be a FitSchedule, got {type(self.schedule).__name__}")


@dataclass(frozen=True)
class ChoiceConfig:
    """How the ``active`` strategy picks its actions.

    Attributes:
        candidates: uniform candidate actions per agent and round.
        spread: batch-diversity length in sd of the candidate points (None: plain argmax).
    """

    candidates: int = 32
    spread: float | None = 1.0

    def __post_init__(self) -> None:
        check_int("candidates", self.candidates)
        if self.spread is not None:
            check_float("spread", self.spread, 0.0, open_low=True)


@dataclass(frozen=True)
class Config:
    """Active design against random babbling and curiosity.

    Attributes:
        seed: the first seed; the run uses ``seed, ..., seed + repeats - 1``. The default
            starts at 10 because ``choice.spread`` was tuned on seeds 0 and 1.
        repeats: seeds per strategy (curves are averaged over them).
        budget: transitions per run (a multiple of ``agents`` is used: whole rounds).
        agents: agents babbling in parallel, one transition each per round.
        strategies: ``"random"`` plus some of :data:`STRATEGIES`.
        ensemble: the learner.
        choice: the active strategy's choice.
    """

    seed: int = 10
    repeats: int = 3
    budget: int = 600
    agents: int = 50
    strategies: tuple[str, ...] = STRATEGIES
    ensemble: EnsembleConfig = EnsembleConfig()
    choice: ChoiceConfig = ChoiceConfig()

    def __post_init__(self) -> None:
        check_int("repeats", self.repeats)
        check_int("agents", self.agents)
        check_int("budget", self.budget)
        if self.budget < self.agents:
            raise ValueError(f"budget {self.budget} is smaller than one round of {self.agents} agents")
        strategies = tuple(check_choice("strategy", s, STRATEGIES) for s in self.strategies)
        if "random" not in strategies or len(set(strategies)) != len(strategies):
            raise ValueError(
                f"strategies {list(strategies)} invalid; expected 'random' plus distinct names from {STRATEGIES}"
            )
        object.__setattr__(self, "strategies", strategies)

    @property
    def seeds(self) -> list[int]:
        """The seeds of the run."""
        return [self.seed + k for k in range(self.repeats)]


def _member(seed: int) -> WorldModel:
    return WorldModel(finger_graph("state", J), hidden=(16, 16), seed=seed)


def _grid() -> dict[str, torch.Tensor]:
    a = torch.linspace(*FINGER_ACTION_RANGE, 40)
    q = torch.linspace(*Q_RANGE, 40)
    aa, qq = torch.meshgrid(a, q, indexing="ij")
    return {ACT: aa.reshape(-1, 1), QP: qq.reshape(-1, 1)}


def _run_one(strategy: str, config: Config, seed: int) -> tuple[list[int], list[float]]:
    """Transitions after every round and the mechanism MSE of dq then, rad²."""
    truth = spring_finger()
    gen = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    grid = _grid()
    with torch.no_grad():
        true_dq = truth.predict(grid)[DQ]
    low, high = FINGER_ACTION_RANGE
    b = config.agents
    q_prev = torch.clamp(-1.0 + 0.8 * torch.randn(b, 1, generator=gen), *Q_RANGE)
    ens = Ensemble.create(_member, k=config.ensemble.members, seed=1000 * seed)
    cur = CuriositySampler(Q_RANGE[0], Q_RANGE[1], bins=20, alpha=0.5)
    rows: dict[str, list[torch.Tensor]] = {k: [] for k in (ACT, QP, DQ, Q)}
    xs, errs = [], []
    for r in range(config.budget // b):
        if r == 0 or strategy == "random":
            a = low + (high - low) * torch.rand(b, 1, generator=gen)
        elif strategy == "active":
            cands = low + (high - low) * torch.rand(b, config.choice.candidates, 1, generator=gen)
            a = ens.choose({QP: q_prev}, {ACT: cands}, [DQ], spread=config.choice.spread)[0][ACT]
        else:
            target = torch.as_tensor(cur.sample(rng, q_prev.numpy()[:, 0]), dtype=torch.float32)[:, None]
            a = infer_action(
                ens.members[0],
                {QP: q_prev},
                {Q: target},
                num_steps=50,
                options=ActionOptions(lr=0.05),
                seed=seed,
            ).actions[ACT]
        noise = {DQ: torch.randn(b, 1, generator=gen), Q: torch.randn(b, 1, generator=gen)}
        with torch.no_grad():
            out = truth.predict({ACT: a, QP: q_prev}, noise=noise)
        for k in rows:
            rows[k].append(out[k])
        cur.partial_fit(out[Q].numpy()[:, 0])
        q_prev = torch.clamp(out[Q], *Q_RANGE)
        ens.fit(
            {k: torch.cat(v) for k, v in rows.items()},
            seed=seed + r,
            schedule=config.ensemble.schedule,
        )
        with torch.no_grad():
            errs.append(float((ens.predict(grid)[DQ] - true_dq).pow(2).mean()))
        xs.append((r + 1) * b)
    return xs, errs


def _fraction(xs: list[int], curve: list[float], level: float) -> float | None:
    """Share of the budget at which ``curve`` first reaches ``level`` (None: never)."""
    for x, e in zip(xs, curve, strict=True):
        if e <= level:
            return x / xs[-1]
    return None


@register(
    "active_design",
    config=Config,
    quick=Config(
        repeats=1, budget=200, agents=25, ensemble=EnsembleConfig(3, FitSchedule(epochs=5, batch_size=256))
    ),
    tiny=Config(
        repeats=1, budget=40, agents=20, ensemble=EnsembleConfig(2, FitSchedule(epochs=2, batch_size=256))
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Active design: transitions each strategy needs to reach random babbling's final mechanism error."""
    per_seed: dict[str, list[list[float]]] = {}
    seconds: dict[str, float] = {}
    xs: list[int] = []
    jobs = [(s, seed) for s in config.strategies for seed in config.seeds]
    for strategy, seed in tqdm(jobs, desc="active design", disable=not progress_bar):
        start = time.perf_counter()
        xs, errs = _run_one(strategy, config, seed)
        seconds[strategy] = seconds.get(strategy, 0.0) + time.perf_counter() - start
        per_seed.setdefault(strategy, []).append(errs)
        log.info("%s seed %d: final mechanism MSE %.4g", strategy, seed, errs[-1])
    curves = {s: np.mean(v, 0).tolist() for s, v in per_seed.items()}
    level = curves["random"][-1]
    efficiency = {s: _fraction(xs, c, level) for s, c in curves.items()}
    # never reaching random's final error within the budget: the share is above 1, at
    # least that of one more round
    beyond = (xs[-1] + config.agents) / xs[-1]
    mid = len(xs) // 3
    rows = [(s, curves[s][mid], curves[s][-1], efficiency[s], seconds[s]) for s in curves]
    return Report(
        title="Active experimental design: mechanism error of dq against transitions",
        metrics={
            "transitions": xs,
            "mechanism_mse": curves,
            "final_mse": {s: c[-1] for s, c in curves.items()},
            "fraction_to_random_final": efficiency,
            "per_seed": per_seed,
            "seconds": seconds,
            "seeds": config.seeds,
        },
        tables=[
            Table(
                "Mechanism MSE of dq [rad²] and sample efficiency",
                (
                    "strategy",
                    f"MSE @ {xs[mid]} transitions",
                    f"MSE @ {xs[-1]}",
                    "share to random's final",
                    "seconds",
                ),
                rows,
                "Share: transitions until the mean curve first reaches random babbling's final error / budget "
                "(n/a: not within the budget).",
            )
        ],
        targets=[
            Target(
                f"share_to_random_final.{s}",
                beyond if efficiency[s] is None else efficiency[s],
                TARGET,
                "<=",
                f"transitions {s} needs to reach random babbling's final mechanism error / budget "
                "(above 1: not reached within the budget)",
            )
            for s in config.strategies
            if s != "random"
        ],
        notes=[
            f"Spring finger, {config.agents} agents in parallel, budget {config.budget} transitions, "
            f"seeds {config.seeds}, ensembles of {config.ensemble.members} MLPs refitted "
            f"{config.ensemble.schedule.epochs} epochs after every round.",
        ],
        figures={"curves": _figure(xs, curves)},
    )


def _figure(xs: list[int], curves: dict[str, list[float]]) -> Figure:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.4))
    for s, c in curves.items():
        ax.plot(xs, c, label=s)
    ax.axhline(curves["random"][-1], color="k", ls=":", lw=1, label="random, final")
    ax.set(yscale="log", xlabel="transitions", ylabel="mechanism MSE of dq [rad²]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
