"""Experiment B3: curiosity-conditioned target selection (thesis §5.2.4, Fig. 5.7).

The observed range X_q of the post-action angle is cut into 20 bins and the training
transitions give the visit counts c_k. For each of 128 test pre-action states q(t-1) one
target is drawn from the curiosity-biased density (Eq. 5.8-5.9)

    p_tar(k) ∝ (max_j c_j - c_k + eps) (1 + alpha exp(-((mu_k - q(t-1)) / sigma)^2 / 2)),

alpha = 0.5, sigma = |X_q| / 10, and a uniform position inside the drawn bin. Two
conditions act on the same states and targets: ``inferred`` (Alg. 4.2 as in B2) and
``random`` (a ~ U(X_a)). Their outcomes are scored by occupancy (visited bins / 20),
normalised entropy over the 20 bins and the mean absolute target error; model-internally
(the model's predicted q(t), as the thesis did) and **realized** (the recorded simulator
state restored and the action executed for one step).

Metrics: ``realized`` and ``model_internal``: ``{graph: {random|inferred: {occupancy,
entropy, target_mae}}}``; ``target_entropy``; ``training: {occupancy, entropy}``; ``info``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from inference import ActionOptions, SamplingConfig, normalized_entropy, occupancy
from pal.checks import check_int
from pal.experiments.world_model.b1 import QUICK_PROTOCOL, TINY_PROTOCOL
from pal.experiments.world_model.b2 import SAMPLED
from pal.experiments.world_model.calibration import (
    calibration,
    calibration_table,
    coverage_targets,
    reliability_figure,
)
from pal.experiments.world_model.data import pick_rows
from pal.experiments.world_model.setup import (
    ActionConfig,
    CuriosityDensity,
    ProtocolConfig,
    abs_errors,
    infer_actions,
    predict_q,
    prepare,
    setup_note,
    state_of,
)
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["THESIS", "Config", "run"]

#: Thesis §5.2.4 (model-internal outcomes; the training data: 20/20 bins, H = 0.840).
THESIS = {
    "training": {"occupancy": 1.0, "entropy": 0.840},
    "random": {"occupancy": 0.90, "entropy": 0.866, "target_mae": 1.302},
    "inferred": {"occupancy": 0.95, "entropy": 0.900, "target_mae": 0.203},
}
CONDITIONS = ("random", "inferred")
_QUANTITIES = (("occupancy", "occupancy"), ("entropy", "entropy H"), ("target_mae", "target MAE [rad]"))


@dataclass(frozen=True)
class Config:
    """B3 protocol (thesis §5.2.4).

    Attributes:
        seed: seeds the protocol, the test rows, the targets and the random actions.
        protocol: data, graphs and fitting schedule (shared with B1 and B2).
        targets: number of test pre-action states (one curiosity target each).
        curiosity: the target density (Eq. 5.8-5.9) and its bins over X_q.
        action: Alg. 4.2 settings.
    """

    seed: int = 0
    protocol: ProtocolConfig = ProtocolConfig()
    targets: int = 128
    curiosity: CuriosityDensity = CuriosityDensity()
    action: ActionConfig = SAMPLED

    def __post_init__(self) -> None:
        check_int("targets", self.targets)


def tables(metrics: dict[str, Any]) -> list[Table]:
    """The training data and targets, then the outcomes per condition, thesis beside ours."""
    real, model = metrics["realized"], metrics["model_internal"]
    graphs = list(real)
    data_rows = [
        ("training outcomes", "occupancy", THESIS["training"]["occupancy"], metrics["training"]["occupancy"]),
        ("training outcomes", "entropy H", THESIS["training"]["entropy"], metrics["training"]["entropy"]),
        ("curiosity targets", "entropy H", None, metrics["target_entropy"]),
    ]
    columns = ["Condition", "Quantity", "thesis (model-internal)"]
    for g in graphs:
        columns += [f"{g} model-internal", f"{g} realized"]
    rows = []
    for cond in CONDITIONS:
        for key, label in _QUANTITIES:
            row: list[Any] = [f"{cond} actions", label, THESIS[cond][key]]
            for g in graphs:
                row += [model[g][cond][key], real[g][cond][key]]
            rows.append(row)
    return [
        Table("Training data and curiosity targets", ("", "Quantity", "thesis", "ours"), data_rows),
        Table("Outcomes of the actions for the sampled targets (thesis §5.2.4)", columns, rows),
    ]


def targets(realized: dict[str, Any]) -> list[Target]:
    """Per graph: realized occupancy and entropy with inferred actions >= with random actions."""
    out = []
    for graph, m in realized.items():
        for key in ("occupancy", "entropy"):
            out.append(
                Target(
                    f"{key}_gain.{graph}",
                    m["inferred"][key] - m["random"][key],
                    0.0,
                    ">=",
                    f"realized {key} with inferred minus with random actions, {graph} graph",
                )
            )
    return out


def _coverage(
    values: np.ndarray, targets: np.ndarray, q_range: tuple[float, float], bins: int
) -> dict[str, float]:
    return {
        "occupancy": occupancy(values, *q_range, bins),
        "entropy": normalized_entropy(values, *q_range, bins),
        "target_mae": float(abs_errors(values, targets).mean()),
    }


@register(
    "b3",
    config=Config,
    quick=Config(protocol=QUICK_PROTOCOL, targets=64),
    tiny=Config(
        protocol=TINY_PROTOCOL,
        targets=6,
        curiosity=CuriosityDensity(bins=5),
        action=ActionConfig(
            num_steps=20, options=ActionOptions(sampling=SamplingConfig(population=16, elites=4))
        ),
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """B3: curiosity targets reached with inferred or random actions, replayed in the simulator (Fig. 5.7)."""
    prep = prepare(config.protocol, config.seed, progress_bar=progress_bar)
    act, qp, dq, q = prep.joint.names
    low_q, high_q = prep.q_range
    sampler = config.curiosity.sampler(low_q, high_q)
    sampler.fit(prep.joint.columns(prep.train)[q])
    rows = pick_rows(len(prep.test), config.targets, config.seed)
    q_prev = prep.test_columns[qp][rows, 0].astype(np.float64)
    goals = sampler.sample(np.random.default_rng([config.seed, 3]), current=q_prev)
    low, high = prep.joint.action_range
    random_a = np.random.default_rng([config.seed, 2]).uniform(low, high, size=len(rows))
    random_real = prep.realizer.outcomes(rows, random_a)
    points = {"targets": goals, "random.real": random_real, "edges": sampler.edges_}
    realized: dict[str, dict[str, dict[str, float]]] = {}
    internal: dict[str, dict[str, dict[str, float]]] = {}
    a = config.action
    transitions: dict[str, dict[str, np.ndarray]] = {}
    for graph, model in prep.models.items():
        state = state_of(model, prep.test_columns, rows)
        actions, predicted, _ = infer_actions(model, prep.joint, state, goals, a, seed=config.seed)
        outcomes = {
            "random": (predict_q(model, prep.joint, state, random_a), random_real),
            "inferred": (predicted, prep.realizer.outcomes(rows, actions)),
        }
        realized[graph], internal[graph] = {}, {}
        for cond, (pred, real) in outcomes.items():
            internal[graph][cond] = _coverage(pred, goals, prep.q_range, config.curiosity.bins)
            realized[graph][cond] = _coverage(real, goals, prep.q_range, config.curiosity.bins)
            points[f"{graph}.{cond}.model"] = pred
        points[f"{graph}.inferred.real"] = real_inferred = outcomes["inferred"][1]
        transitions[graph] = {**state, act: actions, dq: real_inferred - q_prev, q: real_inferred}
    info = prep.info()
    cal = calibration(prep.models, transitions)
    what = "the realized transitions of the inferred actions"
    metrics = {
        "realized": realized,
        "model_internal": internal,
        "target_entropy": normalized_entropy(goals, low_q, high_q, config.curiosity.bins),
        "training": {"occupancy": sampler.occupancy(), "entropy": sampler.normalized_entropy()},
        "calibration": cal,
        "info": info,
    }
    return Report(
        title="B3: curiosity-conditioned target selection (thesis §5.2.4, Fig. 5.7)",
        metrics=metrics,
        tables=[*tables(metrics), calibration_table(cal, what)],
        targets=[*targets(realized), *coverage_targets(cal, what)],
        notes=[
            setup_note(info),
            f"{len(rows)} test pre-action states, {config.curiosity.bins} bins over X_q, alpha {config.curiosity.alpha}, "
            f"sigma {config.curiosity.sigma_fraction} x |X_q| (Eq. 5.8-5.9).",
        ],
        figures={"fig5_7": _figure(points, list(realized)), "reliability": reliability_figure(cal, what)},
    )


def _figure(points: dict[str, np.ndarray], graphs: list[str]) -> Figure:
    """Fig. 5.7 per graph: targets (outline) and outcomes (filled), model-internal and realized."""
    import matplotlib.pyplot as plt

    edges = points["edges"]
    fig, axes = plt.subplots(len(graphs), 2, figsize=(9, 3.2 * len(graphs)), squeeze=False)
    for row, graph in zip(axes, graphs, strict=True):
        for ax, kind in zip(row, ("model", "real"), strict=True):
            rand = points[f"{graph}.random.model"] if kind == "model" else points["random.real"]
            inferred = points[f"{graph}.inferred.{kind}"]
            lo, hi = edges[0], edges[-1]
            ax.hist(np.clip(rand, lo, hi), bins=edges, alpha=0.5, color="0.55", label="random actions")
            ax.hist(np.clip(inferred, lo, hi), bins=edges, alpha=0.5, color="C3", label="inferred actions")
            ax.hist(
                points["targets"], bins=edges, histtype="step", color="k", lw=1.5, label="curiosity targets"
            )
            what = "predicted by the model" if kind == "model" else "realized in the simulator"
            ax.set(xlabel="post-action q(t) [rad]", ylabel="count", title=f"{graph} graph: {what}")
            ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
