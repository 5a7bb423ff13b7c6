"""Figures of the ``pusher`` experiment: learning curves, fingertip and object paths, predicted against realized distances."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from pal.experiments.closed_loop.pusher_runs import Episode

__all__ = ["curve_figure", "paths_figure", "prediction_figure"]

_COLOURS = {"pal": "C0", "baseline": "C1", "simulator": "C2", "random": "C3"}
_LABELS = {
    "pal": "pal",
    "baseline": "PETS-style baseline",
    "simulator": "planner on the true simulator",
    "random": "random torques",
}


def curve_figure(steps: Sequence[int], at: Mapping[str, Mapping[str, Any]]) -> Figure:
    """Final x-y distance against environment steps per controller: mean over seeds x goals, band ± sd over seeds.

    ``at``: checkpoint (str) -> controller -> scores with ``final_planar.mean`` and ``seed_sd``
    (:func:`pal.experiments.closed_loop.pusher_metrics.block`).
    """
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 3.5))
    x = np.asarray(steps, dtype=np.float64)
    controllers = next(iter(at.values())).keys() if at else ()
    for name in controllers:
        mean = np.array(
            [np.nan if (m := at[str(s)][name]["final_planar"]["mean"]) is None else m for s in steps]
        )
        sd = np.array([at[str(s)][name]["seed_sd"] or 0.0 for s in steps])
        ax.plot(
            x,
            mean,
            color=_COLOURS[name],
            marker="o",
            ms=4,
            ls="--" if name in ("random", "simulator") else "-",
            label=_LABELS[name],
        )
        ax.fill_between(x, mean - sd, mean + sd, color=_COLOURS[name], alpha=0.2)
    ax.set(
        xlabel="environment steps", ylabel="final object-goal distance, m", title="Pusher-v5 learning curve"
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def paths_figure(episodes: Mapping[str, Sequence[Episode]], title: str = "") -> Figure:
    """Fingertip (dotted) and object (solid) x-y paths per controller, one panel per goal (at most 3), and the goal.

    ``title``: the figure's title (e.g. which seed and checkpoint the episodes come from).
    """
    import matplotlib.pyplot as plt

    n = max((len(v) for v in episodes.values()), default=0)
    fig, axes = plt.subplots(1, max(n, 1), figsize=(3.6 * max(n, 1), 3.6), squeeze=False)
    for g, ax in enumerate(axes[0]):
        goal = None
        for name, eps in episodes.items():
            if g >= len(eps):
                continue
            e = eps[g]
            p, t = np.asarray(e.path), np.asarray(e.tip)
            ax.plot(p[:, 0], p[:, 1], color=_COLOURS[name], lw=1.5, label=f"{name}: object")
            ax.plot(t[:, 0], t[:, 1], color=_COLOURS[name], lw=0.8, ls=":", label=f"{name}: tip")
            ax.plot(p[0, 0], p[0, 1], color=_COLOURS[name], marker="o", ls="none")
            goal = e.goal
        if goal:
            ax.plot(goal[0], goal[1], color="k", marker="*", ms=12, ls="none", label="goal")
        ax.set(xlabel="x, m", ylabel="y, m", title=f"goal {g + 1}", aspect="equal")
    axes[0][0].legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=10)
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
