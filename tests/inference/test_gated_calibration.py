"""Calibrating a gated site's on branch when its switch is rarely on (``CalibrationOptions``).

The synthetic contact data of ``test_gated_fit`` (about 15 % on rows, the others exactly 0,
a heteroscedastic on branch ``sd = 0.02 + 0.05 |rel|``) at n = 1000: the validation share (10 %)
holds ~15 on rows. Coverage is that of the site's Normal 90 % interval on 4000 held-out rows
(~600 on rows: a binomial sd of 0.012 around the true coverage).
"""

import logging
import math
from dataclasses import replace

import pytest
import torch

from inference import CalibrationOptions, FitSchedule, fit
from inference.fit_sigma import scale_factor
from models import (
    EnsembleMechanism,
    GatedMechanism,
    HeteroscedasticMechanism,
    MLPMechanism,
    WorldModel,
    load,
    save,
)
from tests.inference.test_gated_fit import FLOOR, Z90, contact_data, contact_graph

CONFORMAL = CalibrationOptions(rule="conformal", level=0.9, folds=5)
#: A small schedule: 900 training rows, 4 steps per epoch, early stopping on the validation on rows.
SCHEDULE = FitSchedule(epochs=30, batch_size=256, lr=0.01, validation=0.1, patience=8, calibration=CONFORMAL)
TEST = contact_data(4000, 101)


def gated_model(seed, on=None):
    on = on if on is not None else HeteroscedasticMechanism(2, 1, hidden=(16, 16), seed=seed)
    return WorldModel(
        contact_graph(), {"dpos": GatedMechanism("contact", on, FLOOR)}, discrete={"contact": 2}, seed=seed
    )


def on_coverage(model, data=TEST):
    """The share of on rows of ``data`` inside the site's 90 % Normal interval, given the switch."""
    values = {"rel": data["rel"], "contact": data["contact"]}
    with torch.no_grad():
        loc, sd = model.predict(values)["dpos"], model.predict_scale(values)["dpos"]
    on = data["contact"][:, 0] == 1
    return float((((data["dpos"] - loc) / sd)[on].abs() <= Z90).double().mean())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cross_fitted_conformal_calibration_covers_held_out_pushes(seed):
    model = gated_model(seed)
    result = fit(model, contact_data(1000, seed), schedule=SCHEDULE, seed=seed)
    assert result.sigma_rule["dpos"] == "recalibrated conformal out-of-fold"
    assert result.calibration_seconds > 0
    coverage = on_coverage(model)
    assert 0.85 <= coverage <= 0.95, coverage


def test_the_returned_on_branch_is_trained_as_without_folds_and_the_off_branch_stays_exact():
    data = contact_data(1000, 3)
    models = {}
    for folds in (None, 5):
        models[folds] = gated_model(3)
        fit(
            models[folds],
            data,
            schedule=replace(SCHEDULE, calibration=CalibrationOptions("conformal", 0.9, folds)),
            seed=3,
        )
    values = {"rel": TEST["rel"], "contact": TEST["contact"]}
    with torch.no_grad():
        (loc0, sd0), (loc5, sd5) = (
            (m.predict(values)["dpos"], m.predict_scale(values)["dpos"]) for m in models.values()
        )
    on = TEST["contact"][:, 0] == 1
    assert torch.equal(loc0, loc5)  # the same weights: only the scale's calibration factor differs
    ratio = sd5[on] / sd0[on]
    assert float(ratio.max() - ratio.min()) < 1e-5 * float(ratio.mean())
    assert float((ratio.mean() - 1).abs()) > 1e-3
    assert torch.equal(loc5[~on], torch.zeros_like(loc5[~on]))
    assert torch.equal(sd5[~on], torch.full_like(sd5[~on], FLOOR))
    assert torch.equal(models[5].mechanism("dpos").floor, torch.tensor([FLOOR]))


def test_save_and_load_keep_the_calibration(tmp_path):
    model = gated_model(4)
    fit(model, contact_data(600, 4), schedule=SCHEDULE, seed=4)
    path = save(model, tmp_path / "gated.npz")
    again = load(path)
    values = {"rel": TEST["rel"][:200], "contact": TEST["contact"][:200]}
    with torch.no_grad():
        assert torch.equal(model.predict_scale(values)["dpos"], again.predict_scale(values)["dpos"])
        assert torch.equal(model.predict(values)["dpos"], again.predict(values)["dpos"])


