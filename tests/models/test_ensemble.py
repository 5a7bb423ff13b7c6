"""Ensemble mechanisms: the moment-matched site, the member axis of predict and rollout."""

import pyro
import pytest
import torch

from models import (
    CausalGraph,
    EnsembleMechanism,
    FunctionMechanism,
    HeteroscedasticMechanism,
    LinearMechanism,
    MLPMechanism,
    Variable,
    WorldModel,
    chain_graph,
    finger_graph,
)
from models.ensemble import member_seeds
from models.mechanisms import make_mechanism

W_Y, B_Y, S_Y = (2.0, 1.0), (0.0, 0.5), (0.5, 1.0)
W_Z = (-1.5, -0.5)


def lin(w, b=0.0, s=1.0):
    return LinearMechanism.from_coefficients([[w]], bias=b, sigma=s)


@pytest.fixture
def chain():
    """X -> Y -> Z with two linear members at Y and at Z."""
    return WorldModel(
        chain_graph(),
        {
            "y": EnsembleMechanism([lin(W_Y[k], B_Y[k], S_Y[k]) for k in range(2)]),
            "z": EnsembleMechanism([lin(W_Z[k]) for k in range(2)]),
        },
    )


def test_the_site_is_the_moment_matched_normal_of_the_members(chain):
    x = torch.tensor([[1.0], [-2.0]])
    mech = chain.mechanism("y")
    m = torch.stack([W_Y[k] * x + B_Y[k] for k in range(2)])
    loc = m.mean(0)
    aleatoric = torch.tensor(S_Y).pow(2).mean()
    epistemic = (m - loc).pow(2).mean(0)
    got_loc, got_scale = mech.loc_scale(x)
    torch.testing.assert_close(got_loc, loc)
    torch.testing.assert_close(got_scale, (aleatoric + epistemic).sqrt())
    torch.testing.assert_close(mech(x), loc)
    _, alea, epi = mech.variance(x)
    torch.testing.assert_close(alea, aleatoric.expand(2, 1))
    torch.testing.assert_close(epi, epistemic)
    locs, scales = mech.member_loc_scale(x)
    assert locs.shape == (2, 2, 1) and torch.equal(scales[1], torch.ones(2, 1))
    # the Pyro site is that Normal
    y = torch.tensor([[0.0], [1.0]])
    tr = pyro.poutine.trace(chain).get_trace({"x": x, "y": y, "z": torch.zeros(2, 1)})
    expected = torch.distributions.Normal(loc, (aleatoric + epistemic).sqrt()).log_prob(y).sum(-1)
    torch.testing.assert_close(tr.nodes["y"]["fn"].log_prob(y), expected)
    assert mech.heteroscedastic and mech.size == 2
    with pytest.raises(ValueError, match="ensemble of 2 members has a scale that depends on the parents"):
        chain.sigma("y")


def test_predict_members_feeds_member_k_of_a_site_from_member_k_of_its_parents(chain):
    x = torch.tensor([[1.0], [3.0], [-1.0]])
    out = chain.predict({"x": x}, members=True)
    assert chain.ensemble_size == 2
    assert out["x"].shape == out["y"].shape == out["z"].shape == (2, 3, 1)
    for k in range(2):
        y_k = W_Y[k] * x + B_Y[k]
        torch.testing.assert_close(out["x"][k], x)
        torch.testing.assert_close(out["y"][k], y_k)
        torch.testing.assert_close(out["z"][k], W_Z[k] * y_k)
    # without members: the moment-matched locs compose
    mean = chain.predict({"x": x})
    y_bar = sum(W_Y[k] * x + B_Y[k] for k in range(2)) / 2
    torch.testing.assert_close(mean["y"], y_bar)
    torch.testing.assert_close(mean["z"], sum(W_Z) / 2 * y_bar)


def test_member_residuals_are_shared_and_scaled_by_each_members_own_sigma(chain):
    x = torch.tensor([[1.0], [2.0]])
    eps = {"y": torch.tensor([[1.0], [-2.0]]), "z": torch.tensor([[0.5], [0.0]])}
    out = chain.predict({"x": x}, noise=eps, members=True)
    for k in range(2):
        y_k = W_Y[k] * x + B_Y[k] + S_Y[k] * eps["y"]
        torch.testing.assert_close(out["y"][k], y_k)
        torch.testing.assert_close(out["z"][k], W_Z[k] * y_k + eps["z"])
    a = chain.predict({"x": x}, "sampled", torch.Generator().manual_seed(4), members=True)
    b = chain.predict({"x": x}, "sampled", torch.Generator().manual_seed(4), members=True)
    torch.testing.assert_close(a["z"], b["z"])


def test_a_site_without_an_ensemble_applies_its_mechanism_to_each_member():
    model = WorldModel(chain_graph(), {"y": EnsembleMechanism([lin(1.0), lin(3.0)]), "z": lin(-1.0, b=2.0)})
    out = model.predict({"x": torch.tensor([[1.0]])}, members=True)
    torch.testing.assert_close(out["z"][:, 0, 0], torch.tensor([1.0, -1.0]))


