"""Average treatment effects from a fitted world model against a closed-form oracle (real tables: tests/pal/datasets/test_tables.py)."""

from __future__ import annotations

import numpy as np
import pytest

from inference.effects import treatment_effect
from models import BernoulliMechanism, CausalGraph, LinearMechanism, WorldModel
from models.tables import as_table


def confounded(n=4000, seed=0):
    """X ~ N(0, 1), T ~ Bernoulli(sigmoid(1.5 X)), Y = 2 T + 3 X + N(0, 1): ATE 2, ATT 2, naive > 2."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=n)
    t = (rng.random(n) < 1 / (1 + np.exp(-1.5 * x))).astype(float)
    y = 2.0 * t + 3.0 * x + rng.normal(size=n)
    return {"x": x, "t": t, "y": y}


def true_model():
    g = CausalGraph.from_edges([("x", "t"), ("x", "y"), ("t", "y")])
    mechs = {
        "t": BernoulliMechanism.from_coefficients([[1.5]]),
        "y": LinearMechanism.from_coefficients([[3.0, 2.0]], sigma=1.0),
    }
    return WorldModel(g, mechs)


@pytest.mark.parametrize("target", ["ate", "att"])
@pytest.mark.parametrize("estimator", ["standardise", "doubly_robust"])
def test_the_true_model_recovers_the_effect(target, estimator):
    rows = as_table(confounded())
    r = treatment_effect(true_model(), rows, "t", "y", target=target, estimator=estimator)
    assert r.naive > 3.5  # confounding: treated units have larger x
    # with the true mechanisms the standardised ATE is exact; the ATT averages the treated units'
    # noise (sd about 0.02) and AIPW adds noise of sd about 0.05
    tol = 1e-5 if (estimator, target) == ("standardise", "ate") else 0.15
    assert r.estimate == pytest.approx(2.0, abs=tol)
    if estimator == "doubly_robust":
        assert r.covers(2.0) and 0.01 < r.se < 0.1
    assert r.n == 4000 and r.to_dict()["target"] == target


def test_doubly_robust_survives_a_wrong_outcome_model():
    rows = as_table(confounded())
    wrong = WorldModel(
        true_model().graph,
        {
            "t": BernoulliMechanism.from_coefficients([[1.5]]),
            "y": LinearMechanism.from_coefficients([[0.0, 0.0]], sigma=1.0),
        },
    )
    std = treatment_effect(wrong, rows, "t", "y", estimator="standardise")
    dr = treatment_effect(wrong, rows, "t", "y", estimator="doubly_robust")
    assert std.estimate == pytest.approx(0.0, abs=1e-6)
    assert dr.estimate == pytest.approx(2.0, abs=0.4)


def test_bad_arguments_are_refused():
    rows = as_table(confounded(100))
    model = true_model()
    with pytest.raises(ValueError, match="must be a Bernoulli site"):
        treatment_effect(model, rows, "x", "y")
    with pytest.raises(ValueError, match="continuous descendant"):
        treatment_effect(model, rows, "t", "x")
    with pytest.raises(ValueError, match="needs columns"):
        treatment_effect(model, rows.select(["t", "y"]), "t", "y")
    with pytest.raises(ValueError, match="both arms"):
        ones = {"x": np.zeros(10), "t": np.ones(10), "y": np.zeros(10)}
        treatment_effect(model, as_table(ones), "t", "y")
    with pytest.raises(ValueError, match="target"):
        treatment_effect(model, rows, "t", "y", target="atc")


def test_unit_effects_of_a_single_member_model_are_exact_with_zero_width():
    from inference.unit_effects import unit_effects

    rows = as_table(confounded(50))
    r = treatment_effect(true_model(), rows, "t", "y")
    np.testing.assert_allclose(r.units.effect, 2.0, atol=1e-5)  # Y = 2 T + 3 X: every unit's effect is 2
    assert r.units.members == 1 and np.array_equal(r.units.low, r.units.high)
    assert isinstance(r.units.table(), dict)
    # new units from their covariates alone: the treatment and outcome columns are not read
    alone = unit_effects(true_model(), {"x": np.ones((3, 1))}, "t", "y")
    np.testing.assert_allclose(alone.effect, 2.0, atol=1e-5)
    with pytest.raises(ValueError, match=r"needs columns for \['x'\]"):
        unit_effects(true_model(), {"t": np.ones((3, 1))}, "t", "y")


def test_unit_level_bad_input_names_the_value():
    from inference.unit_effects import unit_effects

    data = confounded(100)
    model = true_model()
    with pytest.raises(ValueError, match="needs a treatment: got treatment=None"):
        unit_effects(model, as_table(data), None, "y")
    with pytest.raises(ValueError, match="needs a treatment: got treatment=None"):
        treatment_effect(model, as_table(data), None, "y")
    third = {**data, "t": np.where(np.arange(100) == 7, 2.0, data["t"])}
    with pytest.raises(ValueError, match=r"treatment column 't' has the value 2 .*takes 0 and 1 only"):
        treatment_effect(model, as_table(third), "t", "y")
    for clip in (0.0, 0.5, 0.7, -0.1):
        with pytest.raises(ValueError, match=f"clip.*{clip:g}"):
            treatment_effect(model, as_table(data), "t", "y", clip=clip)
def test_propensity_clipping_is_reported_with_its_bound():
    rows = as_table(confounded(n=400))
    loose = treatment_effect(true_model(), rows, "t", "y", target="att", clip=1e-3)
    tight = treatment_effect(true_model(), rows, "t", "y", target="att", clip=0.2)
    assert (loose.clip, tight.clip) == (1e-3, 0.2) and tight.to_dict()["clip"] == 0.2
    # sigmoid(1.5 x) < 0.2 for x < -0.92: about 18 % of N(0, 1) rows, and as many above 0.8
    assert 0.2 * 400 < tight.clipped < 0.5 * 400 and loose.clipped < tight.clipped
    for bad, text in ((0.0, "0"), (0.5, "0.5"), (0.7, "0.7")):
        with pytest.raises(ValueError, match=rf"clip must be > 0 and < 0.5 .* got {text}$"):
            treatment_effect(true_model(), rows, "t", "y", clip=bad)
