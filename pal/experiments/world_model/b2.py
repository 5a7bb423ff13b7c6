"""Experiment B2: action inference for proprioceptive targets (thesis §5.2.3, Fig. 5.6).

Targets are the post-action angles q(t) of 128 test transitions, each with its own
pre-action state q(t-1) fixed. Two conditions:

- ``random``: a ~ U(X_a) (Eq. 5.6);
- ``inferred``: Alg. 4.2 through the frozen model, Adam for 200 steps at lr 0.05 from the
  midpoint of X_a, clipped to X_a after every step, no regulariser.

Each action is judged twice: **model-internal**, by the model's prediction
Phi(q(t-1), a) (Eq. 5.7, what the thesis reported), and **realized**, by restoring the
recorded simulator state before the transition, executing a for one step (the other
actuators keep their recorded commands) and measuring the angle reached.

With ``two_step`` each inferred action is followed by the two-step protocol
(:mod:`pal.experiments.world_model.b2_two_step`: act, abduct the step's noise, act again from
the same state), reported beside the one-shot protocol as ``error[graph]["two_step"]``. When the
data record the joint velocity, ``velocity_proxy_r2`` is the R^2 of the previous step's
displacement ``dq_prev`` as a linear predictor of the velocity at the step's start (MuJoCo's
``qvel``) on the test rows.

Metrics: ``error: {graph: {random: {mae_model, mae_real}, inferred: {mae_model, mae_real,
within_005_real, within_010_real}}}``, ``model_internal: {graph: {within_005_model,
within_010_model, objective_first, objective_last}}`` and ``info``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from inference import ActionOptions, SamplingConfig
from pal.checks import check_int
from pal.experiments.world_model.b1 import QUICK_PROTOCOL, TINY_PROTOCOL
from pal.experiments.world_model.b2_two_step import two_step
from pal.experiments.world_model.calibration import (
    calibration,
    calibration_table,
    coverage_targets,
    reliability_figure,
)
from pal.experiments.world_model.data import pick_rows
from pal.experiments.world_model.setup import (
    ActionConfig,
    Prepared,
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

__all__ = ["THESIS", "Config", "evaluate", "run"]

#: Thesis §5.2.3 (model-internal): MAE random 0.851, inferred 0.195 rad; MSE objective
#: 1.113 -> 0.286 rad^2; 79.7 % / 82.8 % of inferred actions within 0.05 / 0.10 rad.
THESIS = {
    "random_mae": 0.851,
    "inferred_mae": 0.195,
    "objective": (1.113, 0.286),
    "within_005": 0.797,
    "within_010": 0.828,
}
#: Realized targets of the state graph.
TARGET_MAE = 0.05
TARGET_WITHIN = 0.9
#: Realized targets of the dynamics graph (with the sampling stage before Alg. 4.2).
TARGET_MAE_DYNAMICS = 0.03
TARGET_WITHIN_DYNAMICS = 0.95
#: Realized share within 0.05 rad of the two-step protocol.
TARGET_WITHIN_TWO_STEP = 0.97
#: Per graph: (realized MAE, share within 0.05 rad) targets of the one-shot protocol.
GRAPH_TARGETS = {
    "state": (TARGET_MAE, TARGET_WITHIN),
    "dynamics": (TARGET_MAE_DYNAMICS, TARGET_WITHIN_DYNAMICS),
    "velocity": (TARGET_MAE_DYNAMICS, TARGET_WITHIN_DYNAMICS),
}
#: The action inference of B2: a CEM sampling stage (the midpoint of X_a in its first
#: population, so the thesis protocol is the special case sampling = None), then Alg. 4.2.
SAMPLED = ActionConfig(
    options=ActionOptions(sampling=SamplingConfig(population=128, elites=16, iterations=3))
)


@dataclass(frozen=True)
class Config:
    """B2 protocol (thesis §5.2.3).

    Attributes:
        seed: seeds the protocol, the test rows and the random actions.
        protocol: data, graphs and fitting schedule (shared with B1 and B3).
        targets: number of test targets.
        action: Alg. 4.2 settings.
        two_step: also run the two-step protocol (act, abduct, act again); needs ``action.options.sampling``.
    """

    seed: int = 0
    protocol: ProtocolConfig = ProtocolConfig()
    targets: int = 128
    action: ActionConfig = SAMPLED
    two_step: bool = False

    def __post_init__(self) -> None:
        check_int("targets", self.targets)
        if not isinstance(self.two_step, bool):
            raise ValueError(f"two_step is {self.two_step!r}; expected True or False")
        if self.two_step and self.action.options.sampling is None:
            raise ValueError(
                "two_step replays the abducted noise in the torch twin; give action.options.sampling"
            )


def tables(error: dict[str, Any], internal: dict[str, Any]) -> list[Table]:
    """Thesis §5.2.3 beside the model-internal and realized errors of each graph."""
    graphs = list(error)
    columns = ["Quantity", "thesis (model-internal)"]
    for g in graphs:
        columns += [f"{g} model-internal", f"{g} realized"]
    rows: list[list[Any]] = []
    for label, ref, cond, key in (
        ("MAE, random actions [rad]", THESIS["random_mae"], "random", "mae"),
        ("MAE, inferred actions [rad]", THESIS["inferred_mae"], "inferred", "mae"),
        ("share of inferred within 0.05 rad", THESIS["within_005"], "inferred", "within_005"),
        ("share of inferred within 0.10 rad", THESIS["within_010"], "inferred", "within_010"),
    ):
        row: list[Any] = [label, ref]
        for g in graphs:
            m = error[g][cond]
            row += [m.get(f"{key}_model", internal[g].get(f"{key}_model")), m.get(f"{key}_real")]
        rows.append(row)
    obj: list[Any] = [
        "MSE objective, first -> last Adam step [rad²]",
        "{:.3f} -> {:.3f}".format(*THESIS["objective"]),
    ]
    for g in graphs:
        obj += [f"{internal[g]['objective_first']:.3f} -> {internal[g]['objective_last']:.3f}", None]
    rows.append(obj)
    return [Table("Action inference for proprioceptive targets (thesis §5.2.3)", columns, rows)]


def targets(error: dict[str, Any]) -> list[Target]:
    """Realized MAE and share within 0.05 rad of the fitted graphs (:data:`GRAPH_TARGETS`); two-step >= 97 %."""
    out = []
    for graph, (mae, within) in GRAPH_TARGETS.items():
        if graph not in error:  # not fitted in this run: no target
            continue
        inferred = error[graph]["inferred"]
        if "two_step" in error[graph]:
            out.append(
                Target(
                    f"realized_within_005_two_step.{graph}",
                    error[graph]["two_step"]["within_005_real"],
                    TARGET_WITHIN_TWO_STEP,
                    ">=",
                    f"share of targets reached within 0.05 rad, realized, two-step protocol, {graph} graph",
                )
            )
        out += [
            Target(
                f"realized_mae.{graph}",
                inferred.get("mae_real"),
                mae,
                "<=",
                f"realized MAE of the inferred actions, {graph} graph, rad",
            ),
            Target(
                f"realized_within_005.{graph}",
                inferred.get("within_005_real"),
                within,
                ">=",
                f"share of targets reached within 0.05 rad, realized, {graph} graph",
            ),
        ]
    return out


@register(
    "b2",
    config=Config,
    quick=Config(protocol=QUICK_PROTOCOL, targets=32),
    tiny=Config(
        protocol=replace(TINY_PROTOCOL, graphs=("thesis", "state", "dynamics", "velocity")),
        targets=4,
        two_step=True,
        action=ActionConfig(
            num_steps=20, options=ActionOptions(sampling=SamplingConfig(population=16, elites=4))
        ),
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """B2: actions inferred for test targets, executed in the simulator from the recorded states (Fig. 5.6)."""
    prep = prepare(config.protocol, config.seed, progress_bar=progress_bar)
    error, internal, points = evaluate(prep, config)
    info = prep.info()
    cal = calibration(prep.models, points["realized"])
    what = "the realized transitions of the inferred actions"
    return Report(
        title="B2: action inference (thesis §5.2.3, Fig. 5.6)",
        metrics={
            "error": error,
            "model_internal": internal,
            "calibration": cal,
            "info": info,
            "velocity_proxy_r2": velocity_proxy_r2(prep.test_columns, prep.joint.joint),
        },
        tables=[*tables(error, internal), calibration_table(cal, what)],
        targets=[*targets(error), *coverage_targets(cal, what)],
        notes=[
            setup_note(info),
            f"{len(points['target'])} test targets; inferred: {config.action.describe()}. Realized: the recorded "
            "simulator state is restored and the action executed for one step.",
        ],
        figures={"fig5_6": _figure(points, list(error)), "reliability": reliability_figure(cal, what)},
    )


def evaluate(
    prep: Prepared, config: Config
) -> tuple[dict[str, dict[str, dict[str, float]]], dict[str, dict[str, float]], dict[str, np.ndarray]]:
    """B2 on fitted models: ``(error, model_internal, points)`` (see the module docstring).

    ``points`` holds ``target``, ``random.real`` and per graph ``<graph>.model``,
    ``<graph>.real``, ``<graph>.random_model`` outcomes, rad, for the figure, and
    ``realized``: graph -> the realized transitions of its inferred actions (name ->
    ``(n, 1)``: the action, the state, and the realized dq and q) for the calibration.
    """
    q = prep.joint.names[3]
    rows = pick_rows(len(prep.test), config.targets, config.seed)
    cols = prep.test_columns
    target = prep.test_columns[q][rows, 0].astype(np.float64)
    low, high = prep.joint.action_range
    random_a = np.random.default_rng([config.seed, 2]).uniform(low, high, size=len(rows))
    random_real = prep.realizer.outcomes(rows, random_a)
    err_random_real = abs_errors(random_real, target)
    points: dict[str, Any] = {"target": target, "random.real": random_real}
    realized: dict[str, dict[str, np.ndarray]] = {}
    metrics: dict[str, dict[str, dict[str, float]]] = {}
    extra: dict[str, dict[str, float]] = {}
    for graph, model in prep.models.items():
        state = state_of(model, cols, rows)
        random_model = predict_q(model, prep.joint, state, random_a)
        actions, predicted, loss = infer_actions(
            model, prep.joint, state, target, config.action, seed=config.seed
        )
        real = prep.realizer.outcomes(rows, actions)
        q_prev = cols[prep.joint.names[1]][rows, 0].astype(np.float64)
        realized[graph] = {
            **state,
            prep.joint.names[0]: actions,
            prep.joint.names[2]: real - q_prev,
            q: real,
        }
        err_model, err_real = abs_errors(predicted, target), abs_errors(real, target)
        if config.two_step:
            second = two_step(prep, model, rows, target, state, (actions, real), config.action, config.seed)
            err_two = abs_errors(second["real"], target)
            points[f"{graph}.two_step"] = second["real"]
        metrics[graph] = {
            "random": {
                "mae_model": float(abs_errors(random_model, target).mean()),
                "mae_real": float(err_random_real.mean()),
            },
            "inferred": {
                "mae_model": float(err_model.mean()),
                "mae_real": float(err_real.mean()),
                "within_005_real": float((err_real <= 0.05).mean()),
                "within_010_real": float((err_real <= 0.10).mean()),
            },
        }
        if config.two_step:
            metrics[graph]["two_step"] = {
                "mae_real": float(err_two.mean()),
                "within_005_real": float((err_two <= 0.05).mean()),
            }
        extra[graph] = {
            "within_005_model": float((err_model <= 0.05).mean()),
            "within_010_model": float((err_model <= 0.10).mean()),
            "objective_first": 2 * loss[0],  # loss is 0.5 (Phi - target)^2 per target
            "objective_last": float((err_model**2).mean()),
        }
        points |= {f"{graph}.model": predicted, f"{graph}.real": real, f"{graph}.random_model": random_model}
    points["realized"] = realized
    return metrics, extra, points


def velocity_proxy_r2(columns: dict[str, np.ndarray], joint: str) -> float | None:
    """R^2 of ``dq_prev`` as a linear predictor of ``v_prev`` (the squared correlation), or None without velocities."""
    v = columns.get(f"v_prev.{joint}")
    if v is None:
        return None
    x, y = (np.asarray(c, np.float64).reshape(-1) for c in (columns[f"dq_prev.{joint}"], v))
    if x.std() == 0 or y.std() == 0:
        return None
    return float(np.corrcoef(x, y)[0, 1] ** 2)


def _figure(points: dict[str, np.ndarray], graphs: list[str]) -> Figure:
    """Fig. 5.6 per graph: target vs outcome, model-internal (left) and realized (right)."""
    import matplotlib.pyplot as plt

    t = points["target"]
    fig, axes = plt.subplots(len(graphs), 2, figsize=(8, 3.8 * len(graphs)), squeeze=False)
    lim = [float(t.min()) - 0.1, float(t.max()) + 0.1]
    for row, graph in zip(axes, graphs, strict=True):
        for ax, kind in zip(row, ("model", "real"), strict=True):
            rand = points[f"{graph}.random_model"] if kind == "model" else points["random.real"]
            ax.scatter(t, rand, s=10, alpha=0.6, color="0.6", label="random action")
            ax.scatter(t, points[f"{graph}.{kind}"], s=10, alpha=0.8, color="C3", label="inferred action")
            ax.plot(lim, lim, "k--", lw=1)
            what = "predicted by the model" if kind == "model" else "realized in the simulator"
            ax.set(
                xlabel="target q(t) [rad]",
                ylabel="post-action q(t) [rad]",
                title=f"{graph} graph: {what}",
                xlim=lim,
            )
            ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
