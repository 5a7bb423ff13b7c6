"""``pal demo``: a short end-to-end run of the world model and its queries.

1. Causal queries on the analytic chain X -> Y -> Z, checked against closed forms.
2. A finger-like world model learnt from transitions of a known nonlinear SCM (a
   spring pulls the joint towards an action-dependent equilibrium, so the displacement
   depends on the previous angle): the thesis graph (Fig. 5.5) against the graph with
   q_prev -> dq, action inference for 128 targets, and curiosity targets.
3. A short B1/B2 on the MuJoCo finger: uniform motor babbling, both graphs fitted, and the
   inferred actions executed in the simulator from the recorded states
   (:mod:`pal.experiments.b1`, :mod:`pal.experiments.b2` at small sizes).

``run`` yields the report line by line and writes figures and a JSON summary.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from inference import (
    CuriositySampler,
    counterfactual,
    fit,
    infer_action,
    infer_state,
    normalized_entropy,
    occupancy,
)
from models import FunctionMechanism, LinearMechanism, WorldModel, chain_graph, finger_graph, save
from models.presets import FINGER_ACTION_RANGE
from pal.experiments import b1, b2
from pal.experiments.closed_loop import loop_demo_lines
from pal.experiments.output import save_figure, write_json
from pal.experiments.perception_demo import perception_demo_lines
from pal.experiments.wm_setup import prepare

__all__ = ["Config", "run", "spring_finger"]

log = logging.getLogger(__name__)

JOINT = "finger"
Q_RANGE = (-2.79, 0.14)


@dataclass(frozen=True)
class Config:
    """Sizes of the demo; the defaults take about a minute on 2 cores.

    ``mujoco_*`` size the B1/B2 run on the MuJoCo finger: babbling steps, training epochs
    (batch ``batch_size``) and action-inference targets. ``quick_perception`` renders the
    tabletop recordings at 320x240 and 6 frames/s instead of 640x480 and 15 frames/s, and
    runs the closed loop with fewer training epochs.
    """

    out_dir: str = "pal-demo"
    transitions: int = 20000
    epochs: int = 60
    batch_size: int = 512
    targets: int = 128
    seed: int = 0
    mujoco_steps: int = 20000
    mujoco_epochs: int = 60
    mujoco_targets: int = 128
    quick_perception: bool = False

    @classmethod
    def quick(cls) -> Config:
        return cls(
            transitions=4000,
            epochs=15,
            targets=32,
            mujoco_steps=3000,
            mujoco_epochs=15,
            mujoco_targets=16,
            quick_perception=True,
        )


def spring_finger() -> WorldModel:
    """Ground-truth SCM over the finger graph with q_prev -> dq (state variant).

    dq = 0.8 * (q_eq(a) - q_prev) + 0.05 U,   q_eq(a) = -0.7 + 1.6 tanh(3 a)
    q  = q_prev + dq + 0.01 U
    """

    def displacement(z: torch.Tensor) -> torch.Tensor:
        a, q_prev = z[..., 0:1], z[..., 1:2]
        return 0.8 * (-0.7 + 1.6 * torch.tanh(3 * a) - q_prev)

    g = finger_graph("state", JOINT)
    truth = WorldModel(
        g,
        {
            f"dq.{JOINT}": FunctionMechanism(displacement, 2, 1, sigma=0.05),
            f"q.{JOINT}": LinearMechanism.from_coefficients([[1.0, 1.0]], sigma=0.01),
        },
    )
    truth.set_root_prior(f"q_prev.{JOINT}", -1.0, 0.8)
    return truth


def _chain_queries() -> Iterator[str]:
    chain = WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients([[2.0]]), "z": LinearMechanism.from_coefficients([[-1.5]])},
    )
    factual = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-3.0]])}
    r = counterfactual(chain, factual, [{"x": 0.0}, {"y": 0.0}])
    yield "1. Causal queries on X -> Y -> Z with Y = 2X + U_y, Z = -1.5Y + U_z (closed forms in brackets)"
    yield f"   factual (X, Y, Z) = (1, 2.5, -3), do(X=0): Y_cf = {r.mean['y'][0].item():.4f} [0.5], Z_cf = {r.mean['z'][0].item():.4f} [0.0]"
    yield f"   factual (X, Y, Z) = (1, 2.5, -3), do(Y=0): Z_cf = {r.mean['z'][1].item():.4f} [0.75]"
    partial = {"x": torch.tensor([[1.0]]), "z": torch.tensor([[-2.0]])}
    r = counterfactual(chain, partial, {"x": 0.0}, num_samples=2000)
    post = r.posterior
    u_mean = post.mean["y"].item() - 2.0
    u_var = post.sd["y"].item() ** 2
    yield (
        f"   Y latent, X = 1, Z = -2: posterior U_y ~ N({u_mean:.4f}, {u_var:.4f}) [N(-0.4615, 0.3077)], "
        f"do(X=0): Z_cf = {r.mean['z'].mean().item():.4f} [1.0]"
    )
    lo, hi = r.interval("y", 0.9)
    yield f"   90% interval of Y_cf: [{lo.item():.3f}, {hi.item():.3f}] [exact: -0.4615 +- 1.645 * 0.5547 = [-1.374, 0.451]]"
    cond = infer_state(chain, {"z": torch.tensor([[-3.0]])})
    # Z = -3X - 1.5 U_y + U_z: Var Z = 12.25, Cov(X, Z) = -3, so E[X | Z = -3] = 9 / 12.25
    yield f"   state inference, Z = -3 observed: E[X | Z] = {cond.mean['x'].item():.4f} [0.7347]"


def run(config: Config, progress_bar: bool = False) -> Iterator[str]:
    """Run the demo; yields report lines. Writes PNG figures and ``demo.json`` to ``config.out_dir``."""
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary: dict[str, object] = {"config": asdict(config)}
    yield "pal demo"
    yield ""
    yield from _chain_queries()
    yield ""

    gen = torch.Generator().manual_seed(config.seed)
    truth = spring_finger()
    n = config.transitions
    with torch.no_grad():
        data = truth.sample(n, gen)
    n_train = int(0.8 * n)
    train = {k: v[:n_train] for k, v in data.items()}
    test = {k: v[n_train:] for k, v in data.items()}
    yield f"2. Finger-like world model learnt from {n} transitions of a known spring SCM (80:20 split)"
    header = f"   {'graph':<8}{'dq MSE':>10}{'q MSE':>10}{'q MAE':>10}"
    yield header
    models: dict[str, WorldModel] = {}
    b1: dict[str, dict[str, float]] = {}
    for variant in ("thesis", "state"):
        torch.manual_seed(config.seed)
        model = WorldModel(finger_graph(variant, JOINT))
        result = fit(
            model,
            train,
            epochs=config.epochs,
            batch_size=config.batch_size,
            lr=0.01,
            seed=config.seed,
            progress_bar=progress_bar,
        )
        save_figure(result.plot(), out / f"fit_{variant}.png")
        save_figure(model.graph.plot(), out / f"graph_{variant}.png")
        with torch.no_grad():
            pred = model.predict(
                {f"act.{JOINT}": test[f"act.{JOINT}"], f"q_prev.{JOINT}": test[f"q_prev.{JOINT}"]}
            )
        dq_mse = float(((pred[f"dq.{JOINT}"] - test[f"dq.{JOINT}"]) ** 2).mean())
        q_err = pred[f"q.{JOINT}"] - test[f"q.{JOINT}"]
        b1[variant] = {
            "dq_mse": dq_mse,
            "q_mse": float((q_err**2).mean()),
            "q_mae": float(q_err.abs().mean()),
        }
        models[variant] = model
        yield f"   {variant:<8}{dq_mse:>10.4f}{b1[variant]['q_mse']:>10.4f}{b1[variant]['q_mae']:>10.4f}"
    persist = test[f"q.{JOINT}"] - test[f"q_prev.{JOINT}"]
    b1["persistence"] = {"q_mse": float((persist**2).mean()), "q_mae": float(persist.abs().mean())}
    yield f"   {'persist.':<8}{'':>10}{b1['persistence']['q_mse']:>10.4f}{b1['persistence']['q_mae']:>10.4f}"
    summary["b1"] = b1
    path = save(
        models["state"],
        out / "world_model_state.npz",
        provenance={"seed": config.seed, "config": asdict(config)},
    )
    yield f"   saved the state-graph model to {path}"
    yield ""

    k = min(config.targets, len(test[f"q.{JOINT}"]))
    state = {f"q_prev.{JOINT}": test[f"q_prev.{JOINT}"][:k]}
    target = test[f"q.{JOINT}"][:k]
    yield f"3. Action inference (Alg. 4.2) for {k} test targets: Adam 200 steps, lr 0.05, midpoint start"
    b2: dict[str, dict[str, float]] = {}
    low, high = FINGER_ACTION_RANGE
    random_a = low + (high - low) * torch.rand(k, 1, generator=gen)
    for variant, model in models.items():
        res = infer_action(
            model, state, {f"q.{JOINT}": target}, steps=200, lr=0.05, progress_bar=progress_bar
        )
        with torch.no_grad():
            real = truth.predict({**state, f"act.{JOINT}": res.actions[f"act.{JOINT}"]})[f"q.{JOINT}"]
            real_random = truth.predict({**state, f"act.{JOINT}": random_a})[f"q.{JOINT}"]
        err_model = (res.predicted[f"q.{JOINT}"] - target).abs()
        err_real = (real - target).abs()
        b2[variant] = {
            "mae_model": float(err_model.mean()),
            "mae_real": float(err_real.mean()),
            "within_005_real": float((err_real < 0.05).float().mean()),
            "random_mae_real": float((real_random - target).abs().mean()),
        }
        yield (
            f"   {variant:<8} model MAE {b2[variant]['mae_model']:.3f} rad, realised MAE {b2[variant]['mae_real']:.3f} rad, "
            f"{100 * b2[variant]['within_005_real']:.1f}% within 0.05 rad (random actions: {b2[variant]['random_mae_real']:.3f} rad)"
        )
        if variant == "state":
            save_figure(
                _scatter(target, res.predicted[f"q.{JOINT}"], real, real_random), out / "action_inference.png"
            )
    summary["b2"] = b2
    yield ""

    yield "4. Curiosity targets (Eq. 5.8-5.9: 20 bins, alpha 0.5, sigma = range / 10)"
    cur = CuriositySampler(Q_RANGE[0], Q_RANGE[1], bins=20, alpha=0.5).fit(train[f"q.{JOINT}"].numpy())
    rng = np.random.default_rng(config.seed)
    targets_cur = cur.sample(rng, state[f"q_prev.{JOINT}"].numpy()[:, 0])
    res = infer_action(
        models["state"], state, {f"q.{JOINT}": torch.tensor(targets_cur[:, None], dtype=torch.float32)}
    )
    with torch.no_grad():
        reached = truth.predict({**state, f"act.{JOINT}": res.actions[f"act.{JOINT}"]})[f"q.{JOINT}"].numpy()
        reached_random = truth.predict({**state, f"act.{JOINT}": random_a})[f"q.{JOINT}"].numpy()
    b3 = {
        "training_entropy": cur.normalized_entropy(),
        "target_entropy": normalized_entropy(targets_cur, *Q_RANGE, 20),
        "curiosity_occupancy_real": occupancy(reached, *Q_RANGE, 20),
        "curiosity_entropy_real": normalized_entropy(reached, *Q_RANGE, 20),
        "random_occupancy_real": occupancy(reached_random, *Q_RANGE, 20),
        "random_entropy_real": normalized_entropy(reached_random, *Q_RANGE, 20),
    }
    summary["b3"] = b3
    yield f"   training data: entropy {b3['training_entropy']:.3f}; curiosity targets: entropy {b3['target_entropy']:.3f}"
    yield (
        f"   realised outcomes: curiosity-conditioned occupancy {b3['curiosity_occupancy_real']:.2f}, entropy "
        f"{b3['curiosity_entropy_real']:.3f}; random actions occupancy {b3['random_occupancy_real']:.2f}, "
        f"entropy {b3['random_entropy_real']:.3f}"
    )
    save_figure(cur.plot(current=float(state[f"q_prev.{JOINT}"][0, 0])), out / "curiosity.png")
    yield ""
    yield from _mujoco_finger(config, out, summary, progress_bar)
    yield ""
    lines = perception_demo_lines(out, quick=config.quick_perception)
    yield "6. " + lines[0]
    yield from lines[1:]
    yield ""
    lines = loop_demo_lines(out, quick=config.quick_perception)
    yield "7. " + lines[0]
    yield from lines[1:]
    for section in ("b1", "b2", "b3"):
        for key, value in dict(summary[section]).items():  # type: ignore[arg-type]
            if isinstance(value, float) and not math.isfinite(value):
                raise FloatingPointError(f"demo produced a non-finite {section}.{key}")
    write_json(out / "demo.json", summary)
    yield ""
    yield f"Figures and demo.json written to {out}"


def _mujoco_finger(
    config: Config, out: Path, summary: dict[str, object], progress_bar: bool
) -> Iterator[str]:
    """Section 5: B1 and B2 on the MuJoCo finger at small sizes; adds ``summary["mujoco"]``."""
    cfg = b2.Config(
        steps=config.mujoco_steps,
        seed=config.seed,
        cache=False,
        epochs=config.mujoco_epochs,
        batch_size=config.batch_size,
        targets=config.mujoco_targets,
    )
    yield (
        f"5. MuJoCo finger: {cfg.steps} uniform babbling transitions (80:20), both graphs, "
        f"{cfg.epochs} epochs (B1, Table 5.7)"
    )
    prep = prepare(cfg, progress_bar=progress_bar)
    metrics = b1.evaluate(prep)
    yield f"   {'graph':<12}{'dq MSE':>10}{'q MSE':>10}{'q MAE':>10}"
    for graph in cfg.graphs:
        m = metrics[graph]
        yield f"   {graph:<12}{m['dq_mse']:>10.4f}{m['q_mse']:>10.4f}{m['q_mae']:>10.4f}"
    p = metrics["persistence"]
    yield f"   {'persistence':<12}{'':>10}{p['q_mse']:>10.4f}{p['q_mae']:>10.4f}"
    b2_metrics, b2_extra, points = b2.evaluate(prep, cfg)
    yield (
        f"   B2: {len(points['target'])} test targets, actions inferred from the midpoint (Alg. 4.2) and "
        "executed from the recorded simulator states"
    )
    for graph in cfg.graphs:
        inf, rnd = b2_metrics[graph]["inferred"], b2_metrics[graph]["random"]
        yield (
            f"   {graph:<8} MAE model {inf['mae_model']:.3f} rad, realized {inf['mae_real']:.3f} rad, "
            f"{100 * inf['within_005_real']:.1f}% within 0.05 rad realized (random actions: {rnd['mae_real']:.3f} rad)"
        )
    restarts, _, _ = b2.evaluate(prep, replace(cfg, graphs=("state",), action_starts=3))
    inf = restarts["state"]["inferred"]
    yield (
        f"   state, Alg. 4.2 restarted from 3 points of X_a: realized MAE {inf['mae_real']:.3f} rad, "
        f"{100 * inf['within_005_real']:.1f}% within 0.05 rad (the midpoint start can stall on the plateau "
        "at the flexion limit)"
    )
    b2_result = b2.Result(b2_metrics, b2_extra, prep.info(), cfg, points)
    for name, fig in b2_result.figures().items():
        save_figure(fig, out / f"mujoco_b2_{name}.png")
    summary["mujoco"] = {"b1": metrics, "b2": b2_metrics}


def _scatter(target: torch.Tensor, predicted: torch.Tensor, real: torch.Tensor, random_real: torch.Tensor):
    """Fig. 5.6-style plot: target vs outcome for inferred and random actions."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.2, 4))
    t = target.numpy().ravel()
    ax.scatter(t, random_real.numpy().ravel(), s=8, alpha=0.6, label="random action (realised)")
    ax.scatter(t, predicted.numpy().ravel(), s=8, alpha=0.8, label="inferred action (model)")
    ax.scatter(t, real.numpy().ravel(), s=8, marker="x", alpha=0.8, label="inferred action (realised)")
    lim = [min(t.min(), -3), max(t.max(), 0.5)]
    ax.plot(lim, lim, "k--", lw=1)
    ax.set_xlabel("target q [rad]")
    ax.set_ylabel("outcome q [rad]")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
