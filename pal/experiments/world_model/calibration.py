"""Calibration of the world-model experiments: NLL and interval coverage per site, on realized transitions.

For every fitted graph and every non-root site X_i, the observed parents of each held-out
realized transition give the model's one-step predictive Normal (its sigma_i, its
sigma_i(pa_i), or an ensemble's moment-matched mixture; :func:`inference.calibration.predictive_check`),
and the realized x_i is scored: NLL (nats), the share inside the central 90 % interval,
MSE, and the reliability pairs (nominal, observed) drawn as a reliability diagram. A
calibrated model covers 90 % of the outcomes with its 90 % interval; an overconfident one
covers fewer.

Given its observed parents, ``q = q_prev + dq`` is an identity, so its coverage there tests
nothing. The coverage the targets hold is therefore ``coverage_action``: each site's interval
as a prediction from the action and the state before the step, the graph's roots only, its
unobserved ancestors (``dq`` for ``q``) sampled (:func:`inference.predictive_interval`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from inference.calibration import predictive_check
from inference.predictive import predictive_interval
from models import WorldModel
from pal.lab.report import Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["LEVEL", "TOLERANCE", "calibration", "calibration_table", "coverage_targets", "reliability_figure"]

#: Nominal level of the reported interval.
LEVEL = 0.9
#: A calibrated site covers within this distance of :data:`LEVEL` (85-95 %).
TOLERANCE = 0.05
#: Forward draws per row of the coverage from the action.
DRAWS = 200

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
        roots = {r: cols[r] for r in model.graph.roots}
        for site, c in out[graph].items():
            c["coverage_action"] = _from_action(model, roots, cols[site], site)
    return out


def _from_action(model: WorldModel, roots: Mapping[str, np.ndarray], truth: np.ndarray, site: str) -> float:
    """Share of ``truth`` inside the site's interval predicted from the roots (module docstring)."""
    iv = predictive_interval(model, roots, site, LEVEL, DRAWS, seed=0)
    x = np.asarray(truth, np.float64).reshape(iv.lower.shape)
    inside = (x >= iv.lower.double().numpy()) & (x <= iv.upper.double().numpy())
    return float(inside.all(-1).mean())


def calibration_table(cal: Calibration, what: str) -> Table:
    """One row per graph and site: NLL, coverage of the 90 % interval, MSE and mean predictive sd."""
    rows = [
        (graph, site, c["nll"], c["coverage"], c.get("coverage_action"), c["mse"], c["mean_sd"], c["n"])
        for graph, sites in cal.items()
        for site, c in sites.items()
    ]
    return Table(
        f"Calibration on {what}",
        (
            "graph",
            "site",
            "NLL [nats]",
            f"coverage of the {LEVEL:.0%} interval, given the parents",
            "coverage, predicted from the action",
            "MSE",
            "mean predictive sd",
            "rows",
        ),
        rows,
        caption=f"Calibrated: coverage within {LEVEL - TOLERANCE:.0%}-{LEVEL + TOLERANCE:.0%}. Given the parents, "
        "q = q_prev + dq is an identity; the targets hold the coverage predicted from the action and the state.",
    )


def coverage_targets(cal: Calibration, what: str) -> list[Target]:
    """Per graph: the largest |coverage - 0.9| over its sites <= 0.05, the coverage predicted from the action."""
    return [
        Target(
            f"coverage_gap.{graph}",
            max(abs(c.get("coverage_action", c["coverage"]) - LEVEL) for c in sites.values()),
            TOLERANCE,
            "<=",
            f"largest |coverage of the {LEVEL:.0%} interval - {LEVEL}| over the sites of the {graph} graph, "
            f"predicted from the action and the state, {what}",
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
