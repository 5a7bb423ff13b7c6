"""The default schedule of fit behaves from 200 to 10^6 rows, and says how sigma was set."""

import math

import pytest
import torch

from inference import FitSchedule, fit
from models import CausalGraph, FunctionMechanism, Variable, WorldModel


def _table(n, seed=0):
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(n, 1, generator=gen)
    return {"x": x, "y": torch.sin(2 * x) + torch.randn(n, 1, generator=gen)}  # true noise sd 1


@pytest.mark.parametrize("n", [200, 747])
def test_small_tables_get_an_honest_noise_sd(n):
    graph = CausalGraph([Variable(v, "observed") for v in "xy"], [("x", "y")])
    model = WorldModel(graph, seed=0)
    r = fit(model, _table(n))
    assert r.schedule == FitSchedule.auto(n)
    assert r.sigma_rule == {"y": "validation"} and r.n_val == round(0.2 * n)
    assert r.sigma["y"][0] == pytest.approx(1.0, rel=0.15)  # not the 0.25-0.44 of an overfitted MLP
    assert r.best_epoch["y"] < r.epochs  # stopped early on the held-out rows


def test_the_schedule_scales_with_the_rows():
    small, large = FitSchedule.auto(200), FitSchedule.auto(1_000_000)
    assert (small.validation, small.batch_size, small.epochs, small.patience) == (0.2, 160, 3000, 100)
    assert small.plateau_se == 1.0 and large.plateau_se == 0.0
    assert (large.validation, large.batch_size, large.epochs, large.patience) == (0.1, 2048, 23, 5)
    for n in (200, 1000, 10_000, 100_000, 1_000_000):
        s = FitSchedule.auto(n)
        steps = s.epochs * math.ceil((n - round(s.validation * n)) / s.batch_size)
        assert 2_000 <= steps <= 25_000, (n, steps)
    assert FitSchedule.auto(10).validation == 0.0 and FitSchedule.auto(10).patience is None


def test_sigma_rules_are_reported():
    graph = CausalGraph([Variable(v, "observed") for v in "xyz"], [("x", "y"), ("y", "z")])
    model = WorldModel(graph, {"z": FunctionMechanism(torch.tanh, 1, 1, sigma=0.5)}, seed=0, kind="linear")
    data = {**_table(100), "z": torch.zeros(100, 1)}
    r = fit(model, data, schedule=FitSchedule(epochs=2, validation=0.0))
    assert r.sigma_rule == {"y": "training"} and "fixed FunctionMechanism" in r.skipped["z"]
    assert float(model.mechanism("z")(torch.ones(1, 1))) == pytest.approx(math.tanh(1.0))
    r = fit(model, data, loss="nll", schedule=FitSchedule(epochs=2, validation=0.0))
    assert r.sigma_rule == {"y": "nll"}
    assert r.to_dict()["sigma_rule"] == {"y": "nll"}
