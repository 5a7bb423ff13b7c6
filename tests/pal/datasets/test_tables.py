"""The shipped real tables and their textbook answers, recovered by a fitted world model."""

from __future__ import annotations

import numpy as np
import pytest

from inference import FitSchedule, fit, treatment_effect
from models import CausalGraph, WorldModel, as_table
from pal.datasets import NHEFS_EFFECT, NSW_EFFECT, lalonde, nhefs, read_table


def test_tables_hold_their_documented_shapes_and_naive_answers():
    nsw, cps, smoking = lalonde("nsw"), lalonde("cps"), nhefs()
    assert len(nsw["treat"]) == 445 and len(cps["treat"]) == 185 + 15992 and len(smoking["qsmk"]) == 1566
    experimental = nsw["re78"][nsw["treat"] == 1].mean() - nsw["re78"][nsw["treat"] == 0].mean()
    assert experimental == pytest.approx(NSW_EFFECT, abs=0.01)
    naive = cps["re78"][cps["treat"] == 1].mean() - cps["re78"][cps["treat"] == 0].mean()
    assert naive == pytest.approx(-8497.5, abs=1.0)
    assert all(np.isfinite(v).all() for v in smoking.values())
    with pytest.raises(ValueError, match="unknown table"):
        read_table("sachs.csv")
    with pytest.raises(ValueError, match="controls must be"):
        lalonde("psid")


@pytest.mark.slow
def test_nhefs_average_effect_of_quitting_is_about_3_4_kg():
    data = nhefs()
    data["education"] = data["education"] - 1  # codes 0..4
    conf = ["sex", "race", "age", "education", "smokeintensity", "smokeyrs", "exercise", "active", "wt71"]
    g = CausalGraph.from_edges(
        [(c, "qsmk") for c in conf] + [(c, "wt82_71") for c in conf] + [("qsmk", "wt82_71")]
    )
    cats = {"qsmk": 2, "sex": 2, "race": 2, "education": 5, "exercise": 3, "active": 3}
    model = WorldModel(g, seed=0, kind="linear", discrete=cats)
    table = as_table(data)
    fit(model, table, seed=0)
    r = treatment_effect(model, table, "qsmk", "wt82_71", estimator="doubly_robust")
    assert r.naive == pytest.approx(2.54, abs=0.01)
    assert r.estimate == pytest.approx(NHEFS_EFFECT, abs=0.5) and r.covers(NHEFS_EFFECT)


@pytest.mark.slow
def test_lalonde_effect_on_the_trained_from_survey_controls():
    data = lalonde("cps")
    data |= {"u74": (data["re74"] == 0) * 1.0, "u75": (data["re75"] == 0) * 1.0}
    data |= {"age^2": data["age"] ** 2, "educ^2": data["educ"] ** 2}
    conf = [c for c in data if c not in ("treat", "re78")]
    g = CausalGraph.from_edges(
        [(c, "treat") for c in conf] + [(c, "re78") for c in conf] + [("treat", "re78")]
    )
    model = WorldModel(g, seed=0, kind="linear", discrete={"treat": 2})
    table = as_table(data)
    schedule = FitSchedule(epochs=100, batch_size=1024, lr=0.02, validation=0.0, patience=None)
    fit(model, table, schedule=schedule, seed=0)
    r = treatment_effect(model, table, "treat", "re78", target="att", estimator="doubly_robust")
    assert r.naive == pytest.approx(-8497.5, abs=1.0)
    assert r.estimate == pytest.approx(NSW_EFFECT, abs=400) and r.covers(NSW_EFFECT)
