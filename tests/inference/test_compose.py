"""Queries compose ChiRho-style: do() and handlers return programs that keep the graph, and every
query accepts such a program or runs under handlers entered with ``with``.

Oracle: the chain X -> Y -> Z, Y = 2X + U_y, Z = -1.5Y + U_z, U ~ N(0, 1), X ~ N(0, 1).
Given X = 1 and Z = z: Y | . ~ N((2 + 1.5 (-z)) / 3.25, 1 / 3.25) (precision 1 + 1.5^2).
"""

import math

import pytest
import torch

from inference import (
    ActionOptions,
    Intervene,
    MeasurementScale,
    Program,
    ReplayNoise,
    counterfactual,
    do,
    infer_action,
    infer_state,
)
from models import CausalGraph, LinearMechanism, Variable, WorldModel, chain_graph

Z = torch.tensor([[-3.0]])
POST_MEAN = (2.0 + 1.5 * 3.0) / 3.25
POST_SD = 3.25**-0.5


def test_do_and_handlers_return_programs_that_keep_the_graph(chain):
    for program in (
        do(chain, {"x": 1.0}),
        Intervene({"x": 1.0})(chain),
        MeasurementScale({"z": torch.ones(1)})(do(chain, {"x": 1.0})),
        do(do(chain, {"x": 1.0}), {"y": 0.0}),
    ):
        assert isinstance(program, Program) and program.graph == chain.graph and program.world is chain
    assert set(simulate_values(do(do(chain, {"x": 1.0}), {"y": 0.0}))) == {"x", "y", "z"}


def simulate_values(program):
    with torch.no_grad():
        return program(None, 3)


def test_infer_state_on_an_intervened_program(chain):
    state = infer_state(do(chain, {"x": 1.0}), {"z": Z}, guide="grid")
    assert state.latent == ("y",)
    assert float(state.mean["y"]) == pytest.approx(POST_MEAN, abs=1e-3)
    assert float(state.sd["y"]) == pytest.approx(POST_SD, abs=1e-3)


def test_queries_run_under_handlers_entered_with_with(chain):
    with Intervene({"x": 1.0}):
        state = infer_state(chain, {"z": Z}, guide="grid")
    assert state.latent == ("y",)  # read from the trace: x is intervened, not latent
    assert float(state.mean["y"]) == pytest.approx(POST_MEAN, abs=1e-3)
    with Intervene({"x": 1.0}):
        cf = counterfactual(chain, {"z": Z}, {"y": 0.0})
    # Z' = -1.5 * 0 + U_z with U_z = z + 1.5 y: mean z + 1.5 E[y]
    assert float(cf.mean["z"]) == pytest.approx(-3.0 + 1.5 * POST_MEAN, abs=0.02)
    with Intervene({"x": 1.0}):
        svi = infer_state(chain, {"z": Z}, num_steps=300)
    assert float(svi.mean["y"]) == pytest.approx(POST_MEAN, abs=0.05)


def test_measurement_scale_around_every_query(chain):
    # the scale of z's site becomes 2: posterior precision 1 + 1.5^2 / 4
    prec = 1 + 2.25 / 4
    mean = (2.0 + 1.5 * 3.0 / 4) / prec
    scale = {"z": torch.tensor([2.0])}
    composed = infer_state(MeasurementScale(scale)(do(chain, {"x": 1.0})), {"z": Z}, guide="grid")
    with MeasurementScale(scale), Intervene({"x": 1.0}):
        entered = infer_state(chain, {"z": Z}, guide="grid")
    for state in (composed, entered):
        assert float(state.mean["y"]) == pytest.approx(mean, abs=1e-3)
        assert float(state.sd["y"]) == pytest.approx(prec**-0.5, abs=1e-3)
    # counterfactual: abducted with sigma 2 and replayed with sigma 2 in either order of the handlers
    factual = {"x": torch.ones(1, 1), "y": torch.full((1, 1), 2.5), "z": Z}
    inner = counterfactual(MeasurementScale(scale)(chain), factual, {"x": 0.0})
    with MeasurementScale(scale):
        outer = counterfactual(chain, factual, {"x": 0.0})
    # Y' = 0.5, Z' = -1.5 * 0.5 + (z + 1.5 * 2.5) = 0
    for cf in (inner, outer):
        assert float(cf.samples["z"].flatten()[0]) == pytest.approx(0.0, abs=1e-5)
    # infer_action under a measurement scale: the target is reached either way
    graph = CausalGraph(
        [Variable("a", "action", bounds=(-2.0, 2.0)), Variable("y", "observed")], [("a", "y")]
    )
    model = WorldModel(graph, {"y": LinearMechanism.from_coefficients([[1.5]], 0.0, 0.5)})
    with MeasurementScale({"y": torch.tensor([0.1])}):
        act = infer_action(model, None, {"y": torch.full((2, 1), 1.5)}, num_steps=200)
    torch.testing.assert_close(act.actions["a"], torch.ones(2, 1), atol=1e-2, rtol=0)


