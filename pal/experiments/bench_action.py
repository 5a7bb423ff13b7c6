"""``pal bench action``: :func:`inference.infer_action` against a plain torch loop.

On ``finger_graph("thesis")`` (act -> dq -> q <- q_prev) with a default
:class:`models.WorldModel` (MLP 2 x 32 tanh, seeded), both find, for ``targets`` units
with given ``q_prev`` and a target ``q``, the action minimising

    L(a) = sum_units 0.5 (Phi_q(q_prev, a) - q_target)^2

with Adam (``lr``), ``steps`` iterations, midpoint initialisation and clipping to the
action bounds after every step (Alg. 4.2). The baseline is the loop a user writes by
hand: Adam on the action tensor through ``model.predict(..., grad=True)`` (expected residuals), with the
world-model parameters frozen as infer_action freezes them. Figures: ``seconds`` per
infer_action call, ``baseline_seconds`` per loop, ``ratio`` = seconds / baseline_seconds
(> 1: infer_action is slower). Target: ``seconds`` <= 1 for 128 targets x 200 steps.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import torch
from torch import Tensor
from tqdm.auto import tqdm

from inference.action import infer_action
from models.presets import FINGER_Q_RANGE, finger_graph
from models.world import WorldModel
from pal.checks import check_float, check_int
from pal.experiments.registry import register
from pal.experiments.report import Report, Table, Target
from pal.experiments.timing import measure_interleaved, torch_threads

__all__ = ["Config", "baseline", "finger_model", "run"]

log = logging.getLogger(__name__)

ACTION, STATE, TARGET = "act.finger", "q_prev.finger", "q.finger"


@dataclass(frozen=True)
class Config:
    """Sizes (thesis B2: 200 steps, lr 0.05, midpoint init) and repetitions.

    Attributes:
        seed: seeds the world-model weights, the states and the targets.
        targets: number of (state, target) units optimised at once.
        steps, lr: Adam iterations and learning rate.
        repeats: timed repeats (median reported) after one warm-up of each.
        threads: torch threads during the run (None: leave as is).
    """

    seed: int = 0
    targets: int = 128
    steps: int = 200
    lr: float = 0.05
    repeats: int = 5
    threads: int | None = 1

    def __post_init__(self) -> None:
        check_int("targets", self.targets)
        check_int("steps", self.steps)
        check_float("lr", self.lr, 0.0, open_low=True)
        check_int("repeats", self.repeats)


def finger_model(seed: int) -> WorldModel:
    """A default (untrained) world model of thesis Fig. 5.5, weights seeded by ``seed``."""
    return WorldModel(finger_graph("thesis"), seed=seed)


def baseline(model: WorldModel, q_prev: Tensor, target: Tensor, steps: int, lr: float) -> Tensor:
    """Projected Adam on the action through ``model.predict``; returns ``(N, 1)`` actions."""
    low, high = model.bounds(ACTION)
    action = ((low + high) / 2).expand(q_prev.shape[0], 1).clone().requires_grad_(True)
    optim = torch.optim.Adam([action], lr=lr)
    params = list(model.parameters())
    before = [p.requires_grad for p in params]
    for p in params:
        p.requires_grad_(False)
    try:
        for _ in range(steps):
            optim.zero_grad()
            pred = model.predict({ACTION: action, STATE: q_prev}, grad=True)
            loss = (0.5 * (pred[TARGET] - target) ** 2).sum()
            loss.backward()
            optim.step()
            with torch.no_grad():
                action.copy_(torch.clamp(action, low, high))
    finally:
        for p, r in zip(params, before, strict=True):
            p.requires_grad_(r)
    return action.detach()


@register(
    "action",
    kind="bench",
    config=Config,
    quick=Config(targets=16, steps=20, repeats=1),
    tiny=Config(targets=4, steps=5, repeats=1),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Action inference: infer_action against the same projected Adam loop written in bare torch."""
    with torch_threads(config.threads):
        model = finger_model(config.seed)
        gen = torch.Generator().manual_seed(config.seed)
        low, high = FINGER_Q_RANGE
        q_prev = low + (high - low) * torch.rand(config.targets, 1, generator=gen)
        target = low + (high - low) * torch.rand(config.targets, 1, generator=gen)
        log.info("timing infer_action and the baseline: %d targets x %d steps", config.targets, config.steps)
        with tqdm(total=1, desc="bench action", disable=not progress_bar, leave=False) as bar:
            timings = measure_interleaved(
                {
                    "infer_action": lambda: infer_action(
                        model,
                        {STATE: q_prev},
                        {TARGET: target},
                        steps=config.steps,
                        lr=config.lr,
                        init="midpoint",
                        seed=config.seed,
                    ),
                    "baseline": lambda: baseline(model, q_prev, target, config.steps, config.lr),
                },
                repeats=config.repeats,
            )
            bar.update()
    ours, base = timings["infer_action"], timings["baseline"]
    diff = float((ours.result.actions[ACTION] - base.result).abs().max())
    if not diff <= 1e-4:
        log.warning("infer_action and the baseline found different actions: max |diff| = %.3g", diff)
    c = config
    rows = [
        ("infer_action", ours.median, 1e3 * ours.median / c.steps),
        ("plain torch loop", base.median, 1e3 * base.median / c.steps),
    ]
    return Report(
        title="Action inference benchmark",
        metrics={
            "seconds": ours.median,
            "baseline_seconds": base.median,
            "ratio": ours.median / base.median,
            "max_action_diff": diff,
        },
        tables=[
            Table(
                "infer_action against a bare torch loop",
                ("", "seconds per call", "ms per step"),
                rows,
                caption="ratio > 1: infer_action is slower.",
            )
        ],
        targets=[
            Target(
                "seconds", ours.median, 1.0, "<=", f"seconds per call, {c.targets} targets x {c.steps} steps"
            ),
            Target("max_action_diff", diff, 1e-4, "<=", "largest |action difference| to the bare loop"),
        ],
        notes=[
            f"finger_graph('thesis'), MLP 2x32 tanh, {c.targets} targets x {c.steps} steps, lr {c.lr}, midpoint "
            f"init; torch threads: {c.threads}."
        ],
    )
