"""Calibration of the world-model experiments: NLL and interval coverage per site, on realized transitions.

For every fitted graph and every non-root site X_i, the observed parents of each held-out
realized transition give the model's one-step predictive Normal (its sigma_i, its
sigma_i(pa_i), or an ensemble's moment-matched mixture; :func:`inference.calibration.predictive_check`),
and the realized x_i is scored: NLL (nats), the share inside the central 90 % interval,
MSE, and the reliability pairs (nominal, observed) drawn as a reliability diagram. A
calibrated model covers 90 % of the outcomes with its 90 % interval; an overconfident one
covers fewer.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from inference.calibration import predictive_check
from models import WorldModel
from pal.lab.report import Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["LEVEL", "TOLERANCE", "calibration", "calibration_table", "coverage_targets", "reliability_figure"]

#: Nominal level of the reported interval.
LEVEL = 0.9
#: A calibrated site covers within this distance of :data:`LEVEL` (85-95 %).
TOLERANCE = 0.05

Calibration = dict[str, dict[str, dict[str, Any]]]


def calibration(
    models: Mapping[str, WorldModel], data: Mapping[str, Mapping[str, np.ndarray]]
) -> Calibration:
    """The predictive check of every graph's model on its data: graph -> site -> result.

    Args:
        models: graph variant -> fitted model.
        data: graph variant -> name -> ``(N, 1)`` realized values (the sites and their parents).
    """
    out: Calibration = {}
    for graph, model in models.items():
        cols = {
            k: np.asarray(v, np.float32).reshape(-1, 1) for k, v in data[graph].items() if k in model.graph
        }
        out[graph] = predictive_check(model, cols, level=LEVEL)
    return out


def calibration_table(cal: Calibration, what: str) -> Table:
    """One row per graph and site: NLL, coverage of the 90 % interval, MSE and mean predictive sd."""
    rows = [
        (graph, site, c["nll"], c["coverage"], c["mse"], c["mean_sd"], c["n"])
        for graph, sites in cal.items()
        for site, c in sites.items()
    ]
    return Table(
        f"Calibration on {what}",
        (
            "graph",
            "site",
            "NLL [nats]",
            f"coverage of the {LEVEL:.0%} interval",
            "MSE",
            "mean predictive sd",
            "rows",
        ),
        rows,
        caption=f"Calibrated: coverage within {LEVEL - TOLERANCE:.0%}-{LEVEL + TOLERANCE:.0%}.",
    )


def coverage_targets(cal: Calibration, what: str) -> list[Target]:
    """Per graph: the largest |coverage - 0.9| over its sites <= 0.05."""
    return [
        Target(
            f"coverage_gap.{graph}",
            max(abs(c["coverage"] - LEVEL) for c in sites.values()),
            TOLERANCE,
            "<=",
            f"largest |coverage of the {LEVEL:.0%} interval - {LEVEL}| over the sites of the {graph} graph, {what}",
        )
        for graph, sites in cal.items()
    ]


def reliability_figure(cal: Calibration, what: str) -> Figure:
    """Observed against nominal coverage, one panel per graph, one line per site."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(cal), figsize=(3.4 * len(cal), 3.3), squeeze=False)
    for ax, (graph, sites) in zip(axes[0], cal.items(), strict=True):
        ax.plot([0, 1], [0, 1], "k:", lw=1, label="calibrated")
        for site, c in sites.items():
            nominal, observed = zip(*c["reliability"], strict=True)
            ax.plot(nominal, observed, marker="o", ms=3, label=site)
        ax.set(
            xlabel="nominal coverage",
            ylabel="observed coverage",
            title=f"{graph} graph",
            xlim=(0, 1),
            ylim=(0, 1),
        )
        ax.legend(fontsize=7)
    fig.suptitle(f"Reliability on {what}", fontsize=9)
    fig.tight_layout()
    return fig
