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

``pal experiment b3 --json`` prints ``{graph: {random|inferred: {occupancy_real,
entropy_real, target_mae_real}}, target_entropy}``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from inference import CuriositySampler, normalized_entropy, occupancy
from pal.experiments.timing import markdown_table
from pal.experiments.wm_data import pick_rows
from pal.experiments.wm_setup import (
    ProtocolConfig,
    abs_errors,
    infer_actions,
    predict_q,
    prepare,
    setup_line,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["THESIS", "Config", "Result", "run"]

#: Thesis §5.2.4 (model-internal outcomes; the training data: 20/20 bins, H = 0.840).
THESIS = {
    "training": {"occupancy": 1.0, "entropy": 0.840},
    "random": {"occupancy": 0.90, "entropy": 0.866, "target_mae": 1.302},
    "inferred": {"occupancy": 0.95, "entropy": 0.900, "target_mae": 0.203},
}
CONDITIONS = ("random", "inferred")


@dataclass(frozen=True)
class Config(ProtocolConfig):
    """B3 protocol (thesis §5.2.4).

    Attributes:
        targets: number of test pre-action states (one curiosity target each).
        bins: histogram bins over X_q.
        alpha: locality amplification of Eq. 5.8.
        sigma_fraction: locality width sigma as a fraction of |X_q|.
        action_steps, action_lr: Adam iterations and learning rate of Alg. 4.2.
        action_starts: 1 starts Adam at the midpoint of X_a (the thesis protocol); k > 1
            restarts it from k points across X_a and keeps the best under the model.
    """

    targets: int = 128
    bins: int = 20
    alpha: float = 0.5
    sigma_fraction: float = 0.1
    action_steps: int = 200
    action_lr: float = 0.05
    action_starts: int = 1

    @classmethod
    def quick(cls) -> Config:
        return cls(steps=20_000, epochs=40, targets=64)


@dataclass(frozen=True)
class Result:
    """B3 coverage per graph and condition.

    Attributes:
        metrics: graph -> condition -> ``occupancy_real``, ``entropy_real``,
            ``target_mae_real`` (and the model-internal ``*_model`` in :attr:`model`).
        model: graph -> condition -> ``occupancy_model``, ``entropy_model``, ``target_mae_model``.
        target_entropy: normalised entropy of the sampled targets over the bins.
        training: ``occupancy`` and ``entropy`` of the training outcomes.
        info: body, joint, sizes, ranges, seconds.
        points: ``targets``, ``random.real``, ``<graph>.<condition>.model``,
            ``<graph>.inferred.real`` outcomes (rad), and ``edges`` of the bins.
    """

    metrics: dict[str, dict[str, dict[str, float]]]
    model: dict[str, dict[str, dict[str, float]]]
    target_entropy: float
    training: dict[str, float]
    info: dict[str, Any]
    config: Config
    points: dict[str, np.ndarray] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {g: {c: dict(v) for c, v in conds.items()} for g, conds in self.metrics.items()}
        out["target_entropy"] = self.target_entropy
        return out

    def target_met(self, graph: str = "state") -> bool | None:
        """Realized occupancy and entropy under inferred actions >= under random actions."""
        m = self.metrics.get(graph)
        if m is None:
            return None
        return all(m["inferred"][f"{k}_real"] >= m["random"][f"{k}_real"] for k in ("occupancy", "entropy"))

    def to_markdown(self) -> str:
        graphs = list(self.metrics)
        header = ["Condition", "Quantity", "thesis (model-internal)"]
        for g in graphs:
            header += [f"`{g}` model-internal", f"`{g}` realized"]
        data_rows: list[list[Any]] = [
            ["training outcomes", "occupancy", THESIS["training"]["occupancy"], self.training["occupancy"]],
            ["training outcomes", "entropy H", THESIS["training"]["entropy"], self.training["entropy"]],
            ["curiosity targets", "entropy H", None, self.target_entropy],
        ]
        rows: list[list[Any]] = []
        for cond in CONDITIONS:
            for key, label in (
                ("occupancy", "occupancy"),
                ("entropy", "entropy H"),
                ("target_mae", "target MAE [rad]"),
            ):
                row = [f"{cond} actions", label, THESIS[cond][key]]
                for g in graphs:
                    row += [self.model[g][cond][f"{key}_model"], self.metrics[g][cond][f"{key}_real"]]
                rows.append(row)
        c = self.config
        lines = [
            "## B3: curiosity-conditioned target selection (thesis §5.2.4, Fig. 5.7)",
            "",
            setup_line(self.info),
            f"{len(self.points.get('targets', []))} test pre-action states, {c.bins} bins over X_q, "
            f"alpha {c.alpha}, sigma {c.sigma_fraction} x |X_q| (Eq. 5.8-5.9).",
            "",
            markdown_table(["", "Quantity", "thesis", "ours"], data_rows),
            "",
            "Outcomes of the actions for the sampled targets:",
            "",
            markdown_table(header, rows),
            "",
        ]
        for g in graphs:
            met = self.target_met(g)
            lines.append(
                f"Target (`{g}` graph): realized occupancy and entropy with inferred actions >= random: "
                f"{'met' if met else 'NOT met'}."
            )
        return "\n".join([*lines, ""])

    def figures(self) -> dict[str, Figure]:
        if not self.points:
            return {}
        return {"fig5_7": _figure(self.points, list(self.metrics))}


def _coverage(
    values: np.ndarray, targets: np.ndarray, q_range: tuple[float, float], bins: int
) -> dict[str, float]:
    return {
        "occupancy": occupancy(values, *q_range, bins),
        "entropy": normalized_entropy(values, *q_range, bins),
        "target_mae": float(abs_errors(values, targets).mean()),
    }


def run(config: Config, progress_bar: bool = False) -> Result:
    """Sample curiosity targets, reach them with inferred or random actions, replay both."""
    prep = prepare(config, progress_bar=progress_bar)
    _, qp, _, q = prep.joint.names
    low_q, high_q = prep.q_range
    sampler = CuriositySampler(
        low_q, high_q, bins=config.bins, alpha=config.alpha, sigma=config.sigma_fraction * (high_q - low_q)
    )
    sampler.fit(prep.joint.columns(prep.train)[q])
    rows = pick_rows(len(prep.test), config.targets, config.seed)
    q_prev = prep.test_columns[qp][rows, 0].astype(np.float64)
    targets = sampler.sample(np.random.default_rng([config.seed, 3]), current=q_prev)
    low, high = prep.joint.action_range
    random_a = np.random.default_rng([config.seed, 2]).uniform(low, high, size=len(rows))
    random_real = prep.realizer.outcomes(rows, random_a)
    points = {"targets": targets, "random.real": random_real, "edges": sampler.edges_}
    metrics: dict[str, dict[str, dict[str, float]]] = {}
    model_metrics: dict[str, dict[str, dict[str, float]]] = {}
    for graph, model in prep.models.items():
        actions, predicted, _ = infer_actions(
            model, prep.joint, q_prev, targets, config.action_steps, config.action_lr, config.action_starts
        )
        outcomes = {
            "random": (predict_q(model, prep.joint, q_prev, random_a), random_real),
            "inferred": (predicted, prep.realizer.outcomes(rows, actions)),
        }
        metrics[graph], model_metrics[graph] = {}, {}
        for cond, (pred, real) in outcomes.items():
            cm, cr = (
                _coverage(pred, targets, prep.q_range, config.bins),
                _coverage(real, targets, prep.q_range, config.bins),
            )
            model_metrics[graph][cond] = {f"{k}_model": v for k, v in cm.items()}
            metrics[graph][cond] = {f"{k}_real": v for k, v in cr.items()}
            points[f"{graph}.{cond}.model"] = pred
        points[f"{graph}.inferred.real"] = outcomes["inferred"][1]
    return Result(
        metrics,
        model_metrics,
        normalized_entropy(targets, low_q, high_q, config.bins),
        {"occupancy": sampler.occupancy(), "entropy": sampler.normalized_entropy()},
        {**prep.info(), "config": asdict(config)},
        config,
        points,
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
