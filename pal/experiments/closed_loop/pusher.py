"""Experiment ``pusher``: learning curves on Gymnasium's Pusher-v5 for the agent, a PETS-style baseline and random torques.

Per seed (``seed``, ``seed + 1``, ...), state-based (the spec :func:`pal.agent.pusher_spec`):

1. **aggregation** (:mod:`pal.agent.aggregate`): each learner runs ``aggregation.rounds``
   episodes of ``aggregation.episode_steps`` steps; the first ``aggregation.random_rounds`` are
   uniform random torques (1: PETS's protocol; more: the babbling-heavy one), every later one
   is goal-directed MPC with the current model, its torques perturbed by the episode's colored
   noise when ``aggregation.exploration.sd`` > 0 (the same noise for both learners,
   :class:`pal.agent.aggregate.Exploration`), and followed by perturbed continuations from its
   saved simulator states when ``aggregation.branching.per_state`` > 0
   (:class:`pal.agent.aggregate.Branching`, a simulator privilege; their steps count as
   environment steps); after each episode its transitions join the learner's data and the model
   is refitted from its current weights. The agent plans with its
   world model built from the spec (joints, fingertip and object as causal variables,
   heteroscedastic ensembles, the sampling planner over ``plan.action.horizon`` steps); the
   baseline with its ensemble over the full observation and CEM (:mod:`pal.baselines.pets`,
   :mod:`pal.baselines.pets_aggregate`). Both use the same planner settings, step cost
   (:mod:`pal.experiments.closed_loop.pusher_runs`), episode seeds and environment steps;
2. **checkpoints**: when a learner's environment steps reach each of ``aggregation.checkpoints``,
   its current model runs ``eval_goals`` evaluation episodes (seeded resets that differ from the
   training ones, no data added); random torques and the planner's ceiling run the same goals
   once. The ceiling (``simulator``, :mod:`pal.baselines.simulator_mpc`) is the learners'
   planner with the same settings and cost, predicting with the true simulator from the exact
   state: a learner's gap to it is its model's, its own gap to the goal the planner's.

3. **ranking**: at each checkpoint, how each learner's model orders candidate plans by cost
   at states of the ceiling's episodes, against the true order (Spearman correlation and the
   regret of its pick, :mod:`pal.experiments.closed_loop.pusher_ranking`): a model error that
   counts for planning, measurable before the learner moves anything.

Scores (:mod:`pal.experiments.closed_loop.pusher_metrics`) per checkpoint and controller: the
object-goal distance at the end of an episode in the table plane (x-y, m; Gymnasium's 3-D
``reward_dist`` is also given: its goal marker sits 4.8 cm lower than the object's centre),
mean ± sd over seeds × goals and the median, the share within ``success`` m, the share of
episodes in which the object moved more than :data:`pusher_runs.MOVED`, the smallest
fingertip-object distance of the episode (does the arm reach the object at all?), and the
planner's planning-time prediction of the final distance next to the realized one. Every
ratio of two controllers counts only when both moved the object.
"""

from __future__ import annotations

import logging
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

from inference import ActionOptions, CalibrationOptions
from pal.agent import CorrectionConfig, ModelConfig, PlanConfig
from pal.agent.aggregate import AggregationConfig, Branching, Exploration
from pal.agent.config import MODEL_SCHEDULE, PLAN_SAMPLING
from pal.baselines.pets import BaselineConfig
from pal.checks import check_float, check_int
from pal.experiments.closed_loop.pusher_metrics import CONTROLLERS, summarise
from pal.experiments.closed_loop.pusher_protocol import one_seed
from pal.experiments.closed_loop.pusher_ranking import RankingConfig
from pal.experiments.closed_loop.pusher_store import PARTS, seed_parts, stored_report
from pal.lab.registry import register
from pal.lab.report import Report
from pal.lab.timing import torch_threads

__all__ = ["AGGREGATION", "CONTROLLERS", "MODEL", "PLAN", "PUSH_MODEL", "Config", "pooled", "run"]

log = logging.getLogger(__name__)

