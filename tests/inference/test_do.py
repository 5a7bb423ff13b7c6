"""do() cuts edges; conditioning does not."""

import pyro
import pytest
import torch

from inference import Intervene, ReplayNoise, do, infer_state, simulate
from models import CausalGraph, LinearMechanism, Variable, WorldModel


@pytest.fixture
def fork():
    """Confounded fork X <- C -> Y (C latent), Y = C + U, X = C + U."""
    g = CausalGraph(
        [Variable("c", "latent"), Variable("x", "observed"), Variable("y", "observed")],
        [("c", "x"), ("c", "y")],
    )
    return WorldModel(
        g,
        {
            "x": LinearMechanism.from_coefficients([[1.0]], sigma=0.5),
            "y": LinearMechanism.from_coefficients([[1.0]], sigma=0.5),
        },
    )


@pytest.mark.slow
def test_do_and_condition_differ_on_a_confounded_fork(fork):
    # condition on X = 2: E[Y | X=2] = E[C | X=2] = 2 * 1 / (1 + 0.25) = 1.6
    post = infer_state(fork, {"x": torch.tensor([[2.0]])})
    assert float(post.mean["y"][0, 0]) == pytest.approx(1.6, abs=0.05)
    # do(X = 2): the edge C -> X is cut, Y keeps its prior mean 0
    n = 20000
    with torch.no_grad():
        tr = pyro.poutine.trace(do(fork, {"x": 2.0})).get_trace(None, n)
    y = tr.nodes["y"]["value"]
    assert abs(float(y.mean())) < 0.05
    assert float(y.var()) == pytest.approx(1.25, rel=0.05)
    assert torch.all(tr.nodes["x"]["value"] == 2.0)
    # the intervened site carries no evidence: the posterior of C ignores X under do
    post_do = infer_state(do(fork, {"x": 5.0}), {"y": torch.tensor([[1.0]])})
    assert float(post_do.mean["c"][0, 0]) == pytest.approx(1 / 1.25, abs=0.05)


def test_intervened_site_is_delta_with_zero_log_density(fork):
    tr = pyro.poutine.trace(do(fork, {"x": 1.0})).get_trace(None, 3)
    site = tr.nodes["x"]
    assert site["is_observed"] and site["infer"]["pal_intervened"]
    assert torch.all(site["fn"].log_prob(site["value"]) == 0)


def test_batched_and_shift_interventions(fork):
    values = torch.tensor([[1.0], [2.0], [3.0]])
    tr = pyro.poutine.trace(do(fork, {"x": values})).get_trace(None, 3)
    torch.testing.assert_close(tr.nodes["x"]["value"], values)
    # a shift sees the replayed pre-intervention value
    noise = {"c": torch.zeros(3, 1), "x": torch.ones(3, 1), "y": torch.zeros(3, 1)}
    program = Intervene({"x": lambda v: v + 10.0})(ReplayNoise(noise)(fork))
    out = program(None, 3)
    torch.testing.assert_close(out["x"], torch.full((3, 1), 10.5))


@pytest.mark.parametrize(
    ("interventions", "match"),
    [
        ({"nope": 1.0}, "unknown intervention target 'nope'"),
        ({"x": float("inf")}, "NaN or inf"),
        ({"x": [1.0, 2.0]}, "expected a scalar"),
        ({"x": "abc"}, "not numeric"),
    ],
)
def test_do_rejects_bad_input(fork, interventions, match):
    with pytest.raises(ValueError, match=match):
        do(fork, interventions)


def test_intervention_with_wrong_number_of_rows_fails_at_run_time(fork):
    with pytest.raises(ValueError, match="has shape \\(2, 1\\)"):
        do(fork, {"x": torch.zeros(2, 1)})(None, 3)


def test_shift_must_keep_shape(fork):
    with pytest.raises(ValueError, match="expected a tensor of shape \\(3, 1\\)"):
        do(fork, {"x": lambda v: v.sum()})(None, 3)


def test_replay_noise_requires_every_site_unless_expected(fork):
    with pytest.raises(ValueError, match="no replayed noise for site 'c'"):
        ReplayNoise({})(fork)(None, 2)
    out = ReplayNoise({}, default="expected")(fork)(None, 2)
    assert torch.all(out["y"] == 0)


def test_simulate_is_seeded_and_intervenes(fork):
    a = simulate(fork, 5000, {"x": 2.0}, seed=3)
    b = simulate(fork, 5000, {"x": 2.0}, seed=3)
    torch.testing.assert_close(a["y"], b["y"])
    assert not a["y"].requires_grad
    assert torch.all(a["x"] == 2.0)
    obs = simulate(fork, 5000, seed=3)
    # observational X and Y are correlated through C; under do(X) they are not
    corr_obs = torch.corrcoef(torch.cat([obs["x"], obs["y"]], 1).T)[0, 1]
    assert float(corr_obs) == pytest.approx(1 / 1.25, abs=0.05)
    with pytest.raises(ValueError, match="n must be a positive int"):
        simulate(fork, 0)


@pytest.mark.parametrize(("kind", "members"), [("mlp", 1), ("linear", 2), ("hetero", 1), ("hetero", 3)])
def test_predict_is_the_twin_of_intervene_and_replay_noise(kind, members):
    """WorldModel.predict with given values and residuals = the program under Intervene + ReplayNoise."""
    from inference import AbductNoise
    from models import random_graph

    model = WorldModel(random_graph(8, seed=1), seed=2, kind=kind, members=members, hidden=(6,))
    n = 16
    factual = model.sample(n, torch.Generator().manual_seed(0))
    with AbductNoise() as abduction, torch.no_grad():
        model(factual, n)
    noise = {k: v for k, v in abduction.noise.items() if not model.graph.is_root(k)}
    torch.testing.assert_close(noise, model.residuals(factual))
    roots = {r: factual[r] for r in model.graph.roots}
    target = max(model.graph.roots, key=lambda r: len(model.graph.descendants(r)))
    roots[target] = roots[target] + 0.5
    fast = model.predict(roots, noise=noise)
    with torch.no_grad():
        program = Intervene({target: roots[target]})(ReplayNoise(noise, default="expected")(model))
        slow = program({k: v for k, v in roots.items() if k != target}, n)
    for name in model.graph.names:
        torch.testing.assert_close(fast[name], slow[name], atol=1e-5, rtol=1e-5)