def test_a_model_without_ensembles_has_one_member():
    model = WorldModel(finger_graph("state"), seed=0, hidden=(4,))
    values = {"act.finger": torch.rand(5, 1) - 0.5, "q_prev.finger": torch.randn(5, 1)}
    single, stacked = model.predict(values), model.predict(values, members=True)
    assert model.ensemble_size == 1
    for k, v in single.items():
        assert stacked[k].shape == (1, *v.shape)
        torch.testing.assert_close(stacked[k][0], v)


def test_rollout_members_runs_each_member_on_its_own_trajectory():
    g = finger_graph("state")
    model = WorldModel(g, seed=1, hidden=(4,), members=3)
    init = {"q_prev.finger": torch.tensor([[0.2], [-0.3]])}
    acts = {"act.finger": torch.rand(2, 4, 1, generator=torch.Generator().manual_seed(0)) - 0.6}
    traj = model.rollout(init, acts, members=True)
    assert traj["q.finger"].shape == (3, 2, 4, 1) and traj["act.finger"].shape == (3, 2, 4, 1)
    for k in range(3):
        single = WorldModel(g, {n: model.mechanism(n).members[k] for n in g.non_roots}).rollout(init, acts)
        for name in g.names:
            torch.testing.assert_close(traj[name][k], single[name])
    mean = model.rollout(init, acts)
    assert mean["q.finger"].shape == (2, 4, 1)


def test_predict_scale_splits_aleatoric_and_epistemic(chain):
    x = torch.tensor([[1.0], [-2.0]])
    total = chain.predict_scale({"x": x})
    alea = chain.predict_scale({"x": x}, component="aleatoric")
    epi = chain.predict_scale({"x": x}, component="epistemic")
    torch.testing.assert_close(total["y"] ** 2, alea["y"] ** 2 + epi["y"] ** 2)
    torch.testing.assert_close(alea["y"], torch.tensor(S_Y).pow(2).mean().sqrt().expand(2, 1))
    m = torch.stack([W_Y[k] * x + B_Y[k] for k in range(2)])
    torch.testing.assert_close(epi["y"], (m - m.mean(0)).pow(2).mean(0).sqrt())
    # Z's parent is filled with the expected Y before its scale is taken
    y_bar = m.mean(0)
    mz = torch.stack([W_Z[k] * y_bar for k in range(2)])
    torch.testing.assert_close(epi["z"], (mz - mz.mean(0)).pow(2).mean(0).sqrt())
    # a homoscedastic site: sigma, no epistemic part
    plain = WorldModel(chain_graph(), {"y": lin(2.0, s=0.3), "z": lin(1.0)})
    scales = plain.predict_scale({"x": x})
    torch.testing.assert_close(scales["y"], torch.full((2, 1), 0.3))
    assert torch.all(plain.predict_scale({"x": x}, component="epistemic")["y"] == 0)
    with pytest.raises(ValueError, match="component 'both' unknown"):
        plain.predict_scale({"x": x}, component="both")


def test_world_model_members_k_wraps_every_default_mechanism_with_its_own_seed_stream():
    a = WorldModel(finger_graph("state"), seed=5, members=4, hidden=(3,))
    b = WorldModel(finger_graph("state"), seed=5, members=4, hidden=(3,))
    mech = a.mechanism("dq.finger")
    assert isinstance(mech, EnsembleMechanism) and mech.size == 4
    assert all(isinstance(m, MLPMechanism) for m in mech.members)
    w = [m.net[0].weight for m in mech.members]
    assert not torch.equal(w[0], w[1])
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert torch.equal(x, y), k
    hetero = WorldModel(finger_graph("state"), seed=0, kind="hetero", members=2, hidden=(3,))
    assert all(isinstance(m, HeteroscedasticMechanism) for m in hetero.mechanism("q.finger").members)
    seeds = [g.initial_seed() for g in member_seeds(7, 3)]
    assert seeds == [g.initial_seed() for g in member_seeds(7, 3)] and len(set(seeds)) == 3


def test_ensembles_of_different_sizes_have_no_common_member_axis():
    model = WorldModel(
        chain_graph(),
        {"y": EnsembleMechanism([lin(1.0), lin(2.0)]), "z": EnsembleMechanism([lin(1.0)] * 3)},
    )
    model.predict({"x": torch.ones(1, 1)})  # the moment-matched sites still work
    with pytest.raises(ValueError, match="ensembles have different sizes \\{'y': 2, 'z': 3\\}"):
        model.predict({"x": torch.ones(1, 1)}, members=True)