#: Both planners on Pusher-v5: horizon 25 (1.25 s, the fingertip starts 50-77 cm from the object)
#: and PETS's L1 cost per step (Chua et al. 2018; mbrl-lib's ``pets_pusher``) with the object-goal
#: term weighted 10x and the action term 0.1x PETS's, c = 12.5 |obj - goal|_1 + 0.5 |tip - obj|_1
#: + 0.01 |a|^2, minimised by iCEM with the mean over the members' TS particles. PETS's weights
#: (1.25, 0.5, 0.1) are too timid for Gymnasium's 100-step episodes: with a perfect model
#: (``pusher-ceiling``, the true simulator, 20 goals, start median 0.242 m) they end at a median
#: 0.228 m; (1.25, 0.5, 0.01) at 0.138 m; (12.5, 0.5, 0.01) at 0.009 m with 70 % within 5 cm.
#: Population 50 x 3 iterations (decay 1.25, 5 elites, 30 % kept): on the true simulator
#: (``pusher-ceiling``, the same 20 goals, one run each on one machine) it ends at a median
#: 0.0071 m with 65 % within 5 cm, population 100 at 0.0085 m and 70 %, for 0.24 against 0.47 s of
#: CPU per step; 50 x 2 iterations falls to 0.044 m and 50 %. With the learned model the step
#: costs 0.60 against 0.78 s at 100 (``pal bench planner``: its Python overhead per rollout step
#: does not shrink with the population). init_std 0.25 of the torque range as in mbrl-lib's iCEM.
#: A plan every 2 steps (``--set plan.replan_every=2``) halves the planning; on the simulator it
#: ends at 0.019 m with 55 % within 5 cm (0.127 s per step), so it is an option, not the default.
PLAN = PlanConfig(
    action=ActionOptions(
        scale=1.0,
        lr=0.05,
        horizon=25,
        target_at="every",
        risk="mean",
        sampling=replace(PLAN_SAMPLING, population=50, elites=5, iterations=3, init_std=0.25, refine_steps=0),
    ),
    preference="l1",
    goal_weight=12.5,
    effector_weight=0.5,
    action_weight=0.01,
)
#: The agent's model of Pusher-v5. ``position_sigma`` 0.1 mm: the object is state-based (no
#: perception noise) and rests exactly (|dpos| = 0 in every untouched step), while a push moves it
#: at most about 3.4 mm per step, so the moved label of its contact switch (``> 3 position_sigma``,
#: :func:`pal.agent.graph.contact_rule`) fires at 0.3 mm; at the 1 mm default it would need 3 mm and
#: hardly ever fire, leaving the gated on branch without rows.
MODEL = ModelConfig(
    members=5,
    hidden=(64, 64),
    arm_hidden=(128, 128),
    position_sigma=1e-4,
    schedule=replace(MODEL_SCHEDULE, epochs=200),
)
#: The agent's model in the protocol: :data:`MODEL` with the body read from Pusher-v5's MJCF (its
#: kinematics, with the claw's points, and its joint dynamics, as fixed mechanisms) and the object's
#: contact and displacement learned in the push frame (:mod:`pal.agent.graph_frame`), so a push
#: learnt in one direction holds in all. ``--set model.object_frame=world --set
#: model.kinematics=learned --set model.dynamics=learned`` is the world-frame model learned whole.
#: Its on branch's sd is calibrated on the validation rows, not by 5-fold cross-fitting
#: (``MODEL_SCHEDULE``'s): the cross-fit leaves the weights as they are and only rescales the sd,
#: and nothing here reads that sd (the object is sensed, so its estimate is the observation, and
#: the planner scores the members' expected rollouts), so the plans are the same without it; it
#: took 26 % of a learner's CPU time (65-75 s per refit at 5000-6000 rows).
PUSH_MODEL = replace(
    MODEL,
    kinematics="mjcf",
    dynamics="mjcf",
    object_frame="push",
    schedule=replace(MODEL.schedule, calibration=CalibrationOptions(folds=None)),
)
#: 60 episodes of 100 steps, the first random, scored at 1.5k, 3k and 6k steps (15k: ``--set
#: aggregation.rounds=150 --set 'aggregation.checkpoints=[1500,3000,6000,15000]'``; to shrink, set the
#: checkpoints before the rounds, since each setting is checked as it is applied).
AGGREGATION = AggregationConfig(rounds=60, episode_steps=100, random_rounds=1, checkpoints=(1500, 3000, 6000))


