"""Posteriors that keep every mode: the bimodal oracle X -> Y (latent) -> Z = Y^2 + 0.3 U.

The exact posterior of Y per unit is computed here on a fine grid (numpy, independent of the
library); the counterfactual under X := X + 1.5 is Z' = (Y + 0.75)^2 - Y^2 + Z = 1.5 Y + 0.5625 + Z,
so its exact 90 % interval maps from Y's.
"""

import warnings

import numpy as np
import pytest
import torch

from inference import (
    GridOptions,
    ImportanceOptions,
    PoorPosteriorWarning,
    SVIOptions,
    counterfactual,
    infer_state,
)
from models import CausalGraph, FunctionMechanism, LinearMechanism, Variable, WorldModel

A = 0.5
SHIFT = 1.5


def bimodal_model():
    graph = CausalGraph([Variable(n, "observed") for n in "xyz"], [("x", "y"), ("y", "z")])
    return WorldModel(
        graph,
        {
            "y": LinearMechanism.from_coefficients([[A]], 0.0, 1.0),
            "z": FunctionMechanism(lambda y: y**2, 1, 1, sigma=0.3),
        },
    )


def units(n, seed=0):
    gen = torch.Generator().manual_seed(seed)
    x, uy, uz = (torch.randn(n, 1, generator=gen) for _ in range(3))
    y = A * x + uy
    z = y**2 + 0.3 * uz
    truth = (y + A * SHIFT) ** 2 + 0.3 * uz
    return x, z, truth[:, 0].numpy()


def exact(x, z, level=0.9):
    grid = np.linspace(-7, 7, 14001)
    lp = -0.5 * (grid[None] - A * x.numpy()) ** 2 - 0.5 * ((z.numpy() - grid[None] ** 2) / 0.3) ** 2
    w = np.exp(lp - lp.max(1, keepdims=True))
    w /= w.sum(1, keepdims=True)
    cdf = w.cumsum(1)
    lo = grid[(cdf < (1 - level) / 2).sum(1)]
    hi = grid[(cdf < (1 + level) / 2).sum(1)]
    c = z.numpy()[:, 0] + (A * SHIFT) ** 2
    neg = (w * (grid < 0)).sum(1)
    bimodal = (neg > 0.05) & (neg < 0.95)
    return 2 * A * SHIFT * lo + c, 2 * A * SHIFT * hi + c, bimodal, neg


def _intervals(model, x, z, guide, options):
    state = infer_state(model, {"x": x, "z": z}, guide=guide, num_samples=1000, options=options)
    cf = counterfactual(model, {"x": x, "z": z}, {"x": lambda v: v + SHIFT}, posterior=state)
    lo, hi = cf.interval("z", 0.9)
    return state, lo[0, :, 0].numpy(), hi[0, :, 0].numpy()


@pytest.mark.slow
def test_grid_posterior_matches_the_exact_bimodal_oracle_on_1000_units():
    model = bimodal_model()
    x, z, truth = units(1000)
    lo_e, hi_e, bimodal, _ = exact(x, z)
    assert bimodal.sum() > 500  # most units have two modes
    state, lo, hi = _intervals(model, x, z, "grid", GridOptions())
    assert state.diagnostics.ok
    covered = (truth >= lo) & (truth <= hi)
    assert 0.88 <= covered.mean() <= 0.92
    assert 0.88 <= covered[bimodal].mean() <= 0.92
    ratio = (hi - lo) / (hi_e - lo_e)
    assert abs(ratio.mean() - 1) < 0.1 and abs(ratio[bimodal].mean() - 1) < 0.1
    assert np.percentile(np.abs(ratio - 1), 95) < 0.1


def test_counterfactual_uses_the_exact_grid_by_default():
    model = bimodal_model()
    x, z, _ = units(200, seed=1)
    lo_e, hi_e, _, _ = exact(x, z)
    cf = counterfactual(model, {"x": x, "z": z}, {"x": lambda v: v + SHIFT})
    assert cf.posterior.guide == "grid"
    lo, hi = (t[0, :, 0].numpy() for t in cf.interval("z"))
    assert np.median(np.abs((hi - lo) / (hi_e - lo_e) - 1)) < 0.05


def test_importance_sampling_keeps_both_modes():
    model = bimodal_model()
    x, z, _ = units(300, seed=2)
    lo_e, hi_e, bimodal, _ = exact(x, z)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PoorPosteriorWarning)  # a few units have few effective particles
        state, lo, hi = _intervals(model, x, z, "importance", ImportanceOptions(num_particles=10_000))
    ratio = (hi - lo) / (hi_e - lo_e)
    assert abs(ratio[bimodal].mean() - 1) < 0.1
    assert float(state.diagnostics.ess.median()) > 200


def test_the_mean_field_guide_is_flagged_where_it_keeps_one_mode():
    model = bimodal_model()
    x, z, _ = units(40, seed=3)
    _, _, _, neg = exact(x, z)
    with pytest.warns(PoorPosteriorWarning, match="almost no density"):
        state = infer_state(
            model, {"x": x, "z": z}, guide="normal", num_steps=300, num_samples=200, options=SVIOptions()
        )
    flagged = np.zeros(40, bool)
    flagged[list(state.diagnostics.flagged)] = True
    # exact posterior mass on the side of zero that the Gaussian guide does not sit on
    missed = np.where(state.mean["y"][:, 0].numpy() > 0, neg, 1 - neg)
    assert flagged.sum() >= 5
    separated = z[:, 0].numpy() > 1.5  # modes at +-sqrt(z), each 0.3 / (2 sqrt(z)) wide
    assert flagged[(missed > 0.2) & separated].all()  # every unit that loses a real mode is flagged
    assert (missed[flagged] > 0.02).all()  # and no unit whose posterior the guide covers
    assert state.to_dict()["diagnostics"]["ok"] is False


def test_flow_and_full_rank_guides_run_and_report():
    model = bimodal_model()
    x, z, _ = units(5, seed=4)
    for guide in ("flow", "mvn"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PoorPosteriorWarning)
            state = infer_state(model, {"x": x, "z": z}, guide=guide, num_steps=50, num_samples=100)
        assert state.guide == guide and len(state.losses) == 50
        assert state.samples["y"].shape == (100, 5, 1)
        assert state.diagnostics.pareto_k.shape == (5,)


def test_grid_refuses_too_many_latent_components():
    graph = CausalGraph([Variable(n, "observed") for n in "abcd"], [("a", "b"), ("b", "c"), ("c", "d")])
    model = WorldModel(graph, seed=0, kind="linear")
    with pytest.raises(ValueError, match="at most 2 continuous latent components"):
        infer_state(model, {"d": torch.zeros(1, 1)}, guide="grid")
