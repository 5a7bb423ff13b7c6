"""Figures of experiments A1-A3: trajectories (Fig. 5.2), PCA projections (Figs. 5.3-5.4), pose error."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from pal.experiments.perception.concept_eval import pca_2d
from pal.experiments.perception.evaluation import RunResult

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["pca_figure", "pose_error_figure", "trajectory_figure"]


def _motions(results: Sequence[RunResult]) -> list[str]:
    return list(dict.fromkeys(r.motion for r in results))


def trajectory_figure(results: Sequence[RunResult]) -> Figure:
    """Relative trajectories (cm, camera frame; Fig. 5.2): lateral Δx against depth Δz per motion.

    Estimated poses are solid blue for usable trajectories and dashed grey otherwise; the
    ground truth of the same point is thin black. Circles mark starts, crosses ends.
    """
    import matplotlib.pyplot as plt

    motions = _motions(results)
    cols = min(3, len(motions))
    rows = -(-len(motions) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.3 * rows), squeeze=False)
    for ax, motion in zip(axes.ravel(), motions, strict=False):
        for r in (r for r in results if r.motion == motion):
            ref = r.p_gt[0] if len(r.p_gt) else np.zeros(3)
            g = 100.0 * (r.p_gt - ref)
            ax.plot(g[:, 0], g[:, 2], color="black", lw=0.7, alpha=0.6)
            if len(r.p_est):
                e = 100.0 * (r.p_est - ref)
                style = {"color": "tab:blue", "ls": "-"} if r.usable else {"color": "0.55", "ls": "--"}
                ax.plot(e[:, 0], e[:, 2], lw=1.4, **style)
                ax.plot(e[0, 0], e[0, 2], "o", mfc="none", mec="black", ms=6)
                ax.plot(e[-1, 0], e[-1, 2], "x", color="black", ms=6)
        ax.set(title=motion, xlabel="Δx [cm]", ylabel="Δz [cm]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(motions) :]:
        ax.set_axis_off()
    fig.suptitle("estimated (blue: usable, grey dashed: limitation) vs ground truth (black)", fontsize=9)
    fig.tight_layout()
    return fig


def pca_figure(
    X: np.ndarray,
    groups: Sequence[str],
    filled: Sequence[bool],
    names: Sequence[str],
    title: str,
) -> Figure:
    """A 2-D PCA scatter of the (n, d) points ``X``: one colour per group, hollow where ``filled`` is False."""
    import matplotlib.pyplot as plt

    Z, explained = pca_2d(X)
    fig, ax = plt.subplots(figsize=(5.6, 4.4))
    colours = {g: f"C{k % 10}" for k, g in enumerate(dict.fromkeys(groups))}
    labelled: set[str] = set()
    for z, g, f, name in zip(Z, groups, filled, names, strict=True):
        c = colours[g]
        label = None if g in labelled else g
        ax.scatter([z[0]], [z[1]], s=46, color=c if f else "none", edgecolors=c, linewidths=1.5, label=label)
        labelled.add(g)
        if len(Z) <= 40:
            ax.annotate(name, (z[0], z[1]), fontsize=6, xytext=(3, 3), textcoords="offset points")
    ax.set(
        xlabel=f"PC1 ({100 * explained[0]:.1f} %)", ylabel=f"PC2 ({100 * explained[1]:.1f} %)", title=title
    )
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def pose_error_figure(results: Sequence[RunResult], targets: tuple[float, float]) -> Figure:
    """Median and 90th-percentile translation (cm) and rotation (deg) error of the estimated poses, per run.

    Args:
        results: the scored runs.
        targets: the (cm, deg) bounds drawn as dashed lines.
    """
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.4))
    names = [r.name for r in results]
    x = np.arange(len(results))
    med_t = [np.median(r.trans_err_cm) if r.trans_err_cm else np.nan for r in results]
    p90_t = [np.percentile(r.trans_err_cm, 90) if r.trans_err_cm else np.nan for r in results]
    med_r = [np.median(r.rot_err_deg) if r.rot_err_deg else np.nan for r in results]
    p90_r = [np.percentile(r.rot_err_deg, 90) if r.rot_err_deg else np.nan for r in results]
    for ax, med, p90, target, unit in (
        (a, med_t, p90_t, targets[0], "cm"),
        (b, med_r, p90_r, targets[1], "deg"),
    ):
        ax.bar(x, p90, color="0.8", label="90th percentile")
        ax.bar(x, med, color="tab:blue", width=0.5, label="median")
        ax.axhline(target, color="tab:red", lw=1, ls="--", label=f"target {target:g} {unit}")
        ax.set_xticks(x, names, rotation=70, fontsize=6)
        ax.set_ylabel(f"error [{unit}]")
        ax.legend(fontsize=7)
    a.set_title("translation error of estimated poses")
    b.set_title("rotation error of estimated poses")
    fig.tight_layout()
    return fig
