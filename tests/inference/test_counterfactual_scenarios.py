"""Several scenarios and discrete sites: what is computed once, what is sampled, what is exact.

Oracles: the logistic closed form of a binary Gumbel-max site, and the general (handler) path
of :func:`inference.counterfactual`, which replays the whole program.
"""

import math

import pytest
import torch

from inference import counterfactual
from inference.handlers import MeasurementScale
from models import BernoulliMechanism, CausalGraph, LinearMechanism, WorldModel
from models.folded import FOLD_ROWS


def _treated():
    """x -> t (Bernoulli), x -> y, t -> y: y = 0.5 x + 2 t + 0.3 u."""
    g = CausalGraph.from_edges([("x", "t"), ("x", "y"), ("t", "y")])
    mechs = {
        "t": BernoulliMechanism.from_coefficients([[1.5]]),
        "y": LinearMechanism.from_coefficients([[0.5, 2.0]], sigma=0.3),
    }
    return WorldModel(g, mechs, discrete={"t": 2})


def _rows(model, n=200, seed=0):
    return model.sample(n, torch.Generator().manual_seed(seed))


def test_a_set_binary_treatment_is_exact_in_one_pass():
    model = _treated()
    rows = _rows(model)
    cf = counterfactual(model, rows, [{"t": 0.0}, {"t": 1.0}])
    assert cf.exact and cf.samples["y"].shape == (1, 2, 200, 1)
    effect = cf.samples["y"][0, 1] - cf.samples["y"][0, 0]
    torch.testing.assert_close(effect, torch.full_like(effect, 2.0), atol=1e-5, rtol=0)
    # the general path (a handler is active) replays the whole program: the same numbers, also exact
    with MeasurementScale({"y": torch.tensor([0.3])}):
        slow = counterfactual(model, rows, [{"t": 0.0}, {"t": 1.0}], num_samples=50)
    assert slow.exact and slow.samples["y"].shape[0] == 1
    torch.testing.assert_close(slow.samples["y"], cf.samples["y"], atol=1e-5, rtol=0)


def _mediated():
    """x -> m (Bernoulli) -> y, x -> w: only m and y depend on m's Gumbel noise under do(x)."""
    g = CausalGraph.from_edges([("x", "m"), ("m", "y"), ("x", "w")])
    mechs = {
        "m": BernoulliMechanism.from_coefficients([[1.0]]),
        "y": LinearMechanism.from_coefficients([[3.0]], sigma=0.5),
        "w": LinearMechanism.from_coefficients([[-1.0]], sigma=0.2),
    }
    return WorldModel(g, mechs, discrete={"m": 2})


def test_mixed_case_samples_only_the_uncertain_discrete_site_and_its_descendants():
    model = _mediated()
    x0, m0 = 0.4, 1.0
    rows = {
        "x": torch.tensor([[x0]]),
        "m": torch.tensor([[m0]]),
        "y": torch.tensor([[2.5]]),
        "w": torch.tensor([[0.1]]),
    }
    s = 40_000
    cf = counterfactual(model, rows, [{"x": -1.0}, {"x": 1.5}], num_samples=s, seed=3)
    assert not cf.exact and cf.samples["m"].shape == (s, 2, 1, 1)
    # w does not read m: one deterministic value per scenario, the same in every draw
    w = cf.samples["w"][:, :, 0, 0]
    assert bool((w == w[0]).all())
    u_w = (0.1 + x0) / 0.2
    torch.testing.assert_close(w[0], torch.tensor([1.0 + 0.2 * u_w, -1.5 + 0.2 * u_w]), atol=1e-5, rtol=0)
    # P(m' = 1 | m = 1, x -> x1), binary Gumbel-max: min(sigmoid(x1), sigmoid(x0)) / sigmoid(x0)
    sig = lambda v: 1 / (1 + math.exp(-v))  # noqa: E731
    for k, x1 in enumerate((-1.0, 1.5)):
        expected = min(sig(x1), sig(x0)) / sig(x0)
        assert float(cf.probability("m", 1.0)[k, 0]) == pytest.approx(expected, abs=0.01)  # 4 sd at s
    # y' = 3 m' + 0.5 u_y with the unit's abducted u_y in every draw
    u_y = (2.5 - 3.0 * m0) / 0.5
    torch.testing.assert_close(cf.samples["y"], 3.0 * cf.samples["m"] + 0.5 * u_y, atol=1e-5, rtol=0)
    assert cf.noise["m"].shape == (s, 1, 2)


