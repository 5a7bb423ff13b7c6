"""Experiment C4: curiosity-driven exploration of the object variables against random babbling.

For each seed, two agents start from the same ``babble_steps`` steps of random babbling (same
seed, so the same actions and the same world), then spend ``budget`` more steps:

- ``curiosity``: the world model is fitted on the warm-up, then every step the agent takes a
  curiosity target for one object (alternating; Eq. 4.34-4.38 on a grid over the table, with
  locality), infers the action (Alg. 4.2) and refits every ``refit_every`` steps; when the model
  predicts no progress towards the target it babbles;
- ``random``: random babbling goes on.

Objects are put back at the same seeded places every ``reset_every`` steps in both runs. Coverage
is the share of cells of a ``bins`` grid over the table region that an object entered during the
budget *by being moved* (true position after a step in which it moved more than ``min_motion``
m; positions where objects were put back do not count), averaged over the objects.

``pal experiment c4 --json``: ``coverage_at_budget`` ``{curiosity, random}`` (mean over seeds),
per-seed values and the coverage curves.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from pal.agent.curiosity import grid_occupancy
from pal.agent.history import History
from pal.experiments.pushing_setup import SetupConfig, babbled_agent
from pal.experiments.timing import markdown_table

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["CONDITIONS", "Config", "Result", "coverage_curve", "run"]

log = logging.getLogger(__name__)

CONDITIONS = ("curiosity", "random")


@dataclass(frozen=True)
class Config(SetupConfig):
    """C4 protocol (module docstring)."""

    babble_steps: int = 400
    budget: int = 200
    seeds: tuple[int, ...] = (0, 1, 2)
    refit_every: int = 50
    checkpoint_every: int = 20
    min_motion: float = 0.005

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (self.budget >= 1 and self.seeds and self.refit_every >= 1 and self.checkpoint_every >= 1):
            raise ValueError(
                f"need budget >= 1, some seeds, refit_every >= 1, checkpoint_every >= 1; got {self}"
            )

    @classmethod
    def quick(cls) -> Config:
        return cls(babble_steps=120, epochs=30, budget=6, seeds=(0,), checkpoint_every=3, refit_every=1000)


@dataclass(frozen=True)
class Result:
    """C4 coverage (fractions of grid cells) per condition and seed."""

    metrics: dict[str, Any]
    info: dict[str, Any]
    config: Config
    curves: dict[str, np.ndarray] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {**self.metrics, "info": self.info}

    def to_markdown(self) -> str:
        m = self.metrics
        rows = [[c, m["coverage_at_budget"][c], *m["per_seed"][c]] for c in CONDITIONS]
        c = self.config
        return (
            "\n".join(
                [
                    "## C4: exploration of the object positions, curiosity vs random babbling",
                    "",
                    f"after {c.babble_steps} warm-up babbling steps, {c.budget} more steps per seed; share of the "
                    f"{self.info['bins'][0]} x {self.info['bins'][1]} table cells that a pushed object entered. The thesis reports occupancy only for "
                    "a finger joint (§5.2.4), not for object variables.",
                    "",
                    markdown_table(["condition", "mean", *[f"seed {s}" for s in c.seeds]], rows),
                    "",
                    f"curiosity / random = {m['curiosity_over_random']:.3g}.",
                ]
            )
            + "\n"
        )

    def figures(self) -> dict[str, Figure]:
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5, 3.4))
        steps = self.curves["steps"]
        for c, colour in zip(CONDITIONS, ("C0", "C3"), strict=True):
            curves = self.curves[c]
            ax.plot(steps, curves.mean(0), color=colour, label=c)
            ax.fill_between(steps, curves.min(0), curves.max(0), color=colour, alpha=0.2)
        ax.set(xlabel="steps after warm-up", ylabel="coverage", title="C4 coverage of pushed positions")
        ax.legend(fontsize=7)
        fig.tight_layout()
        return {"coverage": fig}


def coverage_curve(
    history: History,
    start: int,
    checkpoints: np.ndarray,
    region: Any,
    bins: tuple[int, int],
    min_motion: float,
) -> np.ndarray:
    """Coverage (mean over objects) of moved-object positions in rows [start, start + s) for each s."""
    truth, truth_prev = history.array("truth"), history.array("truth_prev")
    (x0, y0), (x1, y1) = region
    out = []
    for s in checkpoints:
        rows = slice(start, start + int(s))
        values = []
        for k in range(len(history.objects)):
            moved = np.linalg.norm(truth[rows, k] - truth_prev[rows, k], axis=1) > min_motion
            pts = truth[rows, k][moved]
            values.append(grid_occupancy(pts, (x0, y0), (x1, y1), bins) if len(pts) else 0.0)
        out.append(float(np.mean(values)))
    return np.array(out)


def run(config: Config, progress_bar: bool = False) -> Result:
    """Warm-up, then the budget with and without curiosity, for every seed."""
    start = time.perf_counter()
    checkpoints = np.unique(
        np.append(
            np.arange(config.checkpoint_every, config.budget + 1, config.checkpoint_every), config.budget
        )
    )
    curves: dict[str, list[np.ndarray]] = {c: [] for c in CONDITIONS}
    modes: list[dict[str, int]] = []
    region = bins = None
    for seed in config.seeds:
        cfg = replace(config, seed=seed)
        curious = babbled_agent(cfg, progress_bar=progress_bar, refit_every=config.refit_every)
        curious.refit()
        decisions = curious.run(config.budget, "curious", progress_bar=progress_bar)
        modes.append({m: sum(d.mode == m for d in decisions) for m in ("curious", "babble")})
        randomly = babbled_agent(
            replace(cfg, babble_steps=config.babble_steps + config.budget), progress_bar=progress_bar
        )
        region, bins = curious.config.region, curious.config.bins
        for c, agent in (("curiosity", curious), ("random", randomly)):
            curves[c].append(
                coverage_curve(
                    agent.history, config.babble_steps, checkpoints, region, bins, config.min_motion
                )
            )
            agent.env.close()
        log.info(
            "C4 seed %d: curiosity %.3f, random %.3f",
            seed,
            curves["curiosity"][-1][-1],
            curves["random"][-1][-1],
        )
    at_budget = {c: float(np.mean([v[-1] for v in curves[c]])) for c in CONDITIONS}
    metrics = {
        "coverage_at_budget": at_budget,
        "per_seed": {c: [float(v[-1]) for v in curves[c]] for c in CONDITIONS},
        "curiosity_over_random": at_budget["curiosity"] / max(at_budget["random"], 1e-12),
        "curves": {"steps": checkpoints.tolist(), **{c: [v.tolist() for v in curves[c]] for c in CONDITIONS}},
        "curious_decisions": modes,
    }
    info = {"region": region, "bins": bins, "seconds": time.perf_counter() - start, "config": asdict(config)}
    arrays = {"steps": checkpoints, **{c: np.stack(curves[c]) for c in CONDITIONS}}
    return Result(metrics, info, config, arrays)
