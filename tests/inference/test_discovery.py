"""Structure learning on small SCMs with known graphs (fixed seeds, exact recovery)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inference import DiscoveryOptions, admissible_parents, discover, shd
from inference.admissible import StructureData
from inference.design import choose_interventions, orientation_margins
from models import CausalGraph, Role, Variable, finger_graph


def scalars(*names: str) -> list[Variable]:
    return [Variable(n, Role.OBSERVED) for n in names]


def col(a: np.ndarray) -> np.ndarray:
    return a[:, None]


N = 600


def chain_data(rng: np.random.Generator) -> dict[str, np.ndarray]:
    x = rng.normal(size=N)
    y = np.tanh(2 * x) + 0.5 * x + 0.3 * rng.normal(size=N)
    z = np.sin(2 * y) + 0.3 * rng.normal(size=N)
    return {"x": col(x), "y": col(y), "z": col(z)}


def fork_data(rng: np.random.Generator) -> dict[str, np.ndarray]:
    x = rng.normal(size=N)
    y = np.tanh(2 * x) + 0.3 * rng.normal(size=N)
    z = x**2 - 1 + 0.3 * rng.normal(size=N)
    return {"x": col(x), "y": col(y), "z": col(z)}


def collider_data(rng: np.random.Generator) -> dict[str, np.ndarray]:
    x, y = rng.normal(size=N), rng.normal(size=N)
    z = np.tanh(x) + np.sin(y) + 0.3 * rng.normal(size=N)
    return {"x": col(x), "y": col(y), "z": col(z)}


@pytest.mark.parametrize(
    "make, edges",
    [
        (chain_data, {("x", "y"), ("y", "z")}),
        (fork_data, {("x", "y"), ("x", "z")}),
        (collider_data, {("x", "z"), ("y", "z")}),
    ],
    ids=["chain", "fork", "collider"],
)
def test_recovers_small_nonlinear_graphs(make, edges, rng):
    result = discover(scalars("x", "y", "z"), make(rng), seed=0)
    assert set(result.graph.edges) == edges
    assert shd(result.graph, edges) == 0
    for e in edges:
        assert 0.5 < result.graph.edge_confidence(*e) <= 1.0
        assert result.log_ratio[e] >= 3.0


@pytest.mark.parametrize("scale", [1e200, 1e-200, 1e300, 2.0**-1000])
def test_the_units_of_the_data_do_not_change_the_graph_or_its_scores(scale):
    data = chain_data(np.random.default_rng(3))
    plain = discover(scalars("x", "y", "z"), data, seed=0)
    scaled = discover(scalars("x", "y", "z"), {k: v * scale for k, v in data.items()}, seed=0)
    assert set(scaled.graph.edges) == set(plain.graph.edges) == {("x", "y"), ("y", "z")}
    for e, ratio in plain.log_ratio.items():
        assert scaled.log_ratio[e] == pytest.approx(ratio, rel=1e-6)


def test_standardising_leaves_ordinary_columns_bit_for_bit_and_scales_extreme_ones():
    rng = np.random.default_rng(4)
    x = rng.normal(3.0, 2.0, size=(50, 1))
    data = {"a": x, "b": x * 1e200, "c": x * 1e-200, "d": np.full((50, 1), 7.0)}
    sdata = StructureData.build(scalars("a", "b", "c", "d"), data)
    a = sdata.x[:, 0].numpy()
    t = torch.from_numpy(x[:, 0])
    assert np.array_equal(a, ((t - t.mean()) / t.std()).numpy())  # the plain formula, unchanged
    assert np.allclose(sdata.x[:, 1].numpy(), a, atol=1e-12) and np.allclose(
        sdata.x[:, 2].numpy(), a, atol=1e-12
    )
    assert np.all(sdata.x[:, 3].numpy() == 0.0)  # a constant column is only centred


def linear_pair(rng: np.random.Generator, n: int, do_x: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """x -> y, linear Gaussian: Markov equivalent to y -> x from observations alone."""
    x = rng.normal(size=n) if do_x is None else do_x
    y = 0.8 * x + 0.6 * rng.normal(size=n)
    return {"x": col(x), "y": col(y)}


def test_only_interventions_orient_a_linear_gaussian_edge(rng):
    variables = scalars("x", "y")
    obs = linear_pair(rng, 800)
    res_obs = discover(variables, obs, seed=0)
    assert len(res_obs.graph.edges) == 1
    # observationally both orientations have the same held-out likelihood (up to noise)
    margin = orientation_margins(res_obs, obs)[res_obs.graph.edges[0]]
    assert abs(margin) < 5.0
    # do(x) rows: x set by the experimenter, y still follows its mechanism
    forced = linear_pair(rng, 200, do_x=rng.uniform(-3, 3, 200))
    data = {k: np.concatenate([obs[k], forced[k]]) for k in obs}
    mask = {"x": np.r_[np.zeros(800, bool), np.ones(200, bool)]}
    res = discover(variables, data, intervened=mask, seed=0)
    assert res.graph.edges == (("x", "y"),)
    assert orientation_margins(res, data, intervened=mask)[("x", "y")] > 5.0
    # also when the observational search order started the other way round
    res_rev = discover([Variable("y", Role.OBSERVED), Variable("x", Role.OBSERVED)], data, intervened=mask)
    assert res_rev.graph.edges == (("x", "y"),)


def test_intervened_rows_carry_no_evidence_about_the_cut_mechanism(rng):
    x = rng.normal(size=1000)
    y = np.tanh(2 * x) + 0.2 * rng.normal(size=1000)
    cut = np.arange(1000) < 700  # do(y = noise) in 70 % of the rows
    y[cut] = rng.normal(size=int(cut.sum()))
    data = {"x": col(x), "y": col(y)}
    masked = discover(scalars("x", "y"), data, intervened={"y": cut}, seed=0)
    assert masked.graph.edges == (("x", "y"),)
    assert masked.log_ratio[("x", "y")] > 50
    sdata = StructureData.build(scalars("x", "y"), data, {"y": cut})
    assert int(sdata.rows["y"].sum()) == 300 and bool(sdata.rows["x"].all())


def test_admissibility_rules_and_background_knowledge():
    g = finger_graph("thesis")
    allowed = admissible_parents(g)
    assert allowed["act.finger"] == ()
    assert allowed["q_prev.finger"] == ()  # lag 1: no lag-0 parent, and the action is lag 0
    assert set(allowed["dq.finger"]) == {"act.finger", "q_prev.finger", "q.finger"}
    tiers = [["act.finger", "q_prev.finger"], ["dq.finger"], ["q.finger"]]
    allowed = admissible_parents(g, tiers=tiers, forbidden=[("act.finger", "q.finger")])
    assert allowed["dq.finger"] == ("act.finger", "q_prev.finger")
    assert allowed["q.finger"] == ("q_prev.finger", "dq.finger")
    with pytest.raises(ValueError, match="required edge 'q.finger' -> 'dq.finger' is not admissible"):
        admissible_parents(g, tiers=tiers, required=[("q.finger", "dq.finger")])
    with pytest.raises(ValueError, match="tier 0 names unknown variable 'nope'"):
        admissible_parents(g, tiers=[["nope"]])


def test_actions_stay_roots_and_time_runs_forward(rng):
    a = rng.uniform(-1, 1, N)
    q_prev = rng.normal(size=N)
    q = q_prev + np.tanh(2 * a) + 0.1 * rng.normal(size=N)
    variables = [
        Variable("a", Role.ACTION, bounds=(-1, 1)),
        Variable("q_prev", Role.OBSERVED, lag=1, lag_of="q"),
        Variable("q", Role.LATENT),
    ]
    res = discover(variables, {"a": col(a), "q_prev": col(q_prev), "q": col(q)}, seed=0)
    assert set(res.graph.edges) == {("a", "q"), ("q_prev", "q")}


def test_required_and_forbidden_edges_are_honoured(rng):
    data = chain_data(rng)
    res = discover(scalars("x", "y", "z"), data, forbidden=[("y", "z")], required=[("x", "z")], seed=0)
    assert ("y", "z") not in res.graph.edges and ("x", "z") in res.graph.edges


def test_bad_inputs_name_the_problem(rng):
    data = chain_data(rng)
    with pytest.raises(ValueError, match="missing \\['z'\\]"):
        discover(scalars("x", "y", "z"), {"x": data["x"], "y": data["y"]})
    with pytest.raises(ValueError, match="expected \\(N, 1\\)"):
        discover(scalars("x", "y", "z"), {**data, "z": data["z"][:, 0]})
    with pytest.raises(ValueError, match="intervened\\['y'\\] has shape"):
        discover(scalars("x", "y", "z"), data, intervened={"y": np.zeros(3, bool)})
    with pytest.raises(ValueError, match="sparsify 'lasso' unknown"):
        discover(scalars("x", "y", "z"), data, options=DiscoveryOptions(sparsify="lasso"))


def test_gated_sparsification_recovers_the_chain(rng):
    res = discover(
        scalars("x", "y", "z"),
        chain_data(rng),
        options=DiscoveryOptions(sparsify="gated", gated={"steps": 150}),
        seed=0,
    )
    assert set(res.graph.edges) == {("x", "y"), ("y", "z")}


def test_result_serialises_and_reports(rng):
    res = discover(scalars("x", "y", "z"), chain_data(rng), seed=0)
    d = res.to_dict()
    assert {e["child"] for e in d["edges"]} == {"y", "z"}
    back = CausalGraph.from_dict(d["graph"])
    assert back == res.graph and back.confidence == res.graph.confidence
    assert res.order.index("x") < res.order.index("y") < res.order.index("z")
    assert res.history[0][3] > 0 and res.seconds > 0


def test_design_spreads_the_budget_over_uncertain_variables(rng):
    obs = linear_pair(rng, 500)
    res = discover(scalars("x", "y"), obs, seed=0)
    margins = orientation_margins(res, obs)
    targets = choose_interventions(res, margins, 6)
    assert len(targets) == 6 and set(targets) <= {"x", "y"}
    assert choose_interventions(res, {e: math.inf for e in margins}, 0) == []
    with pytest.raises(ValueError, match="budget must be a non-negative int"):
        choose_interventions(res, margins, -1)


def test_learnt_confidence_survives_a_model_file(rng, tmp_path):
    from models import WorldModel, load, save

    res = discover(scalars("x", "y", "z"), chain_data(rng), seed=0)
    path = save(WorldModel(res.graph, hidden=(4,)), tmp_path / "m.npz")
    back = load(path, graph=res.graph.with_confidence({}))  # identity ignores confidence
    assert back.graph.confidence == res.graph.confidence
