"""Fitting a gated site: the on branch on the rows where the switch is on, the off branch at its floor.

Synthetic contact data: ``rel ~ N(0, 1)``, ``contact ~ Bernoulli(sigmoid(-2 + 0.8 rel))`` (about
15 % on), ``dpos = 0`` exactly when off and ``0.5 tanh(rel) + 0.1 + (0.02 + 0.05 |rel|) eps`` when on.
"""

import logging

import pytest
import torch

from inference import FitSchedule, fit
from models import (
    CausalGraph,
    EnsembleMechanism,
    GatedMechanism,
    HeteroscedasticMechanism,
    MLPMechanism,
    Variable,
    WorldModel,
)

FLOOR = 1e-4
Z90 = 1.6449
SCHEDULE = FitSchedule(epochs=40, batch_size=512, lr=0.01, validation=0.2, patience=10)
log = logging.getLogger(__name__)


def contact_graph():
    return CausalGraph(
        [Variable(n, "observed") for n in ("rel", "contact", "dpos")],
        [("rel", "contact"), ("rel", "dpos"), ("contact", "dpos")],
    )


def contact_data(n, seed):
    g = torch.Generator().manual_seed(seed)
    rel = torch.randn(n, 1, generator=g)
    contact = (torch.rand(n, 1, generator=g) < torch.sigmoid(-2.0 + 0.8 * rel)).float()
    sd = 0.02 + 0.05 * rel.abs()
    dpos = contact * (0.5 * torch.tanh(rel) + 0.1 + sd * torch.randn(n, 1, generator=g))
    return {"rel": rel, "contact": contact, "dpos": dpos}


def _scores(model, test):
    """(predicted sd on off rows, 90 % coverage of on rows) on held-out data."""
    vals = {"rel": test["rel"], "contact": test["contact"]}
    loc, sd = model.predict(vals)["dpos"], model.predict_scale(vals)["dpos"]
    on = test["contact"][:, 0] == 1
    z = ((test["dpos"] - loc) / sd)[:, 0]
    return sd[~on], float((z[on].abs() <= Z90).float().mean())


def test_the_gated_site_keeps_its_floor_off_and_covers_the_pushes():
    train, test = contact_data(6000, 1), contact_data(4000, 101)
    assert 0.1 < float(train["contact"].mean()) < 0.2
    gated = WorldModel(
        contact_graph(),
        {"dpos": GatedMechanism("contact", HeteroscedasticMechanism(2, 1, hidden=(16, 16), seed=1), FLOOR)},
        discrete={"contact": 2},
        seed=1,
    )
    result = fit(gated, train, schedule=SCHEDULE, seed=1)
    assert result.sigma_rule["dpos"] == "recalibrated"
    off_sd, coverage = _scores(gated, test)
    assert torch.equal(off_sd, torch.full_like(off_sd, FLOOR))
    assert 0.85 <= coverage <= 0.95, coverage
    # the smooth heteroscedastic site on the same data, for comparison
    smooth = WorldModel(
        contact_graph(),
        {"dpos": HeteroscedasticMechanism(2, 1, hidden=(16, 16), seed=1)},
        discrete={"contact": 2},
        seed=1,
    )
    fit(smooth, train, schedule=SCHEDULE, seed=1)
    smooth_off, smooth_coverage = _scores(smooth, test)
    log.info(
        "gated: off sd %.3g, on coverage %.3f; smooth: off sd %.3g-%.3g, on coverage %.3f",
        FLOOR,
        coverage,
        float(smooth_off.min()),
        float(smooth_off.max()),
        smooth_coverage,
    )
    assert abs(coverage - 0.9) < abs(smooth_coverage - 0.9)


def test_the_on_branch_is_normalised_and_its_sigma_set_on_the_on_rows_only():
    train = contact_data(2000, 1)
    model = WorldModel(
        contact_graph(),
        {"dpos": GatedMechanism("contact", MLPMechanism(2, 1, hidden=(8,), seed=0), FLOOR)},
        discrete={"contact": 2},
        seed=0,
    )
    schedule = FitSchedule(epochs=20, batch_size=256, lr=0.01, validation=0.2, patience=5)
    result = fit(model, train, schedule=schedule, seed=0)
    on_branch = model.mechanism("dpos").on
    on = train["contact"][:, 0] == 1
    perm = torch.randperm(2000, generator=torch.Generator().manual_seed(0))
    train_rows = perm[400:][on[perm[400:]]]
    val_rows = perm[:400][on[perm[:400]]]
    assert float(on_branch.out_loc) == pytest.approx(float(train["dpos"][train_rows].mean()), abs=1e-6)
    with torch.no_grad():
        resid = train["dpos"][val_rows] - on_branch(torch.cat([train["rel"], train["contact"]], -1)[val_rows])
    assert float(on_branch.sigma.detach()) == pytest.approx(float(resid.pow(2).mean().sqrt()), rel=1e-5)
    assert result.sigma["dpos"] == pytest.approx((float(on_branch.sigma.detach()),), rel=1e-6)
    assert torch.equal(model.mechanism("dpos").floor, torch.tensor([FLOOR]))


def test_an_ensemble_on_branch_is_bootstrapped_from_the_on_rows_and_recalibrated():
    train = contact_data(2000, 2)
    on = EnsembleMechanism.replicate(lambda g: HeteroscedasticMechanism(2, 1, hidden=(8,), seed=g), 3, 0)
    model = WorldModel(
        contact_graph(), {"dpos": GatedMechanism("contact", on, FLOOR)}, discrete={"contact": 2}, seed=0
    )
    schedule = FitSchedule(epochs=10, batch_size=256, lr=0.01, validation=0.2, patience=5)
    result = fit(model, train, schedule=schedule, seed=0)
    assert result.sigma_rule["dpos"] == "recalibrated"
    assert float(on.log_scale_offset.abs().sum()) > 0
    off_sd, _ = _scores(model, contact_data(500, 3))
    assert torch.equal(off_sd, torch.full_like(off_sd, FLOOR))


def test_a_gated_site_without_on_rows_cannot_be_fitted():
    train = contact_data(200, 4)
    train["contact"] = torch.zeros_like(train["contact"])
    model = WorldModel(
        contact_graph(),
        {"dpos": GatedMechanism("contact", MLPMechanism(2, 1, hidden=(4,), seed=0), FLOOR)},
        discrete={"contact": 2},
        seed=0,
    )
    with pytest.raises(ValueError, match="switch 'contact' is on in none of the"):
        fit(model, train, schedule=FitSchedule(epochs=2, batch_size=64, validation=0.2), seed=0)
