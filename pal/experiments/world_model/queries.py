"""Causal queries on the analytic chain X -> Y -> Z, checked against their closed forms.

The SCM is ``Y = 2 X + U_y``, ``Z = -1.5 Y + U_z``, ``X, U_y, U_z ~ N(0, 1)``. With every
variable observed, counterfactuals are exact (abduction u = x - f(pa)); with Y latent, the
posterior given (X, Z) is Gaussian:

    U_y | X = 1, Z = -2  ~  N(-0.4615, 0.3077)     (Z - E[Z | X] = -1.5 U_y + U_z)

so under do(X = 0) Y_cf = U_y and Z_cf = -1.5 U_y + U_z = 1 for every posterior draw (U_z =
1 + 1.5 U_y). State inference: E[X | Z = -3] = Cov(X, Z) / Var(Z) * (-3) = 9 / 12.25 = 0.7347.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from inference import counterfactual, infer_state
from models import LinearMechanism, WorldModel, chain_graph
from pal.checks import check_int
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target

__all__ = ["CLOSED_FORM", "Config", "chain", "run"]

#: Closed-form answers (see the module docstring).
CLOSED_FORM = {
    "cf_y_do_x0": 0.5,
    "cf_z_do_x0": 0.0,
    "cf_z_do_y0": 0.75,
    "posterior_u_mean": -6.0 / 13.0,
    "posterior_u_var": 4.0 / 13.0,
    "cf_z_latent_do_x0": 1.0,
    "cf_y_latent_q05": -6.0 / 13.0 - 1.6448536 * math.sqrt(4.0 / 13.0),
    "cf_y_latent_q95": -6.0 / 13.0 + 1.6448536 * math.sqrt(4.0 / 13.0),
    "e_x_given_z": 9.0 / 12.25,
}


@dataclass(frozen=True)
class Config:
    """Sample sizes of the queries with a latent variable.

    Attributes:
        seed: seeds state inference and the posterior samples.
        num_samples: posterior draws of the counterfactual with Y latent.
        tolerance: largest accepted |ours - closed form| of the sampled answers.
    """

    seed: int = 0
    num_samples: int = 2000
    tolerance: float = 0.05

    def __post_init__(self) -> None:
        check_int("num_samples", self.num_samples, minimum=10)


def chain() -> WorldModel:
    """The chain SCM of the module docstring."""
    return WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients([[2.0]]), "z": LinearMechanism.from_coefficients([[-1.5]])},
    )


def answers(config: Config) -> dict[str, float]:
    """Our answers to the queries of :data:`CLOSED_FORM`, same keys."""
    model = chain()
    factual = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-3.0]])}
    exact = counterfactual(model, factual, [{"x": 0.0}, {"y": 0.0}])
    partial = {"x": torch.tensor([[1.0]]), "z": torch.tensor([[-2.0]])}
    latent = counterfactual(model, partial, {"x": 0.0}, num_samples=config.num_samples, seed=config.seed)
    lo, hi = latent.interval("y", 0.9)
    cond = infer_state(model, {"z": torch.tensor([[-3.0]])}, seed=config.seed)
    return {
        "cf_y_do_x0": exact.mean["y"][0].item(),
        "cf_z_do_x0": exact.mean["z"][0].item(),
        "cf_z_do_y0": exact.mean["z"][1].item(),
        "posterior_u_mean": latent.posterior.mean["y"].item() - 2.0,
        "posterior_u_var": latent.posterior.sd["y"].item() ** 2,
        "cf_z_latent_do_x0": latent.mean["z"].mean().item(),
        "cf_y_latent_q05": lo.item(),
        "cf_y_latent_q95": hi.item(),
        "e_x_given_z": cond.mean["x"].item(),
    }


_LABELS = {
    "cf_y_do_x0": "Y_cf under do(X=0), all observed",
    "cf_z_do_x0": "Z_cf under do(X=0), all observed",
    "cf_z_do_y0": "Z_cf under do(Y=0), all observed",
    "posterior_u_mean": "posterior mean of U_y, Y latent",
    "posterior_u_var": "posterior variance of U_y, Y latent",
    "cf_z_latent_do_x0": "Z_cf under do(X=0), Y latent",
    "cf_y_latent_q05": "5 % quantile of Y_cf, Y latent",
    "cf_y_latent_q95": "95 % quantile of Y_cf, Y latent",
    "e_x_given_z": "E[X | Z = -3] by state inference",
}
_EXACT = ("cf_y_do_x0", "cf_z_do_x0", "cf_z_do_y0")


@register("queries", config=Config, quick=Config(), tiny=Config(num_samples=200, tolerance=0.2))
def run(config: Config, progress_bar: bool = False) -> Report:
    """Counterfactual and state queries on X -> Y -> Z against their closed forms."""
    ours = answers(config)
    errors = {k: abs(ours[k] - CLOSED_FORM[k]) for k in CLOSED_FORM}
    rows: list[tuple[Any, ...]] = [(_LABELS[k], ours[k], CLOSED_FORM[k], errors[k]) for k in CLOSED_FORM]
    sampled = [k for k in CLOSED_FORM if k not in _EXACT]
    return Report(
        title="Causal queries on X -> Y -> Z against closed forms",
        metrics={"answers": ours, "closed_form": CLOSED_FORM, "abs_error": errors},
        tables=[Table("Answers", ("query", "pal", "closed form", "|error|"), rows)],
        targets=[
            Target(
                "exact_counterfactual_error",
                max(errors[k] for k in _EXACT),
                1e-5,
                "<=",
                "largest |error| of the exact (all observed) counterfactuals",
            ),
            Target(
                "sampled_query_error",
                max(errors[k] for k in sampled),
                config.tolerance,
                "<=",
                "largest |error| of the posterior-based answers",
            ),
        ],
        notes=["Y = 2X + U_y, Z = -1.5Y + U_z, all noise N(0, 1); factual (X, Y, Z) = (1, 2.5, -3)."],
    )
