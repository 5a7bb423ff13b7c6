"""``pal bench planner``: the cost of one Pusher-v5 MPC step at horizon 25, and iCEM's population.

The agent's world model of Pusher-v5 (the ``pusher`` experiment's model config) is fitted on
``babble_steps`` random-torque steps. From ``states`` seeded resets, each population size P of
``populations`` plans one MPC step with the ``pusher`` experiment's planner settings
(:data:`pal.experiments.closed_loop.pusher.PLAN`: horizon 25, PETS's L1 cost, iCEM, the mean over
the members' TS particles) and is timed on ``threads`` torch threads (process CPU seconds and
wall clock; median over states and repeats, after one warm-up). Figures:

* ``step_cpu_seconds``: the CPU time of one MPC step at the chosen population (``PLAN``'s),
  target <= 0.5 s on one thread;
* ``loss_ratio``: per population, the planner's loss (the expected summed cost of its plan,
  mean over states) over that of a reference search of ``reference`` candidates and
  ``reference_iterations`` iterations (PETS's CEM size), measured in the same run: how much
  of the reference's quality a population keeps (1: all of it);
* ``stacked_speedup``: the seconds of one rollout of P candidates through the K members
  member by member, over the same rollout with the members stacked in one batched pass
  (:mod:`models.stacked`); both give the same first step (``stacked_max_abs_diff``, over the
  rollouts in which no discrete site flips at its threshold by rounding: ``stacked_discrete_flipped``);
* ``driven_speedup``: the seconds of the stacked rollout with every site in the step loop over
  those with the body rolled over the horizon first (:mod:`models.driven`); the values agree to
  ``driven_max_abs_diff``;
* ``lockstep_speedup``: the CPU seconds per unit of ``lockstep`` units planned one by one over
  those of one batched search of all of them (:func:`pal.agent.plan.plan_batch`).

The model is fitted on random torques only, so its plans are not good pushes; the figures are
the planner's cost and its quality relative to a larger search on the same model.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, replace
from typing import Any

import gymnasium
import numpy as np
import torch

from models.stacked import stacked_members
from pal.agent import Agent, AgentConfig, ModelConfig, PlanConfig, pusher_spec
from pal.agent.plan import PlanRequest, plan, plan_batch
from pal.checks import check_int
from pal.experiments.closed_loop.pusher import PLAN, PUSH_MODEL
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import measure_interleaved, ratio, torch_threads

__all__ = ["TARGET_STEP_SECONDS", "Config", "run"]

log = logging.getLogger(__name__)

#: Target of ``step_cpu_seconds`` (one MPC step, horizon 25, one thread).
TARGET_STEP_SECONDS = 0.5


@dataclass(frozen=True)
class Config:
    """Benchmark sizes.

    Attributes:
        seed: seed of the babbling, the fit, the resets and the searches.
        babble_steps: random-torque steps the model is fitted on.
        model: the world model and its fit (the ``pusher`` experiment's, fewer epochs).
        plan: the planner (``plan.action.sampling.population`` is the chosen population).
        populations: the population sizes P timed besides the chosen one.
        reference: population of the reference search; reference_iterations: its iterations.
        states: start states (seeded resets) each population plans from.
        repeats: timed repeats per state (after one warm-up).
        threads: torch threads during the run (one core: 1).
        lockstep: G, the units of the lockstep timing: G seeded resets planned one by one and in
            one batched search (:func:`pal.agent.plan.plan_batch`, as evaluation goals in lockstep).
    """

    seed: int = 0
    babble_steps: int = 400
    model: ModelConfig = replace(PUSH_MODEL, schedule=replace(PUSH_MODEL.schedule, epochs=30))
    plan: PlanConfig = PLAN
    populations: tuple[int, ...] = (50, 100, 200, 300)
    reference: int = 500
    reference_iterations: int = 5
    states: int = 3
    repeats: int = 2
    threads: int = 1
    lockstep: int = 20

    def __post_init__(self) -> None:
        for key in (
            "babble_steps",
            "reference",
            "reference_iterations",
            "states",
            "repeats",
            "threads",
            "lockstep",
        ):
            check_int(key, getattr(self, key))
        object.__setattr__(self, "populations", tuple(check_int("populations", p) for p in self.populations))


def _sized(config: PlanConfig, population: int, iterations: int | None = None) -> PlanConfig:
    """``config`` with population P, 10 % elites (at least 2) and optionally other iterations."""
    s = config.action.sampling
    elites = min(max(population // 10, 2), population)
    sampling = replace(
        s,
        population=population,
        elites=elites,
        refine_elites=min(s.refine_elites, elites),
        iterations=iterations or s.iterations,
    )
    return replace(config, action=replace(config.action, sampling=sampling))


def _fitted(config: Config) -> tuple[Agent, list[tuple[dict[str, np.ndarray], dict[str, np.ndarray]]]]:
    """The agent fitted on random torques, and ``states`` (belief, goal) pairs from seeded resets."""
    cfg = AgentConfig(model=config.model, plan=config.plan, reset_every=None, servo=False)
    agent = Agent(gymnasium.make("Pusher-v5"), pusher_spec(), cfg, seed=config.seed)
    agent.run(config.babble_steps, "babble")
    agent.refit()
    starts = []
    for k in range(config.states):
        agent.reset(seed=config.seed + 100 + k)
        starts.append((agent.belief(), {"object": agent.percept.goals["object"]}))
    return agent, starts


def _time_plans(agent: Agent, starts: list, config: PlanConfig, repeats: int, seed: int) -> dict[str, float]:
    """Median CPU and wall seconds of one MPC step, and the mean planner loss, over the starts."""
    belief, goal = starts[0]
    plan(agent.model, belief, goal, config, seed=seed)  # warm-up
    cpu, wall, losses = [], [], []
    for k, (belief, goal) in enumerate(starts):
        for r in range(repeats):
            c0, w0 = time.process_time(), time.perf_counter()
            p = plan(agent.model, belief, goal, config, seed=seed + 10 * k + r)
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
            losses.append(p.loss)
    return {"cpu": float(np.median(cpu)), "wall": float(np.median(wall)), "loss": float(np.mean(losses))}


def _rollouts(agent: Agent, starts: list, population: int, horizon: int, seed: int) -> dict[str, Any]:
    """One rollout of P random candidates through the members: member by member against stacked."""
    model = agent.model
    belief, _ = starts[0]
    dtype = model.dtype
    initial = {
        k: torch.as_tensor(np.asarray(v)[None], dtype=dtype).expand(population, -1) for k, v in belief.items()
    }
    low, high = model.bounds("act")
    g = torch.Generator().manual_seed(seed)
    act = low + (high - low) * torch.rand(population, horizon, low.shape[0], generator=g, dtype=dtype)

    def loop() -> dict[str, torch.Tensor]:
        return model.rollout(initial, {"act": act}, members=True)

    def stacked(driven: bool = True) -> dict[str, torch.Tensor]:
        with stacked_members(model):
            return model.rollout(initial, {"act": act}, members=True, driven=driven)

    timings = measure_interleaved(
        {"loop": loop, "stacked": stacked, "step_loop": lambda: stacked(False)},
        repeats=3,
        warmup=1,
        no_grad=True,
    )
    first = {k: v[:, :, :1] for k, v in timings["loop"].result.items()}
    stacked_first = {k: v[:, :, :1] for k, v in timings["stacked"].result.items()}
    driven_diff = max(
        float((v - timings["step_loop"].result[k]).abs().max()) for k, v in timings["stacked"].result.items()
    )
    return {
        "loop": timings["loop"].median,
        "stacked": timings["stacked"].median,
        "step_loop": timings["step_loop"].median,
        "driven_max_abs_diff": driven_diff,
        **_agreement(model, first, stacked_first),
    }


def _agreement(model: Any, a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> dict[str, float]:
    """How two rollouts ``(K, P, H, dim)`` of the same candidates agree.

    The bench compares their first step: a model fitted on random torques can be chaotic over
    the horizon and part trajectories by rounding.

    A discrete site (e.g. a contact switch) thresholds a probability, so a rounding difference
    at its threshold flips it and the rest of that rollout legitimately parts: the continuous
    sites are compared on the rollouts whose discrete sites agree at every step.
    ``max_abs_diff``: over those; ``discrete_flipped``: the share of (member, candidate) rollouts
    in which some discrete site differs.
    """
    discrete = [k for k in a if k in model.discrete]
    same = torch.ones(a[next(iter(a))].shape[:2], dtype=torch.bool)
    for k in discrete:
        same &= (a[k] == b[k]).flatten(2).all(-1)
    diffs = [float((a[k] - b[k])[same].abs().max()) for k in a if k not in discrete and bool(same.any())]
    return {
        "max_abs_diff": max(diffs, default=float("inf")),
        "discrete_flipped": float(1.0 - same.float().mean()),
    }


@register(
    "planner",
    kind="bench",
    config=Config,
    quick=Config(
        babble_steps=200,
        populations=(50, 100),
        reference=300,
        reference_iterations=4,
        states=2,
        repeats=1,
        lockstep=8,
    ),
    tiny=Config(
        babble_steps=30,
        model=replace(
            PUSH_MODEL,
            members=2,
            hidden=(8,),
            arm_hidden=(8,),
            schedule=replace(PUSH_MODEL.schedule, epochs=2, patience=None),
        ),
        plan=_sized(replace(PLAN, action=replace(PLAN.action, horizon=3)), 8, iterations=2),
        populations=(4,),
        reference=12,
        reference_iterations=2,
        states=1,
        repeats=1,
        lockstep=3,
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """One Pusher-v5 MPC step: CPU seconds at horizon 25 and the loss of each population size."""
    chosen = config.plan.action.sampling.population
    horizon = config.plan.action.horizon
    with torch_threads(config.threads):
        agent, starts = _fitted(config)
        reference = _time_plans(
            agent, starts, _sized(config.plan, config.reference, config.reference_iterations), 1, config.seed
        )
        sizes = sorted({*config.populations, chosen})
        rows = {}
        for p in sizes:
            cfg = config.plan if p == chosen else _sized(config.plan, p)
            rows[p] = _time_plans(agent, starts, cfg, config.repeats, config.seed)
            log.info("planner P=%d: %.3f s CPU, %.3f s wall, loss %.4f", p, *rows[p].values())
        rollout = _rollouts(agent, starts, chosen, horizon, config.seed)
        rollout["lockstep"] = _lockstep(agent, config)
    return _report(config, rows, reference, rollout)


def _lockstep(agent: Agent, config: Config) -> dict[str, float]:
    """CPU seconds per unit of G single plans and of one batched search over the same G units."""
    requests = []
    for k in range(config.lockstep):
        agent.reset(seed=config.seed + 200 + k)
        requests.append(
            PlanRequest(agent.belief(), {"object": agent.percept.goals["object"]}, config.seed + k)
        )
    c0 = time.process_time()
    for r in requests:
        plan_batch(agent.model, [r], config.plan)
    single = (time.process_time() - c0) / len(requests)
    c0 = time.process_time()
    plan_batch(agent.model, requests, config.plan)
    batched = (time.process_time() - c0) / len(requests)
    log.info(
        "planner lockstep G=%d: %.3f s per unit alone, %.3f s in one batch", len(requests), single, batched
    )
    return {"units": len(requests), "single": single, "batched": batched}


def _tables(
    config: Config,
    rows: dict[int, dict[str, float]],
    reference: dict[str, float],
    rollout: dict,
    loss_ratio: dict[int, float | None],
) -> list[Table]:
    """The step-time table over the populations, and the rollout table."""
    chosen = config.plan.action.sampling.population
    horizon = config.plan.action.horizon
    ref_loss = reference["loss"]
    s = config.plan.action.sampling
    return [
        Table(
            f"One MPC step at horizon {horizon}, {config.threads} thread(s)",
            ("population", "CPU s / step", "wall s / step", "planner loss", "loss / reference loss"),
            [(p, r["cpu"], r["wall"], r["loss"], loss_ratio[p]) for p, r in rows.items()]
            + [
                (
                    f"reference {config.reference} x {config.reference_iterations}",
                    reference["cpu"],
                    reference["wall"],
                    ref_loss,
                    1.0,
                )
            ],
            caption=f"The chosen population is {chosen} ({s.elites} elites, {s.iterations} iterations, decay "
            f"{s.population_decay}, kept elites {s.keep_elites}, noise exponent {s.noise_beta}).",
        ),
        Table(
            f"One rollout of {chosen} candidates x {horizon} steps through the members",
            ("path", "seconds"),
            [
                ("member by member", rollout["loop"]),
                ("stacked (one batched pass)", rollout["stacked"]),
                ("stacked, the body in the step loop (driven=False)", rollout["step_loop"]),
            ],
            caption="The body given by its MJCF is rolled over the horizon before the step loop "
            "(models.driven) except in the last row.",
        ),
        Table(
            f"{rollout['lockstep']['units']} units planned one by one and in one batched search (lockstep)",
            ("path", "CPU s per unit"),
            [("one by one", rollout["lockstep"]["single"]), ("one batch", rollout["lockstep"]["batched"])],
        ),
    ]


def _report(
    config: Config, rows: dict[int, dict[str, float]], reference: dict[str, float], rollout: dict
) -> Report:
    """The report of :func:`run` from its measurements."""
    chosen = config.plan.action.sampling.population
    horizon = config.plan.action.horizon
    ref_loss = reference["loss"]
    loss_ratio = {p: ratio(r["loss"], ref_loss) for p, r in rows.items()}
    speedup = ratio(rollout["loop"], rollout["stacked"])
    step = rows[chosen]
    s = config.plan.action.sampling
    return Report(
        title="Pusher-v5 MPC step: cost at horizon 25 and quality against the population",
        metrics={
            "step_cpu_seconds": step["cpu"],
            "step_wall_seconds": step["wall"],
            "chosen_population": chosen,
            "horizon": horizon,
            "iterations": s.iterations,
            "elites": s.elites,
            "members": config.model.members,
            "populations": {str(p): r for p, r in rows.items()},
            "loss_ratio": {str(p): v for p, v in loss_ratio.items()},
            "reference": {
                **reference,
                "population": config.reference,
                "iterations": config.reference_iterations,
            },
            "stacked_speedup": speedup,
            "rollout_seconds": {k: rollout[k] for k in ("loop", "stacked", "step_loop")},
            "stacked_max_abs_diff": rollout["max_abs_diff"],
            "driven_speedup": ratio(rollout["step_loop"], rollout["stacked"]),
            "driven_max_abs_diff": rollout["driven_max_abs_diff"],
            "lockstep": rollout["lockstep"],
            "lockstep_speedup": ratio(rollout["lockstep"]["single"], rollout["lockstep"]["batched"]),
            "stacked_discrete_flipped": rollout["discrete_flipped"],
            "threads": config.threads,
            "cpu_count": os.cpu_count(),
            "load_average_1min": os.getloadavg()[0],
        },
        tables=_tables(config, rows, reference, rollout, loss_ratio),
        targets=_targets(config, step["cpu"], rollout),
        notes=[
            f"Model fitted on {config.babble_steps} random-torque steps ({config.model.members} members); "
            f"{config.states} start states x {config.repeats} repeats per population after one warm-up; "
            f"{os.cpu_count()} cores, 1-min load average {os.getloadavg()[0]:.2f} at the end of the run.",
            "CPU seconds are the process's (time.process_time); wall seconds grow with the load of other processes.",
        ],
    )


def _targets(config: Config, step_cpu: float, rollout: dict) -> list[Target]:
    """The bench's targets: the step time, and the speedups with their sameness preconditions."""
    chosen = config.plan.action.sampling.population
    horizon = config.plan.action.horizon
    speedup = ratio(rollout["loop"], rollout["stacked"])
    return [
        Target(
            "step_cpu_seconds",
            step_cpu,
            TARGET_STEP_SECONDS,
            "<=",
            f"process CPU seconds of one MPC step at horizon {horizon}, population {chosen}, "
            f"{config.threads} torch thread(s)",
            Precondition(horizon == 25 and config.threads == 1, "horizon 25 on one thread"),
        ),
        Target(
            "stacked_speedup",
            speedup,
            1.0,
            ">=",
            "member-by-member rollout seconds / stacked rollout seconds (same values)",
            Precondition(
                rollout["max_abs_diff"] < 1e-4 and rollout["discrete_flipped"] <= 0.01,
                "the stacked rollout equals the member-by-member one (continuous sites within 1e-4 "
                "where no discrete site flips at its threshold, flips in at most 1 % of the rollouts)",
            ),
        ),
        Target(
            "driven_speedup",
            ratio(rollout["step_loop"], rollout["stacked"]),
            1.0,
            ">=",
            "stacked rollout seconds with the body in the step loop / with the body rolled first",
            Precondition(
                rollout["driven_max_abs_diff"] < 1e-6, "both rollouts give the same values (within 1e-6)"
            ),
        ),
        Target(
            "lockstep_speedup",
            ratio(rollout["lockstep"]["single"], rollout["lockstep"]["batched"]),
            1.0,
            ">=",
            "CPU seconds per unit planned alone / in one batched search of all units",
            Precondition(rollout["lockstep"]["units"] > 1, "more than one unit"),
        ),
    ]