@dataclass(frozen=True)
class Config:
    """The ``pusher`` protocol (module docstring).

    Attributes:
        seed: the first run's seed. runs: seeds (mean ± sd over seeds × goals).
        aggregation: rounds, steps per episode (Pusher-v5 truncates at 100), random rounds, checkpoints.
        eval_goals: evaluation episodes per seed and checkpoint.
        lockstep: each learner's evaluation episodes run in lockstep, their MPC plans made in one
            batched search per step (:mod:`pal.agent.lockstep`, :func:`pal.baselines.pets.act_together`;
            the same planner, one generator for the batch's draws); False: one after the other.
        success: an episode succeeds when it ends within this x-y distance, m.
        model: the agent's world model and fit. plan: both planners' settings and step cost.
        correction: the agent's online correction of its MPC rollouts from abducted residuals
            (:mod:`pal.agent.correction`; off by default: the baseline has none).
        baseline: the PETS-style model and its fit (every refit).
        ranking: the probes of the models' rankings of candidate plans
            (:mod:`pal.experiments.closed_loop.pusher_ranking`). threads: torch threads per
            process (one core: 1). workers: seeds run in this many processes at once.
        store: a directory for finished parts of seeds (:mod:`pal.experiments.closed_loop.pusher_store`):
            each part is written there when it finishes and read back, not run again, by a later
            run with the same settings. parts: the parts this run may compute (of ``pal``,
            ``baseline``, ``reference``; none: only read back); the others must be in ``store``,
            or the report lists what is missing.
    """

    seed: int = 0
    runs: int = 3
    aggregation: AggregationConfig = AGGREGATION
    eval_goals: int = 20
    lockstep: bool = True
    success: float = 0.05
    model: ModelConfig = PUSH_MODEL
    plan: PlanConfig = PLAN
    correction: CorrectionConfig = CorrectionConfig()
    baseline: BaselineConfig = BaselineConfig(epochs=20)
    ranking: RankingConfig = RankingConfig()
    threads: int = 1
    workers: int = 1
    store: str | None = None
    parts: tuple[str, ...] = PARTS

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        for name in ("runs", "eval_goals", "threads", "workers"):
            check_int(name, getattr(self, name))
        for name, kind in (
            ("aggregation", AggregationConfig),
            ("ranking", RankingConfig),
            ("correction", CorrectionConfig),
        ):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(
                    f"{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}"
                )
        check_int("aggregation.episode_steps", self.aggregation.episode_steps, maximum=100)
        check_float("success", self.success, 0.0, open_low=True)
        if not isinstance(self.lockstep, bool):
            raise ValueError(f"lockstep must be a bool, got {self.lockstep!r}")
        unknown = [p for p in self.parts if p not in PARTS]
        if unknown or len(set(self.parts)) != len(self.parts):
            raise ValueError(f"parts must be distinct names of {PARTS}, got {list(self.parts)}")
        if set(self.parts) != set(PARTS) and self.store is None:
            raise ValueError(f"parts {list(self.parts)} leave out some of {PARTS}: set store to keep them")

    @property
    def seeds(self) -> tuple[int, ...]:
        """The runs' seeds."""
        return tuple(range(self.seed, self.seed + self.runs))


QUICK = Config(
    runs=1,
    aggregation=AggregationConfig(rounds=3, episode_steps=30, random_rounds=1, checkpoints=(60, 90)),
    eval_goals=2,
    model=replace(PUSH_MODEL, schedule=replace(PUSH_MODEL.schedule, epochs=30)),
    plan=replace(
        PLAN,
        action=replace(
            PLAN.action, sampling=replace(PLAN.action.sampling, population=32, elites=4, iterations=2)
        ),
    ),
    baseline=BaselineConfig(epochs=10),
    ranking=RankingConfig(goals=1, steps=20, every=10, candidates=16),
)
TINY = Config(
    runs=1,
    aggregation=AggregationConfig(
        rounds=2,
        episode_steps=3,
        random_rounds=1,
        checkpoints=(3, 6),
        exploration=Exploration(sd=0.05),
        branching=Branching(every=2, per_state=1, steps=2),
    ),
    eval_goals=1,
    model=replace(
        PUSH_MODEL,
        members=2,
        hidden=(8,),
        arm_hidden=(8,),
        schedule=replace(PUSH_MODEL.schedule, epochs=2, patience=None),
    ),
    plan=replace(
        PLAN,
        action=replace(
            PLAN.action,
            horizon=2,
            sampling=replace(PLAN.action.sampling, population=8, elites=2, iterations=1),
        ),
    ),
    baseline=BaselineConfig(members=2, hidden=(8,), epochs=2),
    ranking=RankingConfig(goals=1, steps=2, every=2, candidates=4),
)


def _seed_run(config: Config, seed: int) -> dict[str, Any]:
    with torch_threads(config.threads):
        if config.store is None:
            return one_seed(config, seed)
        return seed_parts(config, seed)


def pooled(config: Config, seeds: tuple[int, ...]) -> Config:
    """The report over a sweep's seeds (:mod:`pal.lab.sweep_pool`): every seed's parts read back from the store.

    A sweep's runs compute one seed each into the shared store (``--set runs=1 --set
    store=DIR``, e.g. ``--grid 'parts=["pal"],["baseline","reference"]'`` to split a seed's work).

    Raises:
        ValueError: no store, runs other than 1, or seeds that are not consecutive.
    """
    if config.store is None:
        raise ValueError(
            "the pusher's seeds are pooled from its store of finished parts: set --set store=DIR"
        )
    if config.runs != 1:
        raise ValueError(f"each run of a pusher sweep is one seed: set --set runs=1, got runs={config.runs}")
    first = seeds[0]
    if list(seeds) != list(range(first, first + len(seeds))):
        raise ValueError(f"the pooled pusher report needs consecutive seeds, got {list(seeds)}")
    return replace(config, seed=first, runs=len(seeds), parts=())


@register("pusher", config=Config, quick=QUICK, tiny=TINY, pool=pooled)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Pusher-v5 learning curves: the agent, a PETS-style baseline and random torques at equal environment steps."""
    if config.workers > 1 and config.runs > 1:
        with ProcessPoolExecutor(min(config.workers, config.runs)) as pool:
            results = list(pool.map(_seed_run, [config] * config.runs, config.seeds))
    else:
        results = [_seed_run(config, s) for s in config.seeds]
    per_seed = dict(zip(config.seeds, results, strict=True))
    if config.store is None:
        return summarise(config, per_seed)
    return stored_report(config, per_seed, summarise)
