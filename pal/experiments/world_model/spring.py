"""A finger-like world model learnt from a known nonlinear SCM, then queried (B1-B3 in miniature).

The ground truth is a spring that pulls the joint towards an action-dependent equilibrium,
so the displacement depends on the previous angle (the ``state`` graph of thesis Fig. 5.5
plus q_prev -> dq):

    dq = 0.8 (q_eq(a) - q_prev) + 0.05 U,   q_eq(a) = -0.7 + 1.6 tanh(3 a)
    q  = q_prev + dq + 0.01 U,               q_prev ~ N(-1, 0.8²)

Both graphs are fitted on 80 % of the samples; on the rest we report one-step errors,
action inference for test targets (judged by the true SCM) and curiosity targets
(Eq. 5.8-5.9) with the occupancy and entropy of the outcomes they lead to.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from inference import (
    ActionOptions,
    CuriositySampler,
    FitSchedule,
    fit,
    infer_action,
    normalized_entropy,
    occupancy,
)
from models import FunctionMechanism, LinearMechanism, WorldModel, finger_graph
from models.presets import FINGER_ACTION_RANGE
from pal.checks import check_int
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["Config", "run", "spring_finger"]

JOINT = "finger"
Q_RANGE = (-2.79, 0.14)
ACT, Q_PREV, DQ, Q = (f"{k}.{JOINT}" for k in ("act", "q_prev", "dq", "q"))


@dataclass(frozen=True)
class Config:
    """Sizes.

    Attributes:
        seed: seeds the samples, the initial weights, the minibatches and the random actions.
        transitions: samples of the true SCM (80:20 split).
        schedule: the :func:`inference.fit` schedule.
        targets: test targets of action inference and curiosity.
    """

    seed: int = 0
    transitions: int = 20000
    schedule: FitSchedule = FitSchedule(epochs=60, batch_size=512)
    targets: int = 128

    def __post_init__(self) -> None:
        check_int("transitions", self.transitions, minimum=10)
        if not isinstance(self.schedule, FitSchedule):
            raise ValueError(f"schedule must be a FitSchedule, got {type(self.schedule).__name__}")
        check_int("targets", self.targets)


def spring_finger() -> WorldModel:
    """The ground-truth SCM of the module docstring."""

    def displacement(z: torch.Tensor) -> torch.Tensor:
        a, q_prev = z[..., 0:1], z[..., 1:2]
        return 0.8 * (-0.7 + 1.6 * torch.tanh(3 * a) - q_prev)

    truth = WorldModel(
        finger_graph("state", JOINT),
        {
            DQ: FunctionMechanism(displacement, 2, 1, sigma=0.05),
            Q: LinearMechanism.from_coefficients([[1.0, 1.0]], sigma=0.01),
        },
    )
    truth.set_root_prior(Q_PREV, -1.0, 0.8)
    return truth


def _errors(model: WorldModel, test: dict[str, torch.Tensor]) -> dict[str, float]:
    with torch.no_grad():
        pred = model.predict({ACT: test[ACT], Q_PREV: test[Q_PREV]})
    q_err = pred[Q] - test[Q]
    return {
        "dq_mse": float(((pred[DQ] - test[DQ]) ** 2).mean()),
        "q_mse": float((q_err**2).mean()),
        "q_mae": float(q_err.abs().mean()),
    }


def _outcomes(truth: WorldModel, state: dict[str, torch.Tensor], actions: torch.Tensor) -> torch.Tensor:
    with torch.no_grad():
        return truth.predict({**state, ACT: actions})[Q]


def _targets(prediction: dict[str, Any], action: dict[str, Any], curiosity: dict[str, float]) -> list[Target]:
    return [
        Target(
            "q_mse_ratio",
            prediction["state"]["q_mse"] / prediction["thesis"]["q_mse"],
            0.2,
            "<",
            "q MSE of the state graph / q MSE of the thesis graph",
            Precondition.nonzero(prediction["thesis"]["q_mse"], "the thesis graph's q MSE"),
        ),
        Target(
            "realized_mae_state",
            action["state"]["mae_real"],
            0.05,
            "<=",
            "true-SCM error of the actions inferred with the state graph, rad",
        ),
        Target(
            "curiosity_entropy_gain",
            curiosity["curiosity_entropy_real"] - curiosity["random_entropy_real"],
            0.0,
            ">=",
            "entropy of curiosity-conditioned outcomes minus that of random actions",
        ),
    ]


@register(
    "spring",
    config=Config,
    quick=Config(transitions=4000, schedule=FitSchedule(epochs=15, batch_size=512), targets=32),
    tiny=Config(transitions=400, schedule=FitSchedule(epochs=2, batch_size=128), targets=8),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Fit both finger graphs to a known spring SCM; judge prediction, action inference and curiosity by the truth."""
    gen = torch.Generator().manual_seed(config.seed)
    truth = spring_finger()
    with torch.no_grad():
        data = truth.sample(config.transitions, gen)
    n_train = int(0.8 * config.transitions)
    train = {k: v[:n_train] for k, v in data.items()}
    test = {k: v[n_train:] for k, v in data.items()}
    k = min(config.targets, len(test[Q]))
    state, target = {Q_PREV: test[Q_PREV][:k]}, test[Q][:k]
    low, high = FINGER_ACTION_RANGE
    random_a = low + (high - low) * torch.rand(k, 1, generator=gen)
    reached_random = _outcomes(truth, state, random_a)

    models, fits, prediction, action = {}, {}, {}, {}
    for variant in ("thesis", "state"):
        model = WorldModel(finger_graph(variant, JOINT), seed=config.seed)
        fits[variant] = fit(
            model,
            train,
            schedule=config.schedule,
            seed=config.seed,
            progress_bar=progress_bar,
        )
        models[variant] = model
        prediction[variant] = _errors(model, test)
        res = infer_action(
            model, state, {Q: target}, num_steps=200, options=ActionOptions(lr=0.05), seed=config.seed
        )
        real = _outcomes(truth, state, res.actions[ACT])
        err_real = (real - target).abs()
        action[variant] = {
            "mae_model": float((res.predicted[Q] - target).abs().mean()),
            "mae_real": float(err_real.mean()),
            "within_005_real": float((err_real < 0.05).float().mean()),
            "random_mae_real": float((reached_random - target).abs().mean()),
        }
        if variant == "state":
            scatter = (target, res.predicted[Q], real, reached_random)
    persist = test[Q] - test[Q_PREV]
    prediction["persistence"] = {"q_mse": float((persist**2).mean()), "q_mae": float(persist.abs().mean())}

    cur = CuriositySampler(Q_RANGE[0], Q_RANGE[1], bins=20, alpha=0.5).fit(train[Q].numpy())
    targets_cur = cur.sample(np.random.default_rng(config.seed), state[Q_PREV].numpy()[:, 0])
    res = infer_action(
        models["state"], state, {Q: torch.tensor(targets_cur[:, None], dtype=torch.float32)}, seed=config.seed
    )
    reached = _outcomes(truth, state, res.actions[ACT]).numpy()
    curiosity = {
        "training_entropy": cur.normalized_entropy(),
        "target_entropy": normalized_entropy(targets_cur, *Q_RANGE, 20),
        "curiosity_occupancy_real": occupancy(reached, *Q_RANGE, 20),
        "curiosity_entropy_real": normalized_entropy(reached, *Q_RANGE, 20),
        "random_occupancy_real": occupancy(reached_random.numpy(), *Q_RANGE, 20),
        "random_entropy_real": normalized_entropy(reached_random.numpy(), *Q_RANGE, 20),
    }
    figures: dict[str, Figure] = {f"fit_{g}": f.plot() for g, f in fits.items()}
    figures.update({f"graph_{g}": m.graph.plot() for g, m in models.items()})
    figures["action_inference"] = _scatter(*scatter)
    figures["curiosity"] = cur.plot(current=float(state[Q_PREV][0, 0]))
    return Report(
        title="World model of a known spring finger: prediction, action inference, curiosity",
        metrics={"prediction": prediction, "action": action, "curiosity": curiosity},
        tables=_tables(prediction, action, curiosity),
        targets=_targets(prediction, action, curiosity),
        notes=[
            f"{config.transitions} samples of the true SCM (80:20 split); Alg. 4.2: Adam 200 steps, lr 0.05, "
            "midpoint start; curiosity: 20 bins, alpha 0.5, sigma = range / 10."
        ],
        figures=figures,
    )


