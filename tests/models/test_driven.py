"""The driven sites of a rollout, rolled over the horizon before the step loop (:mod:`models.driven`).

Oracle: a rollout is ``predict`` chained step by step (Alg. 4.1), the lag-1 roots taking the
previous step's values. The driven pre-pass must leave every value as that chain gives it.
"""

import pytest
import torch

from models import (
    CausalGraph,
    EnsembleMechanism,
    FunctionMechanism,
    LinearMechanism,
    Role,
    Variable,
    WorldModel,
)
from models.driven import driven_sites

N, H = 4, 6


def lin(weights, b=0.0, s=0.1):
    return LinearMechanism.from_coefficients([weights], bias=b, sigma=s)


def body_and_object(members: int = 2) -> WorldModel:
    """A body ``s = s_prev + a`` with a point ``y = sin(s)``, a carried sum ``c = c_prev + y``, and an object ``o``.

    ``s``, ``y`` and ``c`` are driven (``s`` and ``c`` through their lag-1 slots); ``o`` is an
    ensemble fed by ``y`` and ``o_prev``, so it is not.
    """
    graph = CausalGraph(
        [
            Variable("a", Role.ACTION, bounds=(-1.0, 1.0)),
            Variable("s_prev", Role.OBSERVED, lag=1, lag_of="s"),
            Variable("s", Role.LATENT),
            Variable("y", Role.LATENT),
            Variable("c_prev", Role.OBSERVED, lag=1, lag_of="c"),
            Variable("c", Role.LATENT),
            Variable("o_prev", Role.OBSERVED, lag=1, lag_of="o"),
            Variable("o", Role.LATENT),
        ],
        [
            ("s_prev", "s"),
            ("a", "s"),
            ("s", "y"),
            ("c_prev", "c"),
            ("y", "c"),
            ("o_prev", "o"),
            ("y", "o"),
        ],
    )
    ensemble = EnsembleMechanism([lin([0.9, 0.5 + 0.3 * k], b=0.1 * k) for k in range(members)])
    return WorldModel(
        graph,
        {
            "s": lin([1.0, 1.0]),
            "y": FunctionMechanism(torch.sin, 1, 1, sigma=0.2),
            "c": lin([1.0, 1.0]),
            "o": ensemble,
        },
    )


def chained(model, initial, actions, noise):
    """The oracle: ``predict`` step by step, each step's lag-1 roots from the step before."""
    lagged = model.graph.lagged
    state, steps = dict(initial), []
    for tau in range(actions.shape[1]):
        step_noise = noise
        if isinstance(noise, dict):
            step_noise = {k: v[:, tau] if v.ndim == 3 else v for k, v in noise.items()}
        pred = model.predict({**state, "a": actions[:, tau]}, noise=step_noise)
        steps.append(pred)
        state = {r: pred[lagged[r]] for r in initial}
    return {k: torch.stack([s[k] for s in steps], 1) for k in steps[0]}


def inputs(seed=0):
    g = torch.Generator().manual_seed(seed)
    initial = {r: torch.randn(N, 1, generator=g) for r in ("s_prev", "c_prev", "o_prev")}
    return initial, torch.rand(N, H, 1, generator=g) * 2 - 1


def test_the_body_and_what_it_carries_are_driven_the_ensemble_is_not():
    model = body_and_object()
    sites = driven_sites(model.graph, model._mech_by_name, set(), {"a"})
    assert sites == ["s", "y", "c"]
    # with s assigned, its slot is known: y and c stay driven, s is not computed
    assert driven_sites(model.graph, model._mech_by_name, set(), {"a", "s"}) == ["y", "c"]


def residuals(kind):
    g = torch.Generator().manual_seed(1)
    if kind == "expected":
        return "expected"
    shape = (N, 1) if kind == "per_unit" else (N, H, 1)
    return {k: torch.randn(*shape, generator=g) for k in ("s", "y", "c", "o")}


@pytest.mark.parametrize("noise_kind", ["expected", "per_unit", "per_step"])
def test_a_rollout_equals_predict_chained_step_by_step(noise_kind):
    model = body_and_object()
    initial, actions = inputs()
    noise = residuals(noise_kind)
    got = model.rollout(initial, {"a": actions}, noise=noise)
    want = chained(model, initial, actions, noise)
    for name in ("s", "y", "c", "o"):
        torch.testing.assert_close(got[name], want[name], rtol=0, atol=1e-6)
    # the object really moves with the body: the comparison is not vacuous
    assert float(got["o"].std()) > 0.1 and float(got["c"].std()) > 0.1


@pytest.mark.parametrize("noise_kind", ["expected", "per_unit", "per_step"])
def test_member_rollouts_are_those_of_the_step_loop(noise_kind):
    model = body_and_object(members=3)
    initial, actions = inputs(1)
    noise = residuals(noise_kind)
    got = model.rollout(initial, {"a": actions}, noise=noise, members=True)

    want = model.rollout(initial, {"a": actions}, noise=noise, members=True, driven=False)
    assert got["o"].shape == (3, N, H, 1)
    for name in model.graph.names:
        torch.testing.assert_close(got[name], want[name], rtol=0, atol=1e-6)
    assert float((got["o"][0] - got["o"][1]).abs().max()) > 1e-3  # the members part


def test_sampled_rollouts_keep_their_draws():
    model = body_and_object()
    initial, actions = inputs(2)
    a = model.rollout(initial, {"a": actions}, "sampled", torch.Generator().manual_seed(5))
    b = model.rollout(initial, {"a": actions}, "sampled", torch.Generator().manual_seed(5))
    torch.testing.assert_close(a["o"], b["o"], rtol=0, atol=0)
    # sampled residuals enter every site, the body's too
    expected = model.rollout(initial, {"a": actions})
    assert float((a["s"] - expected["s"]).abs().max()) > 1e-3


def test_an_assigned_body_feeds_the_driven_sites_below_it():
    model = body_and_object()
    initial, actions = inputs(3)
    s = torch.linspace(-1, 1, N * H).reshape(N, H, 1)
    got = model.rollout(initial, {"a": actions}, assign={"s": s})
    torch.testing.assert_close(got["y"], torch.sin(s), rtol=0, atol=1e-6)
    c = initial["c_prev"].unsqueeze(1) + torch.sin(s).cumsum(1)
    torch.testing.assert_close(got["c"], c, rtol=0, atol=1e-5)


def test_gradients_reach_the_actions_through_the_driven_sites():
    model = body_and_object()
    initial, actions = inputs(4)
    actions.requires_grad_(True)
    out = model.rollout(initial, {"a": actions}, grad=True, members=True)
    out["o"][:, :, -1].sum().backward()
    assert actions.grad is not None and float(actions.grad[:, :-1].abs().min()) > 0