def test_counterfactual_with_a_given_posterior_matches_the_inferred_one(chain):
    obs = {"x": torch.ones(1, 1), "z": Z}
    state = infer_state(chain, obs, guide="grid", num_samples=4000)
    given = counterfactual(chain, obs, {"x": 0.0}, posterior=state)
    assert given.posterior is state
    inferred = counterfactual(chain, obs, {"x": 0.0}, guide="grid", num_samples=4000)
    torch.testing.assert_close(given.mean["y"], inferred.mean["y"], atol=0.03, rtol=0)
    # Y' = 0 + (y - 2): mean POST_MEAN - 2, sd POST_SD
    assert float(given.samples["y"].std()) == pytest.approx(POST_SD, rel=0.05)


def test_counterfactual_on_a_program_with_per_unit_interventions(chain):
    n = 4
    xs = torch.linspace(-1, 1, n)[:, None]
    program = do(chain, {"x": xs})
    factual = {"y": 2 * xs + 0.3, "z": -1.5 * (2 * xs + 0.3) - 0.2}
    cf = counterfactual(program, factual, {"y": 0.0})
    torch.testing.assert_close(cf.samples["z"][0, 0], torch.full((n, 1), -0.2), atol=1e-5, rtol=0)


def test_infer_action_accepts_a_program_with_replayed_noise():
    graph = CausalGraph(
        [Variable("a", "action", bounds=(-2.0, 2.0)), Variable("y", "observed")], [("a", "y")]
    )
    model = WorldModel(graph, {"y": LinearMechanism.from_coefficients([[1.5]], 0.0, 0.5)})
    u = torch.tensor([[1.0], [-1.0]])
    target = torch.zeros(2, 1)
    # y = 1.5 a + 0.5 u = 0  ->  a = -u / 3
    for program in (ReplayNoise({"y": u}, default="expected")(model),):
        act = infer_action(program, None, {"y": target}, num_steps=300)
        torch.testing.assert_close(act.actions["a"], -u / 3, atol=1e-2, rtol=0)
    from inference import SamplingConfig

    sampled = infer_action(
        ReplayNoise({"y": u}, default="expected")(model),
        None,
        {"y": target},
        num_steps=100,
        options=ActionOptions(sampling=SamplingConfig(population=64, elites=8)),
    )
    torch.testing.assert_close(sampled.actions["a"], -u / 3, atol=1e-2, rtol=0)


def test_the_keywords_replaced_by_composition_are_refused(chain):
    with pytest.raises(TypeError, match="unexpected keyword argument 'interventions'"):
        infer_state(chain, {"z": Z}, interventions={"x": 1.0}, guide="grid")
    with pytest.raises(TypeError, match="unexpected keyword argument 'measurement_scale'"):
        infer_state(chain, {"z": Z}, measurement_scale={"z": 0.1}, guide="grid")
    with pytest.raises(TypeError, match="unexpected keyword argument 'state_kwargs'"):
        counterfactual(chain, {"x": torch.ones(1, 1), "z": Z}, {"x": 0.0}, state_kwargs={"num_steps": 5})
    with pytest.raises(TypeError, match="unexpected keyword argument 'noise'"):
        infer_action(chain, None, {"z": Z}, noise={"y": Z})


def test_composing_a_posterior_of_another_graph_is_refused(chain):
    other = WorldModel(
        CausalGraph([Variable(n, "observed") for n in "xyz"], [("x", "y"), ("y", "z"), ("x", "z")]),
        seed=0,
        kind="linear",
    )
    state = infer_state(other, {"x": torch.ones(1, 1), "z": Z}, guide="grid")
    with pytest.raises(ValueError, match=r"posterior was made for another graph.*\('x', 'z'\)"):
        counterfactual(chain, {"x": torch.ones(1, 1), "z": Z}, {"x": 0.0}, posterior=state)
    with pytest.raises(ValueError, match="not sites of the program"):
        Intervene({"w": 1.0})(chain)
    with pytest.raises(ValueError, match="not sites of the program"), Intervene({"w": 1.0}):
        infer_state(chain, {"z": Z})


def test_a_posterior_from_other_evidence_is_refused(chain):
    state = infer_state(chain, {"x": torch.ones(1, 1), "z": Z}, guide="grid")
    with pytest.raises(ValueError, match="other evidence for 'z'"):
        counterfactual(chain, {"x": torch.ones(1, 1), "z": Z + 1}, {"x": 0.0}, posterior=state)


def test_results_are_frozen_with_to_dict(chain):
    import json

    state = infer_state(chain, {"x": torch.ones(1, 1), "z": Z}, guide="grid")
    cf = counterfactual(chain, {"x": torch.ones(1, 1), "z": Z}, {"x": 0.0}, posterior=state)
    for result in (state, cf):
        json.dumps(result.to_dict())
        with pytest.raises(AttributeError):
            result.samples = {}
    assert math.isfinite(state.to_dict()["sd"]["y"][0][0])
    assert chain_graph() == state.graph
