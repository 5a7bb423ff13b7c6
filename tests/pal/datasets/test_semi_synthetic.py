"""The table of IHDP's shape with known unit effects, and the unit-level effects that a fitted model recovers."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from inference import FitSchedule, fit, treatment_effect
from inference.unit_effects import COLUMNS
from models import CausalGraph, WorldModel
from pal.datasets.semi_synthetic import ATT, ihdp_like


def test_the_table_has_the_benchmark_shape_and_its_known_effects():
    table = ihdp_like(seed=0)
    assert len(table.columns) == 26 and all(len(v) == 747 for v in table.columns.values())
    t = table.columns["t"]
    assert set(np.unique(t)) == {0.0, 1.0} and 0.1 < t.mean() < 0.4
    assert table.effect[t == 1].mean() == pytest.approx(ATT, abs=1e-9)
    assert table.effect.std() > 1.0  # the effect varies from unit to unit
    assert table.pehe(table.effect) == 0.0
    again = ihdp_like(seed=0)
    assert all(np.array_equal(again.columns[c], table.columns[c]) for c in table.columns)
    with pytest.raises(ValueError, match="expected"):
        table.pehe(np.zeros(3))


@pytest.fixture(scope="module")
def fitted():
    """A 3-member MLP ensemble fitted briefly on the table (bootstrap members give the intervals)."""
    table = ihdp_like(seed=0)
    edges = [(c, "t") for c in table.covariates] + [(c, "y") for c in table.covariates] + [("t", "y")]
    model = WorldModel(CausalGraph.from_edges(edges), seed=0, discrete={"t": 2}, members=3)
    rows = pd.DataFrame(table.columns, index=[f"u{i}" for i in range(747)])
    fit(model, rows, schedule=FitSchedule(epochs=60, batch_size=256, validation=0.2, patience=10), seed=0)
    return table, model, rows


@pytest.mark.slow  # a 3-member fit of 747 rows, about 3 s
def test_unit_effects_recover_the_known_effects_beside_the_att(fitted):
    table, model, rows = fitted
    r = treatment_effect(model, rows, "t", "y", target="att")
    assert r.covers(ATT) or abs(r.estimate - ATT) < 1.0
    units = r.units.table()
    assert isinstance(units, pd.DataFrame) and list(units.columns) == list(COLUMNS)
    assert list(units.index[:2]) == ["u0", "u1"]
    np.testing.assert_allclose(units["effect"], units["y1"] - units["y0"], atol=1e-9)
    # the best constant effect has PEHE = sd(tau) (3.3 here): unit effects must do much better
    assert table.pehe(units["effect"].to_numpy()) < 0.8 * table.effect.std()
    assert np.corrcoef(units["effect"], table.effect)[0, 1] > 0.7
    assert (units["low"] < units["effect"]).all() and (units["effect"] < units["high"]).all()
    assert 0.2 < r.units.covers(table.effect) <= 1.0 and r.units.members == 3
    assert len(r.to_dict()["units"]["effect"]) == 747
