"""predictive_check against closed forms, and heteroscedastic against homoscedastic fits."""

import math

import numpy as np
import pytest
import torch

from inference import FitSchedule, fit, predictive_check
from models import CausalGraph, LinearMechanism, Variable, WorldModel, chain_graph

SIGMA = 0.5


def xy_graph():
    return CausalGraph([Variable("x", "observed"), Variable("y", "latent")], [("x", "y")])


@pytest.fixture
def linear():
    """Y = 2 X + 0.5 U: the model is the true SCM."""
    return WorldModel(xy_graph(), {"y": LinearMechanism.from_coefficients(2.0, sigma=SIGMA)})


def linear_rows(n, seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 1))
    return {"x": x, "y": 2.0 * x + SIGMA * rng.normal(size=(n, 1))}


def test_a_true_linear_gaussian_model_is_calibrated_and_its_nll_is_the_closed_form(linear):
    data = linear_rows(20_000, 0)
    out = predictive_check(linear, data)
    assert set(out) == {"y"}
    y = out["y"]
    assert y["coverage"] == pytest.approx(0.9, abs=0.02)
    z = (data["y"] - 2.0 * data["x"]) / SIGMA
    closed = float(np.mean(0.5 * np.log(2 * np.pi * SIGMA**2) + 0.5 * z**2))
    assert y["nll"] == pytest.approx(closed, abs=1e-3)
    # and the expected NLL of a Normal, 0.5 log(2 pi e sigma^2), up to sampling error
    assert y["nll"] == pytest.approx(0.5 * math.log(2 * math.pi * math.e * SIGMA**2), abs=0.02)
    assert y["mse"] == pytest.approx(SIGMA**2, rel=0.03)
    assert y["mean_sd"] == pytest.approx(SIGMA, rel=1e-6)
    assert y["n"] == 20_000 and y["level"] == 0.9
    nominal = [p for p, _ in y["reliability"]]
    assert nominal == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9])
    for p, observed in y["reliability"]:
        assert observed == pytest.approx(p, abs=0.02)
    assert y["reliability"][-1][1] == y["coverage"]


def test_an_overconfident_model_covers_less(linear):
    data = linear_rows(5000, 1)
    linear.mechanism("y").set_sigma(SIGMA / 4)
    y = predictive_check(linear, data, level=0.5, levels=[0.5, 0.95])["y"]
    # |z| <= q * 0.25 sigma has probability 2 Phi(q / 4) - 1 for the true sigma
    q = 0.6744897501960817
    assert y["coverage"] == pytest.approx(math.erf(q / 4 / math.sqrt(2)), abs=0.02)
    assert [p for p, _ in y["reliability"]] == [0.5, 0.95]
    assert y["reliability"][1][1] < 0.5


def test_sites_default_to_those_with_columns_and_multi_site_models():
    model = WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients(2.0), "z": LinearMechanism.from_coefficients(-1.5)},
    )
    data = model.sample(4000, torch.Generator().manual_seed(0))
    both = predictive_check(model, data)
    assert set(both) == {"y", "z"}
    assert all(abs(r["coverage"] - 0.9) < 0.03 for r in both.values())
    only = predictive_check(model, {"x": data["x"], "y": data["y"]})
    assert set(only) == {"y"}
    assert predictive_check(model, data, sites=["z"])["z"] == both["z"]


def hetero_rows(n, seed):
    """Y = sin X + (0.05 + 0.3 |X|) U, X ~ U(-2, 2)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-2, 2, (n, 1))
    return {"x": x, "y": np.sin(x) + (0.05 + 0.3 * np.abs(x)) * rng.normal(size=(n, 1))}


BINS = ((-2.0, -1.0), (-1.0, -0.3), (-0.3, 0.3), (0.3, 1.0), (1.0, 2.0))


def coverage_by_bin(model, data):
    out = []
    for lo, hi in BINS:
        sel = (data["x"][:, 0] >= lo) & (data["x"][:, 0] < hi)
        out.append(predictive_check(model, {k: v[sel] for k, v in data.items()})["y"]["coverage"])
    return out


def test_a_heteroscedastic_fit_is_calibrated_where_a_homoscedastic_one_is_not():
    train, test = hetero_rows(6000, 0), hetero_rows(20_000, 1)
    kwargs = {"schedule": FitSchedule(epochs=60, batch_size=256, lr=0.005, patience=10), "seed": 0}
    homo = WorldModel(xy_graph(), seed=0, hidden=(32, 32))
    fit(homo, train, **kwargs)
    hetero = WorldModel(xy_graph(), seed=0, kind="hetero", hidden=(32, 32))
    fit(hetero, train, **kwargs)
    homo_bins, hetero_bins = coverage_by_bin(homo, test), coverage_by_bin(hetero, test)
    # written: homoscedastic 0.76 0.97 1.00 0.98 0.77, heteroscedastic 0.90 0.87 0.94 0.86 0.91
    assert all(abs(c - 0.9) <= 0.05 for c in hetero_bins), hetero_bins
    assert max(abs(c - 0.9) for c in homo_bins) >= 0.1, homo_bins
    assert homo_bins[0] < 0.82 and homo_bins[2] > 0.97
    # overall both look fine, and the heteroscedastic one has the better NLL
    h, s = predictive_check(homo, test)["y"], predictive_check(hetero, test)["y"]
    assert abs(s["coverage"] - 0.9) <= 0.02
    assert s["nll"] < h["nll"] - 0.1


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"level": 1.0}, "level must be > 0 and < 1"),
        ({"level": 0.0}, "level must be > 0 and < 1"),
        ({"level": float("nan")}, "level must be > 0 and < 1 (a finite number), got nan"),
        ({"levels": []}, "levels must be a non-empty sequence"),
        ({"levels": "0.5"}, "levels must be a non-empty sequence"),
        ({"levels": [0.5, 1.5]}, "levels[1] must be > 0 and < 1"),
        ({"sites": ["x"]}, "site 'x' is a root"),
        ({"sites": ["w"]}, "unknown site 'w'"),
        ({"sites": []}, "sites is empty"),
    ],
)
def test_bad_input_names_the_value(linear, kwargs, match):
    with pytest.raises(ValueError, match=match.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        predictive_check(linear, linear_rows(10, 0), **kwargs)


def test_bad_models_and_data(linear):
    with pytest.raises(ValueError, match="model must be a WorldModel"):
        predictive_check("model", linear_rows(10, 0))
    with pytest.raises(ValueError, match="data is empty"):
        predictive_check(linear, {})
    with pytest.raises(ValueError, match="no site can be checked from columns \\['x'\\]"):
        predictive_check(linear, {"x": np.zeros((3, 1))})
    with pytest.raises(ValueError, match="cannot check site 'y': data has no column for \\['y'\\]"):
        predictive_check(linear, {"x": np.zeros((3, 1))}, sites=["y"])
