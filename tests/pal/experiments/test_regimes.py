"""Object motion per regime: predictive intervals at several levels, coverage per regime, its targets."""

import numpy as np
import pytest

from pal.agent import ModelConfig, build_graph, build_model, pushing_spec
from pal.agent.history import History
from pal.experiments.closed_loop.regime_report import MIN_ROWS, regime_targets
from pal.experiments.closed_loop.regimes import LEVELS, RegimeRows, concat, regime_rows, summarize


def synthetic(n_on: int, n_off: int, origin: str = "random") -> RegimeRows:
    """Contact rows: at 0.9 the x component always inside, y inside on every other row (coverage 0.75);
    no-contact rows: both inside (1.0), sd 0.5 mm. At the other levels nothing is inside."""
    n = n_on + n_off
    inside = np.zeros((len(LEVELS), n, 2), dtype=bool)
    k = LEVELS.index(0.9)
    inside[k, :, 0] = True
    inside[k, :n_on, 1] = np.arange(n_on) % 2 == 0
    inside[k, n_on:, 1] = True
    sd = np.full((n, 2), 5e-4)
    sd[:n_on] = 0.01
    return RegimeRows(
        contact=np.arange(n) < n_on,
        origin=np.full(n, origin),
        true=np.zeros((n, 2)),
        mean=np.full((n, 2), 2e-3),
        sd=sd,
        inside=inside,
        levels=LEVELS,
    )


def test_summarize_counts_components_separately_per_regime_and_origin():
    rows = concat([synthetic(20, 30), synthetic(4, 6, "planned")])
    s = summarize(rows)
    assert s["random contact"]["rows"] == 20 and s["random contact"]["coverage"] == pytest.approx(0.75)
    assert s["random no contact"]["coverage"] == 1.0 and s["random no contact"][
        "sd_median_mm"
    ] == pytest.approx(0.5)
    assert s["planned contact"]["rows"] == 4 and s["planned contact"]["components"] == 8
    assert s["contact"]["rows"] == 24 and s["all"]["rows"] == 60
    assert s["random contact"]["abs_err_median_mm"] == pytest.approx(2.0)
    curve = s["random contact"]["reliability"]
    assert list(curve) == [f"{v:g}" for v in LEVELS] and curve["0.5"] == 0.0 and curve["0.9"] == 0.75
    only = summarize(synthetic(3, 0))
    assert only["no contact"]["rows"] == 0 and only["no contact"]["coverage"] is None
    assert "planned contact" not in only
    with pytest.raises(ValueError, match="level 0.85 is not among"):
        summarize(rows, 0.85)
    with pytest.raises(ValueError, match="origin has"):
        RegimeRows(
            rows.contact, np.full(len(rows), "other"), rows.true, rows.mean, rows.sd, rows.inside, LEVELS
        )


def test_regime_targets_need_twenty_rows_per_regime():
    few = summarize(synthetic(MIN_ROWS - 1, MIN_ROWS - 1))
    targets = regime_targets(few, "random")
    assert len(targets) == 5 and {t.verdict for t in targets} == {"not evaluated"}
    assert "(had 19)" in targets[0].precondition.reason and not any(t.met for t in targets)
    enough = {t.name: t.verdict for t in regime_targets(summarize(synthetic(MIN_ROWS, MIN_ROWS)), "random")}
    assert enough == {
        "random_no_contact_sd_mm": "met",  # 0.5 mm
        "random_no_contact_coverage_low": "met",  # 1.0
        "random_no_contact_coverage_high": "not met",
        "random_contact_coverage_low": "not met",  # 0.75
        "random_contact_coverage_high": "met",
    }
    none = regime_targets({"rows": 0}, "planned")
    assert none[0].name == "planned_no_contact_sd_mm" and none[0].verdict == "not evaluated"


def test_regime_rows_split_the_history_by_touch_and_drop_unperceived_rows():
    spec = pushing_spec()
    config = ModelConfig(members=2, hidden=(8,))
    low, high = np.full(len(spec.actions), -1.0), np.full(len(spec.actions), 1.0)
    model = build_model(spec, build_graph(spec, (low, high)), config, seed=0)
    h = History(spec.joints, spec.object_names, actions=len(spec.actions), effector_dim=3)
    rng = np.random.default_rng(0)
    for k in range(6):
        prev = rng.uniform(-0.2, 0.2, size=(2, 2))
        now = prev + (0.01 if k < 2 else 0.0)
        meas_prev = prev.copy()
        if k == 5:
            meas_prev[1] = np.nan  # the ball is not perceived before the last step
        row = {"episode": 0, "act": rng.uniform(-1, 1, len(spec.actions)), "touch": [float(k < 2), 0.0]}
        row.update({f: rng.uniform(-0.3, 0.3, size=len(spec.joints)) for f in ("q_prev", "q")})
        row.update({f: rng.uniform(-0.3, 0.3, size=3) for f in ("hand_prev", "hand")})
        row.update(meas_prev=meas_prev, meas=now, std=np.full((2, 2), 1e-3), est_prev=prev, est=now)
        row.update(truth_prev=prev, truth=now)
        row.update({f: np.zeros(1) for f in h.fields if f not in row})
        h.append(**row)
    rows = regime_rows(model, h, np.arange(6), "random", source="perceived", num_samples=8, seed=0)
    assert len(rows) == 6 + 5  # box: 6 rows, ball: 5
    assert rows.contact.tolist() == [True, True] + [False] * 9
    np.testing.assert_allclose(rows.true[:2], 0.01, atol=1e-12)
    assert rows.inside.shape == (len(LEVELS), 11, 2) and np.all(rows.sd > 0)
    again = regime_rows(model, h, np.arange(6), "random", source="perceived", num_samples=8, seed=0)
    np.testing.assert_array_equal(again.sd, rows.sd)
    with pytest.raises(ValueError, match="origin 'babble' unknown"):
        regime_rows(model, h, np.arange(6), "babble")
