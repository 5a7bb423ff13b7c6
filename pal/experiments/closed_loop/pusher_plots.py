"""Figures of the ``pusher`` experiment: learning curves, object paths, predicted against realized distances."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from pal.experiments.closed_loop.pusher_runs import Episode

__all__ = ["curve_figure", "paths_figure", "prediction_figure"]

_COLOURS = {"pal": "C0", "baseline": "C1", "random": "C3"}


def curve_figure(steps: Sequence[int], curves: Mapping[str, np.ndarray], random: float | None) -> Figure:
    """Final x-y distance of each training episode against environment steps: mean ± sd over seeds (rows)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 3.5))
    x = np.asarray(steps)
    for name, values in curves.items():
        v = np.asarray(values, dtype=np.float64).reshape(-1, len(x))
        mean, sd = v.mean(0), v.std(0)
        ax.plot(
            x,
            mean,
            color=_COLOURS[name],
            marker=".",
            label="PETS-style baseline" if name == "baseline" else name,
        )
        ax.fill_between(x, mean - sd, mean + sd, color=_COLOURS[name], alpha=0.2)
    if random is not None:
        ax.axhline(random, color=_COLOURS["random"], ls="--", lw=1, label="random (median)")
    ax.set(
        xlabel="environment steps", ylabel="final object-goal distance, m", title="Pusher-v5 learning curve"
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def paths_figure(episodes: Mapping[str, Episode]) -> Figure:
    """The object's x-y path of one evaluation episode per controller, and the goal."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.4, 4.0))
    for name, e in episodes.items():
        p = np.asarray(e.path)
        ax.plot(p[:, 0], p[:, 1], color=_COLOURS[name], marker=".", ms=3, lw=1, label=name)
        ax.plot(p[0, 0], p[0, 1], color=_COLOURS[name], marker="o", ls="none")
    goal = next(iter(episodes.values())).goal
    ax.plot(goal[0], goal[1], color="k", marker="*", ms=12, ls="none", label="goal")
    ax.set(xlabel="x, m", ylabel="y, m", title="object path (first evaluation goal)", aspect="equal")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def prediction_figure(episodes: Mapping[str, Sequence[Episode]]) -> Figure:
    """The planner's predicted final distance against the realized one (the diagonal: calibrated)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.2, 3.8))
    top = 0.0
    for name, eps in episodes.items():
        pairs = np.array([(e.predicted_final, e.final_planar) for e in eps if e.predicted_final is not None])
        if pairs.size:
            ax.scatter(pairs[:, 1], pairs[:, 0], s=12, color=_COLOURS[name], label=name)
            top = max(top, float(pairs.max()))
    ax.plot([0, top or 1.0], [0, top or 1.0], color="k", lw=1, ls=":")
    ax.set(
        xlabel="realized final distance, m",
        ylabel="predicted at planning time, m",
        title="planning-time prediction",
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
