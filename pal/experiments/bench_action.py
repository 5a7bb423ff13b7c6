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
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor
from tqdm.auto import tqdm

from inference.action import infer_action
from models.presets import FINGER_Q_RANGE, finger_graph
from models.world import WorldModel
from pal.experiments.timing import markdown_table, measure_interleaved, torch_threads

__all__ = ["Config", "Result", "baseline", "finger_model", "run"]

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

    @classmethod
    def quick(cls) -> Config:
        return cls(targets=16, steps=20, repeats=1)


@dataclass(frozen=True)
class Result:
    """Seconds per call of infer_action and of the baseline loop."""

    seconds: float
    baseline_seconds: float
    ratio: float
    max_action_diff: float = 0.0
    config: Config = field(default_factory=Config)

    def to_dict(self) -> dict[str, Any]:
        return {"seconds": self.seconds, "baseline_seconds": self.baseline_seconds, "ratio": self.ratio}

    def to_markdown(self) -> str:
        c = self.config
        rows = [
            ["infer_action", self.seconds, 1e3 * self.seconds / c.steps],
            ["plain torch loop", self.baseline_seconds, 1e3 * self.baseline_seconds / c.steps],
        ]
        return (
            "\n".join(
                [
                    "## Action inference benchmark",
                    "",
                    f"finger_graph('thesis'), MLP 2x32 tanh, {c.targets} targets x {c.steps} steps, lr {c.lr}, midpoint "
                    f"init; torch threads: {c.threads}.",
                    "",
                    markdown_table(["", "seconds per call", "ms per step"], rows),
                    "",
                    f"ratio infer_action / baseline: **{self.ratio:.3g}** (> 1: infer_action is slower); "
                    f"target: <= 1 s per call. Max |action difference|: {self.max_action_diff:.2g}.",
                ]
            )
            + "\n"
        )

    def figures(self) -> dict[str, Any]:
        return {}


def finger_model(seed: int) -> WorldModel:
    """A default (untrained) world model of thesis Fig. 5.5, weights seeded by ``seed``."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return WorldModel(finger_graph("thesis"))


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


def run(config: Config, progress_bar: bool = False) -> Result:
    """Time infer_action and the baseline alternately; see the module docstring."""
    if config.targets < 1 or config.steps < 1 or not config.lr > 0:
        raise ValueError(
            f"need targets >= 1, steps >= 1, lr > 0; got {config.targets}, {config.steps}, {config.lr}"
        )
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
    return Result(ours.median, base.median, ours.median / base.median, diff, config)
