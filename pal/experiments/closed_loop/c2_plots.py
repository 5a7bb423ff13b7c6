"""C2's figures: predicted against realized pushes, the box's paths and the distance per step."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["Z90", "episodes_figure", "paths_figure", "pushes_figure"]

#: The standard Normal's 95 % quantile: a 90 % interval is the mean ± Z90 sd.
Z90 = 1.6448536269514722
#: One colour per controller, in the order of the records (inferred, random, scripted).
_COLOURS = ("C0", "C3", "C2")


def pushes_figure(pushes: np.ndarray) -> Figure:
    """Predicted against realized box displacement over each push, per component, with the 90 % intervals.

    ``pushes``: (P, 6) rows of predicted mean (2), predicted sd (2) and realized displacement (2), m.
    """
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.2, 3.8))
    for k, (axis, colour) in enumerate((("x", "C0"), ("y", "C1"))):
        ax.errorbar(
            100 * pushes[:, 4 + k],
            100 * pushes[:, k],
            yerr=100 * Z90 * pushes[:, 2 + k],
            fmt=".",
            color=colour,
            ecolor=colour,
            alpha=0.6,
            lw=0.8,
            label=axis,
        )
    lim = float(np.abs(100 * pushes[:, [0, 1, 4, 5]]).max()) if len(pushes) else 1.0
    ax.plot([-lim, lim], [-lim, lim], color="k", lw=1, ls=":")
    ax.set(xlabel="realized displacement, cm", ylabel="predicted (90 % interval), cm", title="C2 pushes")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def paths_figure(paths: dict[str, list[np.ndarray]], specs: list[dict[str, Any]], n: int = 4) -> Figure:
    """The box centre's path (T + 1, 2) m under each controller in the first ``n`` episodes, with its start and goal."""
    import matplotlib.pyplot as plt

    n = min(n, len(specs))
    cols = min(n, 2)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, 3.2 * rows), squeeze=False)
    for k, ax in enumerate(axes.flat):
        if k >= n:
            ax.set_axis_off()
            continue
        for (c, runs), colour in zip(paths.items(), _COLOURS, strict=True):
            p = 100 * runs[k]
            ax.plot(p[:, 0], p[:, 1], color=colour, marker=".", ms=3, lw=1, label=c)
        start, goal = 100 * np.asarray(specs[k]["box"][:2]), 100 * np.asarray(specs[k]["goal"])
        ax.plot(*start, color="k", marker="o", ls="none", label="start")
        ax.plot(*goal, color="k", marker="*", ms=11, ls="none", label="goal")
        ax.set(xlabel="x, cm", ylabel="y, cm", title=f"goal {k}", aspect="equal")
    axes.flat[0].legend(fontsize=6)
    fig.suptitle("C2: the box's path and its goal")
    fig.tight_layout()
    return fig


def episodes_figure(traces: dict[str, list[np.ndarray]], target_cm: float) -> Figure:
    """Each controller's box-goal distance per step (m, plotted in cm), with the target as a dotted line."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for (c, runs), colour in zip(traces.items(), _COLOURS, strict=True):
        for k, trace in enumerate(runs):
            ax.plot(
                np.arange(len(trace)),
                trace * 100,
                color=colour,
                alpha=0.35,
                lw=1,
                label=c if k == 0 else None,
            )
    ax.axhline(target_cm, color="k", ls=":", lw=1)
    ax.set(xlabel="step", ylabel="box distance to goal, cm", title="C2 episodes")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