def test_a_homoscedastic_on_branch_takes_its_sigma_from_the_out_of_fold_residuals():
    data, sigmas = contact_data(600, 5), {}
    for folds in (None, 4):
        model = gated_model(5, MLPMechanism(2, 1, hidden=(8,), seed=5))
        schedule = replace(SCHEDULE, calibration=CalibrationOptions("variance", 0.9, folds))
        result = fit(model, data, schedule=schedule, seed=5)
        sigmas[folds] = float(model.mechanism("dpos").on.sigma.detach())
        assert result.sigma["dpos"] == pytest.approx((sigmas[folds],), rel=1e-6)
    assert result.sigma_rule["dpos"] == "out-of-fold"
    on = TEST["contact"][:, 0] == 1
    with torch.no_grad():
        resid = (TEST["dpos"] - model.predict({"rel": TEST["rel"], "contact": TEST["contact"]})["dpos"])[on]
    rms = float(resid.pow(2).mean().sqrt())  # the sigma that held-out on rows ask for
    assert 0.7 * rms < sigmas[4] < 1.4 * rms, (sigmas, rms)
    assert abs(math.log(sigmas[4] / rms)) < abs(math.log(sigmas[None] / rms))  # ~15 validation on rows


def test_an_ensemble_on_branch_gets_its_members_and_its_site_scale_from_the_refits():
    data, offsets = contact_data(600, 7), {}
    for folds in (None, 3):
        on = EnsembleMechanism.replicate(lambda g: HeteroscedasticMechanism(2, 1, hidden=(4,), seed=g), 2, 7)
        model = gated_model(7, on)
        schedule = replace(SCHEDULE, epochs=10, calibration=CalibrationOptions("conformal", 0.9, folds))
        result = fit(model, data, schedule=schedule, seed=7)
        offsets[folds] = [float(m.log_scale_offset) for m in (*on.members, on)]
        with torch.no_grad():
            offsets[folds].append(model.predict({"rel": TEST["rel"], "contact": TEST["contact"]})["dpos"])
    assert result.sigma_rule["dpos"] == "recalibrated conformal out-of-fold"
    assert torch.equal(offsets[None][-1], offsets[3][-1])  # the same members
    assert all(a != b for a, b in zip(offsets[None][:3], offsets[3][:3], strict=True))  # members and site


def test_too_few_on_rows_for_the_folds_fall_back_to_the_validation_rows(caplog):
    data = contact_data(200, 6)  # ~30 on rows
    schedule = replace(SCHEDULE, calibration=CalibrationOptions("conformal", 0.9, 20))
    with caplog.at_level(logging.INFO, logger="inference"):
        result = fit(gated_model(6, MLPMechanism(2, 1, hidden=(4,), seed=6)), data, schedule=schedule, seed=6)
    assert result.sigma_rule["dpos"] == "validation conformal"
    assert result.calibration_seconds == 0.0
    assert "too few for 20 calibration folds" in caplog.text


def test_the_scale_factors_of_the_two_rules():
    z = torch.arange(1.0, 20.0)[:, None] * torch.tensor([[1.0, -2.0]])  # |z| = 1..19 and 2..38, n = 19
    variance = scale_factor(z, CalibrationOptions("variance"))
    assert variance == pytest.approx(z.pow(2).mean(0).sqrt(), rel=1e-6)
    conformal = scale_factor(z, CalibrationOptions("conformal", level=0.9))  # k = ceil(20 * 0.9) = 18
    assert conformal.tolist() == pytest.approx([18 / 1.6448536, 36 / 1.6448536], rel=1e-6)
    assert scale_factor(z, CalibrationOptions("conformal", level=0.5)).tolist() == pytest.approx(
        [10 / 0.6744898, 20 / 0.6744898], rel=1e-6
    )  # k = ceil(20 * 0.5) = 10
    few = scale_factor(z[:5], CalibrationOptions("conformal", level=0.9))  # k = 6 > 5: the largest |z|
    assert few.tolist() == pytest.approx([5 / 1.6448536, 10 / 1.6448536], rel=1e-6)
    assert math.isfinite(float(few.sum()))


def test_warm_refits_on_a_branch_whose_residuals_are_all_zero_keep_its_scale_positive_and_bounded():
    # On rows whose value never changes (an object's height on a table): before each fit
    # started from offset 0, every warm refit cut the scale by up to 1e6, until it was 0.
    data = contact_data(600, 4)
    data["dpos"] = torch.zeros_like(data["dpos"])
    model = gated_model(4)
    schedule = SCHEDULE
    offsets = []
    for r in range(6):
        fit(model, data, schedule=schedule, seed=r)
        on = model.mechanism("dpos").on
        offsets.append(float(on.log_scale_offset[0]))
        low, high = (b.detach() for b in on.scale_bounds())
        assert float(low[0]) >= -8.0 and float(high[0]) <= 1.0
    assert max(abs(o) for o in offsets) < 5.0, offsets
    values = {"rel": TEST["rel"], "contact": TEST["contact"]}
    with torch.no_grad():
        sd = model.predict_scale(values)["dpos"]
    assert bool(torch.isfinite(sd).all()) and float(sd.min()) > 0.0