def test_one_member_is_the_member_itself():
    member = lin(2.0, b=1.0, s=0.7)
    ens = EnsembleMechanism([member])
    x = torch.tensor([[0.5]])
    assert not ens.heteroscedastic and float(ens.sigma.detach()) == pytest.approx(0.7)
    for a, b in zip(ens.loc_scale(x), member.loc_scale(x), strict=True):
        assert torch.equal(a, b)
    ens.set_sigma(0.2)
    assert float(member.sigma.detach()) == pytest.approx(0.2)


def test_config_round_trip_and_rewiring():
    ens = EnsembleMechanism.replicate(lambda g: MLPMechanism(2, 1, hidden=(3,), seed=g), 3, seed=0)
    cfg = ens.config()
    assert cfg["kind"] == "ensemble" and len(cfg["members"]) == 3
    again = make_mechanism(cfg)
    again.load_state_dict(ens.state_dict())
    x = torch.randn(4, 2, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(again.loc_scale(x)[1], ens.loc_scale(x)[1])
    model = WorldModel(finger_graph("thesis"), seed=0, members=2, hidden=(3,))
    bigger = model.with_graph(finger_graph("state"))
    assert bigger.provenance["warm_start"]["dq.finger"] == "rewired"
    act = torch.tensor([[0.1]])
    q = torch.tensor([[0.4]])
    before = model.mechanism("dq.finger").loc_scale(act)
    after = bigger.mechanism("dq.finger").loc_scale(torch.cat([act, q], -1))
    for a, b in zip(before, after, strict=True):
        torch.testing.assert_close(a, b)


@pytest.mark.parametrize(
    ("members", "match"),
    [
        ([], "an ensemble needs at least 1 member (ensemble size must be >= 1), got 0"),
        ("ab", "members must be a list of Mechanism"),
        (lin(1.0), "members must be a list of Mechanism"),
        ([lin(1.0), "x"], "ensemble member 1 must be a Mechanism"),
        ([lin(1.0), MLPMechanism(1, 1, seed=0)], "ensemble members must be of one kind"),
        ([lin(1.0), LinearMechanism(2, 1, seed=0)], "ensemble members must share in_dim and out_dim"),
        ([EnsembleMechanism([lin(1.0)])], "ensemble member 0 is itself an ensemble"),
    ],
)
def test_bad_ensembles(members, match):
    with pytest.raises(ValueError, match=match.replace("(", r"\(").replace(")", r"\)")):
        EnsembleMechanism(members)


def test_bad_ensemble_sizes_name_the_value():
    with pytest.raises(ValueError, match="members must be a positive int, got 0"):
        WorldModel(finger_graph(), members=0)
    with pytest.raises(ValueError, match="members must be a positive int, got -2"):
        EnsembleMechanism.replicate(lambda g: lin(1.0), -2)
    with pytest.raises(ValueError, match="'members', a non-empty list"):
        make_mechanism({"kind": "ensemble", "members": []})


def test_function_members_are_not_trainable_and_dims_are_checked():
    ens = EnsembleMechanism([FunctionMechanism(torch.sin, 1), FunctionMechanism(torch.cos, 1)])
    assert not ens.trainable
    with pytest.raises(ValueError, match="paired parents have shape \\(3, 1\\), expected \\(2, ..., 1\\)"):
        ens.member_loc_scale(torch.zeros(3, 1), paired=True)
    g = CausalGraph([Variable("x", "observed"), Variable("y", "latent")], [("x", "y")])
    with pytest.raises(ValueError, match="maps 2 -> 1, expected 1"):
        WorldModel(g, {"y": EnsembleMechanism([LinearMechanism(2, 1, seed=0)])})


class _Counting(LinearMechanism):
    """A known linear law that records the batch shapes it is asked for."""

    shapes: list

    def loc_scale(self, z):
        self.shapes.append(tuple(z.shape))
        return super().loc_scale(z)


def test_a_known_law_of_inputs_the_members_share_runs_once_and_one_fed_by_members_per_member():
    known = _Counting(1, 1, sigma=0.1)
    known.shapes = []
    with torch.no_grad():
        known.linear.weight.fill_(3.0)
        known.linear.bias.zero_()
    # x -> y (the known law, shared by the members) -> z (two members); z has no successor here
    model = WorldModel(chain_graph(), {"y": known, "z": EnsembleMechanism([lin(W_Z[k]) for k in range(2)])})
    x = torch.tensor([[1.0], [-2.0], [0.5]])
    out = model.predict({"x": x}, members=True)
    assert known.shapes == [(3, 1)]  # once on member 0's rows, not on (2, 3, 1)
    torch.testing.assert_close(out["y"], (3.0 * x).expand(2, 3, 1))
    torch.testing.assert_close(out["z"], torch.stack([W_Z[k] * 3.0 * x for k in range(2)]))
    # member-specific parents: a chain whose y is an ensemble feeds z per member
    chained = WorldModel(
        chain_graph(), {"y": EnsembleMechanism([lin(W_Y[k], B_Y[k]) for k in range(2)]), "z": known}
    )
    known.shapes.clear()
    chained.predict({"x": x}, members=True)
    assert known.shapes == [(2, 3, 1)]
