"""``pal bench action``: :func:`inference.infer_action` against the same algorithms in bare torch.

The model is ``finger_graph("thesis")`` (act -> dq -> q <- q_prev) with the default MLP
mechanisms (2 x 32 tanh, seeded), fitted by :func:`inference.fit` on a finger-like plant
with joint limits, the case where gradient-only action inference stalls:

    dq = GAIN (act - ACT_REST) + 0.01 e_1,    q = clip(q_prev + dq, FINGER_Q_RANGE) + 0.01 e_2

For ``targets`` units with given ``q_prev`` and a target ``q`` (the plant's outcome of a
random action, so every target is reachable), each method minimises

    L(a) = sum_units 0.5 (Phi_q(q_prev, a) - q_target)^2

within the action bounds. Two comparisons, each against the loop a user writes by hand on
``model.predict(..., grad=True)`` with the world-model parameters frozen:

1. gradient only (Alg. 4.2): ``infer_action`` (through the Pyro program) against bare
   projected Adam, ``num_steps`` iterations from the midpoint;
2. the sampling planner: ``infer_action(..., sampling=...)`` (iCEM over the action box, then
   Adam on the best elite) against the same iCEM + Adam in bare torch, with the same
   population and its decay, elites and kept elites, iterations, momentum, steps and random draws.

Figures: seconds per call (median of ``repeats``), ratios to the bare-torch versions (> 1:
infer_action is slower), the largest action difference to them, and the share of targets
each method reaches within ``tolerance`` rad under the model (model-internal). Targets:
the planner takes <= 1 s for 128 targets on one core and <= 1.5x the bare CEM + Adam.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from dataclasses import dataclass

import torch
from torch import Tensor
from tqdm.auto import tqdm

from inference import ActionOptions, FitSchedule, SamplingConfig, fit, infer_action
from models.presets import FINGER_ACTION_RANGE, FINGER_Q_RANGE, finger_graph
from models.world import WorldModel
from pal.checks import check_float, check_int
from pal.experiments.world_model.setup import FitConfig
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import Timing, measure_interleaved, ratio, torch_threads

__all__ = ["Config", "bare_adam", "bare_cem_adam", "finger_model", "run"]

log = logging.getLogger(__name__)

ACTION, STATE, DQ, TARGET = "act.finger", "q_prev.finger", "dq.finger", "q.finger"
#: Plant of the fitted model: dq = GAIN (act - ACT_REST), rad per unit command.
GAIN, ACT_REST = 3.0, -0.1
METHODS = ("infer_action", "bare Adam", "planner", "bare CEM + Adam")


@dataclass(frozen=True)
class Config:
    """Sizes (thesis B2: 200 steps, lr 0.05, midpoint start), the sampling stage and repetitions.

    Attributes:
        seed: seeds the plant data, the world-model weights and fit, the units and the sampling.
        targets: number of (state, target) units optimised at once.
        num_steps: Adam iterations (gradient only, and the planner's refinement).
        lr: Adam learning rate.
        sampling: the planner's CEM sizes (its ``refine_steps`` is left None: ``num_steps``).
        rows: plant transitions the model is fitted on.
        fit: the fit schedule.
        repeats: timed calls of each method (the median is reported), after one untimed warm-up.
        threads: torch threads while it runs; None leaves the setting alone.
        tolerance: a target is reached when |Phi_q - target| < tolerance, rad.
    """

    seed: int = 0
    targets: int = 128
    num_steps: int = 200
    lr: float = 0.05
    sampling: SamplingConfig = SamplingConfig(population=128, elites=16, iterations=3, alpha=0.1)
    rows: int = 4096
    fit: FitConfig = FitConfig(schedule=FitSchedule(epochs=60, batch_size=512))
    repeats: int = 5
    threads: int | None = 1
    tolerance: float = 0.05

    def __post_init__(self) -> None:
        check_int("targets", self.targets)
        check_int("num_steps", self.num_steps)
        check_float("lr", self.lr, 0.0, open_low=True)
        check_int("rows", self.rows, minimum=2)
        check_float("tolerance", self.tolerance, 0.0, open_low=True)
        check_int("repeats", self.repeats)
        if self.sampling.refine_steps is not None:
            raise ValueError(
                f"sampling.refine_steps is {self.sampling.refine_steps}; leave it None, the benchmark "
                "refines for `num_steps` steps on both sides"
            )


def _plant(q_prev: Tensor, action: Tensor, gen: torch.Generator | None = None) -> tuple[Tensor, Tensor]:
    """``(dq, q)`` of the finger-like plant (module docstring), with noise when ``gen`` is given."""
    dq = GAIN * (action - ACT_REST)
    if gen is not None:
        dq = dq + 0.01 * torch.randn(dq.shape, generator=gen)
    q = torch.clamp(q_prev + dq, *FINGER_Q_RANGE)
    if gen is not None:
        q = q + 0.01 * torch.randn(q.shape, generator=gen)
    return dq, q


def _uniform(n: int, bounds: tuple[float, float], gen: torch.Generator) -> Tensor:
    low, high = bounds
    return low + (high - low) * torch.rand(n, 1, generator=gen)


def finger_model(config: Config) -> WorldModel:
    """The thesis Fig. 5.5 world model (weights seeded) fitted on ``config.rows`` plant transitions."""
    gen = torch.Generator().manual_seed(config.seed)
    q_prev, action = (
        _uniform(config.rows, FINGER_Q_RANGE, gen),
        _uniform(config.rows, FINGER_ACTION_RANGE, gen),
    )
    dq, q = _plant(q_prev, action, gen)
    model = WorldModel(finger_graph("thesis"), seed=config.seed, hidden=config.fit.hidden)
    data = {ACTION: action, STATE: q_prev, DQ: dq, TARGET: q}
    fit(model, data, schedule=config.fit.schedule, seed=config.seed)
    return model


@contextlib.contextmanager
def _frozen(model: WorldModel) -> Iterator[None]:
    """Parameters without grad for the block, as a user freezes a model to plan through it."""
    params = list(model.parameters())
    before = [p.requires_grad for p in params]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p, r in zip(params, before, strict=True):
            p.requires_grad_(r)


def _loss(model: WorldModel, q_prev: Tensor, action: Tensor, target: Tensor) -> Tensor:
    """Per-unit 0.5 (Phi_q - target)^2 through ``model.predict``; rows of ``action`` tile the units."""
    reps = action.shape[0] // q_prev.shape[0]
    pred = model.predict({ACTION: action, STATE: q_prev.repeat(reps, 1)}, grad=True)
    return (0.5 * (pred[TARGET] - target.repeat(reps, 1)) ** 2).sum(-1)


def bare_adam(
    model: WorldModel, q_prev: Tensor, target: Tensor, start: Tensor, steps: int, lr: float
) -> Tensor:
    """Projected Adam on ``(M, 1)`` actions from ``start`` (M a multiple of N); returns them."""
    low, high = model.bounds(ACTION)
    action = start.clone().requires_grad_(True)
    optim = torch.optim.Adam([action], lr=lr)
    with _frozen(model):
        for _ in range(steps):
            optim.zero_grad()
            _loss(model, q_prev, action, target).sum().backward()
            optim.step()
            with torch.no_grad():
                action.copy_(torch.clamp(action, low, high))
    return action.detach()


def bare_cem_adam(
    model: WorldModel, q_prev: Tensor, target: Tensor, cfg: SamplingConfig, steps: int, lr: float, seed: int
) -> Tensor:
    """The sampling stage over the action box, then Adam on the best elite.

    iCEM at horizon 1: the midpoint a member of each population, the population decays, a share
    of the elites is kept, and the best seen are returned.
    """
    n = q_prev.shape[0]
    low, high = model.bounds(ACTION)
    gen = torch.Generator().manual_seed(seed)
    mean = ((low + high) / 2).expand(n, 1).clone()
    std = (cfg.init_std * (high - low)).expand(n, 1).clone()
    kept, kept_loss = torch.empty(0, n, 1), torch.empty(0, n)
    best, best_loss = torch.empty(0, n, 1), torch.empty(0, n)
    with torch.no_grad():
        for p in cfg.sizes():
            cand = mean + std * torch.randn(p, n, 1, generator=gen)  # horizon 1: white noise
            cand[0] = mean
            cand = torch.clamp(cand, low, high)
            loss = _loss(model, q_prev, cand.reshape(-1, 1), target).reshape(p, n)
            pool, pool_loss = torch.cat([cand, kept]), torch.cat([loss, kept_loss])
            elite_loss, idx = torch.topk(pool_loss, cfg.elites, dim=0, largest=False)
            elites = pool.gather(0, idx[..., None])
            kept, kept_loss = elites[: cfg.kept], elite_loss[: cfg.kept]
            pool, pool_loss = torch.cat([best, cand]), torch.cat([best_loss, loss])
            best_loss, idx = torch.topk(pool_loss, cfg.elites, dim=0, largest=False)
            best = pool.gather(0, idx[..., None])
            mean = cfg.alpha * mean + (1 - cfg.alpha) * elites.mean(0)
            std = cfg.alpha * std + (1 - cfg.alpha) * elites.std(0, unbiased=False)
    elites, elite_loss = best, best_loss
    refined = bare_adam(model, q_prev, target, elites[0], steps, lr)
    with torch.no_grad():
        better = _loss(model, q_prev, refined, target) <= elite_loss[0]
    return torch.where(better[:, None], refined, elites[0])


def _reached(model: WorldModel, q_prev: Tensor, action: Tensor, target: Tensor, tolerance: float) -> float:
    """Share of units whose predicted q lies within ``tolerance`` of the target."""
    with torch.no_grad():
        err = (model.predict({ACTION: action, STATE: q_prev})[TARGET] - target).abs()
    return float((err < tolerance).float().mean())


def _reachable(
    model: WorldModel, q_prev: Tensor, target: Tensor, tolerance: float, points: int = 1001
) -> float:
    """The ceiling of :func:`_reached`: the best of ``points`` evenly spaced actions per unit."""
    grid = torch.linspace(*FINGER_ACTION_RANGE, points)[:, None, None].expand(points, q_prev.shape[0], 1)
    with torch.no_grad():
        err = (_loss(model, q_prev, grid.reshape(-1, 1), target).reshape(points, -1) * 2).sqrt().amin(0)
    return float((err < tolerance).float().mean())


def _time_methods(c: Config, progress_bar: bool) -> tuple[WorldModel, Tensor, Tensor, dict[str, Timing]]:
    """Fit the finger model, draw the targets, time the four methods: (model, q_prev, target, timings)."""
    with torch_threads(c.threads):
        model = finger_model(c)
        gen = torch.Generator().manual_seed(c.seed + 1)
        q_prev = _uniform(c.targets, FINGER_Q_RANGE, gen)
        target = _plant(q_prev, _uniform(c.targets, FINGER_ACTION_RANGE, gen))[1]
        mid = torch.full((c.targets, 1), sum(FINGER_ACTION_RANGE) / 2)
        log.info("timing action inference: %d targets x %d steps", c.targets, c.num_steps)
        with tqdm(total=1, desc="bench action", disable=not progress_bar, leave=False) as bar:
            timings = measure_interleaved(
                {
                    METHODS[0]: lambda: infer_action(
                        model,
                        {STATE: q_prev},
                        {TARGET: target},
                        num_steps=c.num_steps,
                        options=ActionOptions(lr=c.lr),
                        seed=c.seed,
                    ).actions[ACTION],
                    METHODS[1]: lambda: bare_adam(model, q_prev, target, mid, c.num_steps, c.lr),
                    METHODS[2]: lambda: infer_action(
                        model,
                        {STATE: q_prev},
                        {TARGET: target},
                        num_steps=c.num_steps,
                        options=ActionOptions(lr=c.lr, sampling=c.sampling),
                        seed=c.seed,
                    ).actions[ACTION],
                    METHODS[3]: lambda: bare_cem_adam(
                        model, q_prev, target, c.sampling, c.num_steps, c.lr, c.seed
                    ),
                },
                repeats=c.repeats,
            )
            bar.update()
    return model, q_prev, target, timings


def _targets(
    sec: dict[str, float], diff: dict[str, float], ratios: dict[str, float | None], sizes: str
) -> list[Target]:
    return [
        Target("seconds", sec[METHODS[0]], 1.0, "<=", f"gradient-only seconds per call, {sizes}"),
        Target("max_action_diff", diff["gradient"], 1e-4, "<=", "largest |action difference| to bare Adam"),
        Target("planner_seconds", sec[METHODS[2]], 1.0, "<=", f"sampling planner seconds per call, {sizes}"),
        Target(
            "planner_ratio",
            ratios["planner"],
            1.5,
            "<=",
            "planner seconds / bare-torch CEM + Adam seconds",
            Precondition.nonzero(sec[METHODS[3]], "the bare-torch CEM + Adam seconds"),
        ),
        Target(
            "planner_max_action_diff",
            diff["planner"],
            1e-4,
            "<=",
            "largest |action difference| to bare CEM + Adam",
        ),
    ]


@register(
    "action",
    kind="bench",
    config=Config,
    quick=Config(
        targets=32,
        num_steps=50,
        rows=1024,
        fit=FitConfig(schedule=FitSchedule(epochs=20, batch_size=256)),
        repeats=1,
    ),
    tiny=Config(
        targets=4,
        num_steps=5,
        sampling=SamplingConfig(population=8, elites=2, iterations=2),
        rows=64,
        fit=FitConfig(schedule=FitSchedule(epochs=1, batch_size=64)),
        repeats=1,
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Action inference: infer_action, gradient only and with CEM, against the same loops in bare torch."""
    c = config
    model, q_prev, target, timings = _time_methods(c, progress_bar)
    sec = {k: t.median for k, t in timings.items()}
    reached = {k: _reached(model, q_prev, t.result, target, c.tolerance) for k, t in timings.items()}
    reachable = _reachable(model, q_prev, target, c.tolerance)
    diff = {
        "gradient": float((timings[METHODS[0]].result - timings[METHODS[1]].result).abs().max()),
        "planner": float((timings[METHODS[2]].result - timings[METHODS[3]].result).abs().max()),
    }
    for what, d in diff.items():
        if not d <= 1e-4:
            log.warning(
                "%s: infer_action and the bare loop found different actions: max |diff| = %.3g", what, d
            )
    s = c.sampling
    ratios = {
        "gradient": ratio(sec[METHODS[0]], sec[METHODS[1]]),
        "planner": ratio(sec[METHODS[2]], sec[METHODS[3]]),
    }
    baseline_of = {METHODS[0]: "gradient", METHODS[2]: "planner"}
    rows = [(k, sec[k], ratios.get(baseline_of.get(k, ""), None), reached[k]) for k in METHODS]
    sizes = (
        f"{c.targets} targets, {c.num_steps} Adam steps, population {s.population}, {s.iterations} iterations"
    )
    return Report(
        title="Action inference benchmark",
        metrics={
            "seconds": sec[METHODS[0]],
            "baseline_seconds": sec[METHODS[1]],
            "ratio": ratios["gradient"],
            "max_action_diff": diff["gradient"],
            "planner": {
                "seconds": sec[METHODS[2]],
                "baseline_seconds": sec[METHODS[3]],
                "ratio": ratios["planner"],
                "max_action_diff": diff["planner"],
            },
            "reached": reached,
            "reachable": reachable,
        },
        tables=[
            Table(
                "infer_action against bare torch loops",
                ("method", "seconds per call", "ratio to bare torch", f"reached within {c.tolerance:g} rad"),
                rows,
                caption=(
                    "ratio > 1: infer_action is slower; reached: share of targets, under the model "
                    f"(the best of 1001 evenly spaced actions reaches {reachable:.4g})."
                ),
            )
        ],
        targets=_targets(sec, diff, ratios, sizes),
        notes=[
            f"finger_graph('thesis'), MLP 2x32 tanh fitted on {c.rows} transitions of a plant with joint limits "
            f"(dq = {GAIN:g} (act - ({ACT_REST:g})), q clipped to the finger's range); {sizes}, {s.elites} "
            f"elites, momentum {s.alpha:g}, lr {c.lr:g}, midpoint start; torch threads: {c.threads}."
        ],
    )