def _tables(prediction: dict[str, Any], action: dict[str, Any], curiosity: dict[str, float]) -> list[Table]:
    pred_rows = [(g, m.get("dq_mse"), m["q_mse"], m["q_mae"]) for g, m in prediction.items()]
    act_rows = [
        (g, m["mae_model"], m["mae_real"], m["within_005_real"], m["random_mae_real"])
        for g, m in action.items()
    ]
    cur_rows = [(k.replace("_", " "), v) for k, v in curiosity.items()]
    return [
        Table("One-step prediction on the test split", ("graph", "dq MSE", "q MSE", "q MAE"), pred_rows),
        Table(
            "Action inference for test targets (judged by the true SCM)",
            (
                "graph",
                "MAE model [rad]",
                "MAE real [rad]",
                "share within 0.05 rad",
                "random actions MAE [rad]",
            ),
            act_rows,
        ),
        Table("Curiosity targets (Eq. 5.8-5.9)", ("quantity", "value"), cur_rows),
    ]


def _scatter(
    target: torch.Tensor, predicted: torch.Tensor, real: torch.Tensor, random_real: torch.Tensor
) -> Figure:
    """Fig. 5.6-style plot: target vs outcome for inferred and random actions."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.2, 4))
    t = target.numpy().ravel()
    ax.scatter(t, random_real.numpy().ravel(), s=8, alpha=0.6, label="random action (true SCM)")
    ax.scatter(t, predicted.numpy().ravel(), s=8, alpha=0.8, label="inferred action (model)")
    ax.scatter(t, real.numpy().ravel(), s=8, marker="x", alpha=0.8, label="inferred action (true SCM)")
    lim = [min(t.min(), -3), max(t.max(), 0.5)]
    ax.plot(lim, lim, "k--", lw=1)
    ax.set(xlabel="target q [rad]", ylabel="outcome q [rad]")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
