"""Experiment C3: counterfactual validation against the simulator replayed from the saved state.

The agent babbles; the pushing world model is fitted on the first ``1 - test_fraction`` of the
transitions (perceived object positions, Eq. 4.33). For held-out recorded steps t-1 -> t it asks
"where would the box be had the action been a' ?", for ``query.alternatives`` actions a' per step:
the executed servo targets moved by U(-delta, delta) rad per joint (``query``):

- ``counterfactual``: :func:`inference.counterfactual` on the fully observed transition (actions,
  joint angles, sensed hand, touch, perceived box before and after): abduction of every residual
  (Eq. 4.43, exact), ``do(act = a')``, prediction with the abducted residuals. With the gated
  displacement the contact switch is re-decided under a': its Gumbel noise is drawn from its
  posterior given the sensed contact (:func:`models.discrete.gumbel_posterior`) and the switch
  is the argmax of its logits at a' plus that noise, so an a' that moves the hand away from the
  box turns the switch off and the answer is the off branch (the box stays), and the
  displacement's residual ``u = (x - f_c(pa)) / sigma_c(pa)`` is replayed on the branch the
  switch takes; the answer is the mean over ``query.num_samples`` Gumbel draws;
- ``interventional``: the prediction under ``do(act = a')`` with expected residuals (no abduction;
  with the gated form the mixture mean over the contact switch);
- ``factual``: where the box actually went (the answer "nothing would change").

The ground truth is the simulator restored to the saved MuJoCo state before the step (recorded
from the environment's ``info``) and stepped with every a' of the step in one open-loop batch
(:meth:`pal.sim.pushing.PushingEnv.replay`, ``mujoco.rollout``); MuJoCo is deterministic, so
this is exact. A query counts when the box moves more than
``min_motion`` m in the factual or the counterfactual world (otherwise every answer is trivially
"it stays"). Errors compare displacements over the step (answer minus the perceived position
before it, against the true counterfactual position minus the true one before it), so the
constant offset between the perceived point and the box centre cancels.

Both displacement forms of ``forms`` are fitted (:attr:`pal.agent.config.ModelConfig.displacement`);
the first gives the targets, the others are comparison columns.

Metrics (cm): ``n`` queries and, per form and model (``perceived``: the agent's, fitted on
perceived positions; ``ground_truth_model``: fitted on the true positions), the median and mean
error of each answer, ``cf_over_interventional`` (target for the agent's model: <= 1/4) and
``cf_over_factual`` (target: < 1, better than "nothing would change"). ``perceived`` and
``ground_truth_model`` at the top level are the first form's.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from inference import counterfactual
from models import WorldModel
from pal.agent import Agent, restrict
from pal.agent.config import DISPLACEMENTS
from pal.agent.graph import contact_rule
from pal.agent.history import History
from pal.checks import check_choice, check_float, check_int
from pal.experiments.closed_loop.setup import (
    QUICK_SETUP,
    TINY_SETUP,
    SetupConfig,
    babbled_agent,
    fitted_model,
    split_rows,
    summary,
)
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["ANSWERS", "TARGET_RATIO", "Config", "QueryConfig", "counterfactual_answers", "run"]

log = logging.getLogger(__name__)

ANSWERS = ("cf", "interventional", "factual")
#: The counterfactual error should be at most this fraction of the interventional baseline's.
TARGET_RATIO = 0.25
_MODELS = (
    ("perceived", "perceived", "perceived positions (the agent)"),
    ("ground_truth_model", "truth", "true positions"),
)


@dataclass(frozen=True)
class QueryConfig:
    """Which counterfactuals are asked.

    Attributes:
        count: queries (step, a') to ask.
        alternatives: actions a' per held-out step, replayed in one batch.
        delta: a' moves each executed servo target by U(-delta, delta), rad.
        min_motion: a query counts when the box moves more than this in either world, m.
        num_samples: Gumbel draws of the discrete sites' noise per query (the contact switch).
    """

    count: int = 240
    alternatives: int = 8
    delta: float = 0.3
    min_motion: float = 0.005
    num_samples: int = 200

    def __post_init__(self) -> None:
        check_int("num_samples", self.num_samples)
        check_float("delta", self.delta, 0.0, open_low=True)
        check_float("min_motion", self.min_motion, 0.0)
        check_int("count", self.count)
        check_int("alternatives", self.alternatives)


@dataclass(frozen=True)
class Config:
    """C3 protocol.

    Attributes:
        seed: master seed (babbling, fits, the perturbations).
        setup: babbling and fitting.
        query: the counterfactual questions.
        test_fraction: share of the transitions (the last ones) held out.
        forms: displacement forms fitted and reported; the first gives the targets, the
            others are comparison columns.
    """

    seed: int = 0
    setup: SetupConfig = SetupConfig()
    query: QueryConfig = QueryConfig()
    test_fraction: float = 0.3
    forms: tuple[str, ...] = ("gated", "smooth")

    def __post_init__(self) -> None:
        forms = tuple(check_choice("forms", f, DISPLACEMENTS) for f in self.forms)
        if not forms or len(set(forms)) != len(forms):
            raise ValueError(
                f"forms must name distinct displacement forms of {DISPLACEMENTS}, got {self.forms!r}"
            )
        object.__setattr__(self, "forms", forms)
        check_int("seed", self.seed, minimum=0)
        check_float("test_fraction", self.test_fraction, 0.0, 1.0, open_low=True, open_high=True)


QUICK = Config(setup=QUICK_SETUP, query=QueryConfig(count=16, alternatives=4, min_motion=0.0))
TINY = Config(
    setup=TINY_SETUP,
    query=QueryConfig(count=4, alternatives=2, min_motion=0.0, num_samples=20),
    test_fraction=0.5,
)


def _queries(
    agent: Agent, rows: np.ndarray, config: QueryConfig, seed: int
) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(row, a', true counterfactual box position) for informative held-out steps (module docstring)."""
    env, history = agent.env.unwrapped, agent.history
    rng = np.random.default_rng(np.random.SeedSequence([seed, 73]))
    k = history.objects.index("box")
    act, states = history.array("act"), history.array("state")
    meas_prev, meas, truth_prev, truth = (
        history.array(f) for f in ("meas_prev", "meas", "truth_prev", "truth")
    )
    out: list[tuple[int, np.ndarray, np.ndarray]] = []
    for row in rng.permutation(rows):
        if not (np.isfinite(meas_prev[row, k, 0]) and np.isfinite(meas[row, k, 0])):
            continue
        alts = np.clip(
            act[row] + rng.uniform(-config.delta, config.delta, size=(config.alternatives, act.shape[1])),
            agent.low,
            agent.high,
        )
        true_cf = env.replay(states[row], alts)["box"][:, :2]
        factual = np.linalg.norm(truth[row, k] - truth_prev[row, k])
        for alt, cf in zip(alts, true_cf, strict=True):
            if max(np.linalg.norm(cf - truth_prev[row, k]), factual) > config.min_motion:
                out.append((int(row), alt, cf))
        if len(out) >= config.count:
            break
    return out[: config.count]


def counterfactual_answers(
    model: WorldModel,
    factual: dict[str, torch.Tensor],
    do: dict[str, torch.Tensor],
    site: str,
    *,
    num_samples: int = 200,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """The counterfactual and the interventional answer for ``site`` under ``do``, per unit ``(N, dim)``.

    ``cf``: :func:`inference.counterfactual` of the fully observed ``factual`` (discrete sites'
    Gumbel noise from its posterior, so a switch is re-decided under ``do``; the mean over
    ``num_samples`` draws). ``interventional``: :meth:`models.WorldModel.predict` of the roots
    other than the intervened ones and ``do``, expected residuals.
    """
    cf = counterfactual(model, factual, do, num_samples=num_samples, seed=seed)
    roots = {n: factual[n] for n in model.graph.roots if n not in do}
    return {
        "cf": cf.mean[site][0].double().numpy(),
        "interventional": model.predict({**roots, **do})[site].double().numpy(),
    }


def _answers(
    model: WorldModel,
    history: History,
    queries: list,
    source: str,
    contact: tuple[str, float],
    num_samples: int,
    seed: int,
) -> dict[str, np.ndarray]:
    """Displacement errors (cm) of the three answers for every query; ``contact``: the ``(rule, floor)`` of contact.o."""
    rows = np.array([r for r, _, _ in queries])
    alt = np.stack([a for _, a, _ in queries])
    true_cf = np.stack([t for _, _, t in queries])
    box = restrict(model, ("box",))
    arm, objects = history.columns(source, rows, contact=contact[0], floor=contact[1])
    cols = {**arm, **objects["box"]}
    cols["meas.box"] = cols["pos.box"]
    dtype = box.dtype
    factual = {n: torch.as_tensor(cols[n], dtype=dtype) for n in box.graph.names}
    do = {"act": torch.as_tensor(alt, dtype=dtype)}
    answers = {
        **counterfactual_answers(box, factual, do, "pos.box", num_samples=num_samples, seed=seed),
        "factual": cols["pos.box"],
    }
    prev = cols["pos_prev.box"].astype(np.float64)
    true_disp = true_cf - history.array("truth_prev")[rows, history.objects.index("box")]
    return {a: 100 * np.linalg.norm((answers[a] - prev) - true_disp, axis=1) for a in ANSWERS}


def _block(errors: dict[str, np.ndarray]) -> dict[str, Any]:
    """Median and mean error of each answer, cm, and the ratios of the counterfactual's to the others'."""
    block: dict[str, Any] = {}
    for a in ANSWERS:
        s = summary(errors[a])
        block[f"{a}_err_cm_median"], block[f"{a}_err_cm_mean"] = s["median"], s["mean"]
    cf = block["cf_err_cm_median"]
    for a in ("interventional", "factual"):
        den = block[f"{a}_err_cm_median"]
        block[f"cf_over_{a}"] = cf / den if den else None
    return block


def _targets(block: dict[str, Any], form: str) -> list[Target]:
    """The counterfactual against the interventional answer and against "nothing changes" (the agent's model)."""
    return [
        Target(
            "cf_over_interventional",
            block["cf_over_interventional"],
            TARGET_RATIO,
            "<=",
            f"median counterfactual error / median interventional error, the agent's model ({form} form, "
            "perceived positions)",
            Precondition.nonzero(block["interventional_err_cm_median"], "the median interventional error"),
        ),
        Target(
            "cf_over_factual",
            block["cf_over_factual"],
            1.0,
            "<",
            f'median counterfactual error / median error of "nothing would change", the agent\'s model ({form} form)',
            Precondition.nonzero(
                block["factual_err_cm_median"], 'the median error of "nothing would change"'
            ),
        ),
    ]


@register("c3", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """C3: counterfactual answers about held-out pushes against the simulator replayed with a'."""
    agent = babbled_agent(config.setup, config.seed, progress_bar=progress_bar)
    history = agent.history
    train, test = split_rows(len(history), config.test_fraction)
    queries = _queries(agent, test, config.query, config.seed)
    if not queries:
        agent.env.close()
        raise ValueError(
            "no held-out step moved the box; babble longer (setup.babble_steps) or lower query.min_motion"
        )
    metrics: dict[str, Any] = {
        "n": len(queries),
        "steps": len({r for r, _, _ in queries}),
        "unit": "cm",
        "info": {"train_rows": int(train.size)},
    }
    errors: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    metrics["forms"] = {}
    for form in config.forms:
        m = replace(agent.config.model, displacement=form)
        errors[form], metrics["forms"][form] = {}, {}
        for key, source, _ in _MODELS:
            model, _ = fitted_model(agent, config.setup, config.seed, source, train, displacement=form)
            errors[form][key] = _answers(
                model,
                history,
                queries,
                source,
                contact_rule(agent.spec, m),
                config.query.num_samples,
                config.seed,
            )
            metrics["forms"][form][key] = _block(errors[form][key])
    agent.env.close()
    primary = config.forms[0]
    metrics.update(metrics["forms"][primary])
    metrics["form"] = primary
    rows = [
        [
            form,
            label,
            *[metrics["forms"][form][key][f"{a}_err_cm_median"] for a in ANSWERS],
            metrics["forms"][form][key]["cf_over_interventional"],
            metrics["forms"][form][key]["cf_over_factual"],
        ]
        for form in config.forms
        for key, _, label in _MODELS
    ]
    return Report(
        title="C3: counterfactual answers against the replayed simulator",
        metrics=metrics,
        tables=[
            Table(
                "Median error of the predicted box displacement [cm]",
                [
                    "form",
                    "model fitted on",
                    "counterfactual",
                    "interventional",
                    "factual",
                    "cf / interventional",
                    "cf / factual",
                ],
                rows,
                caption="The thesis has no number for this.",
            )
        ],
        targets=_targets(metrics["perceived"], primary),
        notes=[
            f"{len(queries)} queries on {metrics['steps']} held-out steps where the box moves more than "
            f"{config.query.min_motion} m, with a' = a + U(-{config.query.delta}, {config.query.delta}) rad per joint, "
            f"{config.query.alternatives} per step, replayed in one batch with mujoco.rollout.",
            "Errors compare the predicted box displacement with the simulator replayed from the saved state "
            "with a', cm.",
            f"Targets on the {primary} displacement; {', '.join(config.forms[1:]) or 'no other form'} as comparison.",
        ],
        figures={"errors": _errors_figure({f: e["perceived"] for f, e in errors.items()})},
    )


def _errors_figure(errors: dict[str, dict[str, np.ndarray]]) -> Figure:
    """Box plots of each answer's error, one panel per form (the agent's model)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(errors), figsize=(4.2 * len(errors), 3.4), squeeze=False, sharey=True)
    for ax, (form, e) in zip(axes[0], errors.items(), strict=True):
        ax.boxplot([e[a] for a in ANSWERS], tick_labels=list(ANSWERS), showfliers=False)
        ax.set(ylabel="displacement error, cm", title=f"C3 (agent's model, {form})")
    fig.tight_layout()
    return fig