def test_two_identical_scenarios_warn_and_are_computed_once():
    model = _treated()
    rows = _rows(model, 20)
    with pytest.warns(UserWarning, match=r"scenario 2 repeats scenario 0 \(do\(t=\[1.0\]\)\)"):
        cf = counterfactual(model, rows, [{"t": 1.0}, {"t": 0.0}, {"t": 1.0}])
    assert cf.samples["y"].shape == (1, 3, 20, 1)
    torch.testing.assert_close(cf.samples["y"][:, 2], cf.samples["y"][:, 0], atol=0, rtol=0)
    assert not torch.equal(cf.samples["y"][:, 1], cf.samples["y"][:, 0])


def _mlp_scm(d=12, seed=7):
    from models import random_graph

    return WorldModel(random_graph(d, seed=seed), seed=seed)


def _mixed_scenarios(model, n):
    """Scenarios on different sites: two roots, a per-unit value, a shift, nested sites, none."""
    graph = model.graph
    roots = sorted(graph.roots, key=lambda r: -len(graph.descendants(r)))
    inner = next(v for v in graph.topological_order() if graph.descendants(v) and not graph.is_root(v))
    above = next(r for r in roots if inner in graph.descendants(r))
    per_unit = torch.linspace(-2.0, 2.0, n)[:, None]
    return [
        {roots[0]: 0.5},
        {roots[1]: per_unit},
        {inner: lambda v: v + 1.0},
        {above: -1.0, inner: lambda v: 2.0 * v},  # an intervened site below another
        {},
    ]


@pytest.mark.parametrize("n", [30, 600])  # 5 x 600 rows: the replay evaluates folded MLP layers
def test_batched_scenarios_equal_the_scenarios_one_by_one(n):
    model = _mlp_scm()
    rows = _rows(model, n, seed=1)
    scenarios = _mixed_scenarios(model, n)
    assert (len(scenarios) * n >= FOLD_ROWS) == (n == 600)
    batch = counterfactual(model, rows, scenarios)
    assert batch.exact and batch.samples[model.graph.roots[0]].shape == (1, len(scenarios), n, 1)
    for k, sc in enumerate(scenarios):
        single = counterfactual(model, rows, sc)
        for name, value in single.samples.items():
            torch.testing.assert_close(batch.samples[name][:, k], value[:, 0], atol=1e-5, rtol=0)


def test_each_scenario_replays_only_the_descendants_of_its_own_interventions():
    model = _mlp_scm()
    graph = model.graph
    rows = _rows(model, 30, seed=2)
    a, b = sorted(graph.roots, key=lambda r: -len(graph.descendants(r)))[:2]
    only_a = graph.descendants(a) - graph.descendants(b)
    assert only_a  # a site that do(b) must leave untouched
    cf = counterfactual(model, rows, [{a: 3.0}, {b: -3.0}])
    for name in graph.topological_order():
        if name != b and name not in graph.descendants(b):
            # bit for bit the factual value where do(b) does not reach (nothing recomputed there)
            assert torch.equal(cf.samples[name][0, 1], rows[name]), name
        if name in only_a:
            assert not torch.allclose(cf.samples[name][0, 0], rows[name], atol=1e-4)


def test_batched_scenarios_with_a_latent_site_equal_the_scenarios_one_by_one():
    model = _mlp_scm(8, seed=7)
    graph = model.graph
    rows = _rows(model, 10, seed=3)
    hidden = next(v for v in graph.topological_order() if not graph.is_root(v) and graph.descendants(v))
    evidence = {k: v for k, v in rows.items() if k != hidden}
    root = next(r for r in graph.roots if hidden in graph.descendants(r))
    scenarios = [{root: 1.0}, {root: lambda v: v - 1.0}, {hidden: 0.0}]
    batch = counterfactual(model, evidence, scenarios, num_samples=64, seed=4)
    assert not batch.exact and batch.samples[hidden].shape == (64, 3, 10, 1)
    for k, sc in enumerate(scenarios):
        single = counterfactual(model, evidence, sc, posterior=batch.posterior, seed=4)
        for name, value in single.samples.items():
            torch.testing.assert_close(batch.samples[name][:, k], value[:, 0], atol=1e-5, rtol=0)
