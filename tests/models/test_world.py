import pyro
import pytest
import torch

from models import (
    CausalGraph,
    FunctionMechanism,
    LinearMechanism,
    MLPMechanism,
    Variable,
    WorldModel,
    chain_graph,
    finger_graph,
)


@pytest.fixture
def chain():
    """Y = 2X + U_y, Z = -1.5Y + U_z."""
    return WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients([[2.0]]), "z": LinearMechanism.from_coefficients([[-1.5]])},
    )


def test_default_mechanism_is_thesis_mlp():
    m = WorldModel(finger_graph("state"))
    mech = m.mechanism("dq.finger")
    assert isinstance(mech, MLPMechanism)
    assert mech.hidden == (32, 32) and mech.activation == "tanh"
    assert mech.in_dim == 2 and mech.out_dim == 1
    with pytest.raises(ValueError, match="is a root and has no mechanism"):
        m.mechanism("act.finger")


def test_program_sites_in_topological_order_with_obs(chain):
    data = {"x": torch.ones(4, 1), "z": torch.zeros(4, 1)}
    tr = pyro.poutine.trace(chain).get_trace(data)
    sites = [k for k, s in tr.nodes.items() if s["type"] == "sample" and k != "units"]
    assert sites == ["x", "y", "z"]
    assert tr.nodes["x"]["is_observed"] and tr.nodes["z"]["is_observed"]
    assert not tr.nodes["y"]["is_observed"]
    assert tr.nodes["y"]["fn"].batch_shape == (4,) and tr.nodes["y"]["fn"].event_shape == (1,)
    # log p(y | x) is the Normal(2x, 1) density
    y = tr.nodes["y"]["value"]
    expected = torch.distributions.Normal(2.0, 1.0).log_prob(y).sum(-1)
    torch.testing.assert_close(tr.nodes["y"]["fn"].log_prob(y), expected)


def test_actions_are_uniform_roots():
    m = WorldModel(finger_graph())
    tr = pyro.poutine.trace(m).get_trace(None, n=1000)
    a = tr.nodes["act.finger"]["value"]
    assert a.min() >= -1.0 and a.max() < 0.33


def test_predict_expected_and_given(chain):
    out = chain.predict({"x": torch.tensor([[1.0], [2.0]])})
    torch.testing.assert_close(out["y"], torch.tensor([[2.0], [4.0]]))
    torch.testing.assert_close(out["z"], torch.tensor([[-3.0], [-6.0]]))
    # an assigned non-root keeps its value (Alg. 4.1 line 7) and its children follow it
    out = chain.predict({"x": torch.tensor([[1.0]]), "y": torch.tensor([[0.0]])})
    torch.testing.assert_close(out["z"], torch.tensor([[0.0]]))


def test_predict_with_given_noise_and_residuals_round_trip(chain):
    values = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-3.0]])}
    eps = chain.residuals(values)
    torch.testing.assert_close(eps["y"], torch.tensor([[0.5]]))
    torch.testing.assert_close(eps["z"], torch.tensor([[0.75]]))
    back = chain.predict({"x": values["x"]}, noise=eps)
    for k in values:
        torch.testing.assert_close(back[k], values[k])


def test_predict_has_no_autograd_history_unless_asked():
    m = WorldModel(finger_graph("thesis"))
    x = {"act.finger": torch.zeros(2, 1), "q_prev.finger": torch.zeros(2, 1)}
    assert not m.predict(x)["q.finger"].requires_grad
    assert m.predict(x, grad=True)["q.finger"].requires_grad


def test_scalar_coefficient():
    mech = LinearMechanism.from_coefficients(2.0, bias=1.0, sigma=0.5)
    torch.testing.assert_close(mech(torch.tensor([[3.0]])).detach(), torch.tensor([[7.0]]))
    torch.testing.assert_close(mech.sigma.detach(), torch.tensor([0.5]))


def test_sampled_noise_is_seeded_and_has_the_right_scale(chain):
    x = torch.zeros(20000, 1)
    a = chain.predict({"x": x}, "sampled", torch.Generator().manual_seed(1))
    b = chain.predict({"x": x}, "sampled", torch.Generator().manual_seed(1))
    torch.testing.assert_close(a["z"], b["z"])
    # Var(Z) = 1.5^2 * 1 + 1 = 3.25 when X = 0
    assert abs(float(a["z"].var()) - 3.25) < 0.1


def test_sample_draws_observational_distribution(chain):
    chain.set_root_prior("x", 1.0, 2.0)
    s = chain.sample(50000, torch.Generator().manual_seed(0))
    assert abs(float(s["x"].mean()) - 1.0) < 0.05
    assert abs(float(s["y"].mean()) - 2.0) < 0.1
    assert abs(float(s["y"].var()) - (4 * 4 + 1)) < 0.5


def test_rollout_feeds_lag0_into_lag1_slots():
    g = CausalGraph(
        [
            Variable("a", "action", bounds=(-1, 1)),
            Variable("q_prev", "observed", lag=1, lag_of="q"),
            Variable("q", "latent"),
        ],
        [("a", "q"), ("q_prev", "q")],
    )
    m = WorldModel(g, {"q": LinearMechanism.from_coefficients([[1.0, 0.5]], bias=0.1)})
    actions = torch.tensor([[[1.0], [0.0], [-1.0]]])  # (N=1, H=3, 1)
    traj = m.rollout({"q_prev": torch.tensor([[2.0]])}, {"a": actions})
    # q_t = a_t + 0.5 q_{t-1} + 0.1
    q = 2.0
    expected = []
    for a in (1.0, 0.0, -1.0):
        q = a + 0.5 * q + 0.1
        expected.append(q)
    torch.testing.assert_close(traj["q"][0, :, 0], torch.tensor(expected))
    torch.testing.assert_close(traj["q_prev"][0, 1:, 0], torch.tensor(expected[:-1]))
    # abducted residuals reused at every step shift every step by sigma * eps
    traj2 = m.rollout({"q_prev": torch.tensor([[2.0]])}, {"a": actions}, noise={"q": torch.tensor([[1.0]])})
    assert float((traj2["q"] - traj["q"])[0, 0, 0]) == pytest.approx(1.0)


def test_rollout_assign_sets_a_non_root_at_every_step():
    g = CausalGraph(
        [
            Variable("a", "action", bounds=(-1, 1)),
            Variable("q_prev", "observed", lag=1, lag_of="q"),
            Variable("q", "latent"),
            Variable("y", "latent"),
        ],
        [("a", "q"), ("q_prev", "q"), ("q", "y")],
    )
    m = WorldModel(
        g,
        {
            "q": LinearMechanism.from_coefficients([[1.0, 0.5]], bias=0.1),
            "y": LinearMechanism.from_coefficients([[2.0]]),
        },
    )
    actions = torch.zeros(2, 3, 1)
    forced = torch.tensor([[[1.0], [2.0], [3.0]], [[-1.0], [0.0], [4.0]]])  # (N=2, H=3, 1)
    traj = m.rollout({"q_prev": torch.zeros(2, 1)}, {"a": actions}, assign={"q": forced})
    torch.testing.assert_close(traj["q"], forced)  # do(q_t = forced_t), not a + 0.5 q_prev + 0.1
    torch.testing.assert_close(traj["y"], 2.0 * forced)  # descendants read the assigned value
    torch.testing.assert_close(traj["q_prev"][:, 1:], forced[:, :-1])  # the lag slot carries it on
    members = m.rollout({"q_prev": torch.zeros(2, 1)}, {"a": actions}, members=True, assign={"q": forced})
    torch.testing.assert_close(members["y"][0], 2.0 * forced)
    with pytest.raises(ValueError, match="assign sets roots \\['a'\\]"):
        m.rollout({"q_prev": torch.zeros(2, 1)}, {"a": actions}, assign={"a": actions})
    with pytest.raises(ValueError, match="assign\\['q'\\] has shape \\(2, 2, 1\\)"):
        m.rollout({"q_prev": torch.zeros(2, 1)}, {"a": actions}, assign={"q": forced[:, :2]})


def test_rollout_is_batched_and_checks_inputs():
    m = WorldModel(finger_graph("state"))
    traj = m.rollout({"q_prev.finger": torch.zeros(5, 1)}, {"act.finger": torch.zeros(5, 4, 1)})
    assert traj["q.finger"].shape == (5, 4, 1)
    with pytest.raises(ValueError, match="missing \\['q_prev.finger'\\]"):
        m.rollout({}, {"act.finger": torch.zeros(5, 4, 1)})
    with pytest.raises(ValueError, match="expected \\(N, T, 1\\)"):
        m.rollout({"q_prev.finger": torch.zeros(5, 1)}, {"act.finger": torch.zeros(5, 1)})


def test_vector_valued_variables():
    g = CausalGraph(
        [Variable("a", "action", dim=2, bounds=([-1, -1], [1, 1])), Variable("p", "latent", dim=3)],
        [("a", "p")],
    )
    w = torch.arange(6.0).reshape(3, 2)
    m = WorldModel(
        g, {"p": LinearMechanism.from_coefficients(w, bias=[1.0, 2.0, 3.0], sigma=[0.1, 0.2, 0.3])}
    )
    a = torch.tensor([[1.0, -1.0], [0.5, 0.5]])
    out = m.predict({"a": a})
    torch.testing.assert_close(out["p"], a @ w.T + torch.tensor([1.0, 2.0, 3.0]))
    tr = pyro.poutine.trace(m).get_trace({"a": a})
    assert tr.nodes["p"]["fn"].event_shape == (3,)
    torch.testing.assert_close(m.sigma("p"), torch.tensor([0.1, 0.2, 0.3]))


def test_function_mechanism_and_dim_checks():
    mech = FunctionMechanism(torch.sin, 1, 1, sigma=0.5)
    m = WorldModel(chain_graph(), {"y": mech})
    out = m.predict({"x": torch.tensor([[0.5]])})
    torch.testing.assert_close(out["y"], torch.sin(torch.tensor([[0.5]])))
    with pytest.raises(ValueError, match="maps 2 -> 1, expected 1"):
        WorldModel(chain_graph(), {"y": LinearMechanism(2, 1)})
    with pytest.raises(ValueError, match="'x' is a root"):
        WorldModel(chain_graph(), {"x": LinearMechanism(1, 1)})


@pytest.mark.parametrize(
    ("values", "match"),
    [
        ({"x": torch.ones(3)}, "expected \\(N, 1\\).*x\\[:, None\\]"),
        ({"x": torch.ones(3, 2)}, "expected \\(N, 1\\)"),
        ({"x": torch.tensor([[1.0], [float("nan")]])}, "NaN or inf"),
        ({"x": torch.tensor([[float("inf")]])}, "NaN or inf"),
        ({"w": torch.ones(3, 1)}, "unknown variable in values 'w'"),
        ({"x": torch.ones(3, 1), "y": torch.ones(2, 1)}, "has 2 rows, expected 3"),
    ],
)
def test_predict_rejects_bad_values(chain, values, match):
    with pytest.raises(ValueError, match=match):
        chain.predict(values)


def test_predict_needs_roots_and_complete_noise(chain):
    with pytest.raises(ValueError, match="missing \\['x'\\]"):
        chain.predict({"y": torch.ones(2, 1)})
    with pytest.raises(ValueError, match="no residual for 'z'"):
        chain.predict({"x": torch.ones(2, 1)}, noise={"y": torch.zeros(2, 1)})
    with pytest.raises(ValueError, match="noise 'bogus' unknown"):
        chain.predict({"x": torch.ones(2, 1)}, noise="bogus")


def test_mechanism_validation():
    with pytest.raises(ValueError, match="activation 'nope' unknown"):
        MLPMechanism(1, 1, activation="nope")
    mech = LinearMechanism(1, 2)
    with pytest.raises(ValueError, match="sigma must be > 0"):
        mech.set_sigma([1.0, -1.0])
    with pytest.raises(ValueError, match="has 3 entries, expected 2"):
        mech.set_sigma([1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="last dim 3, expected 1"):
        mech(torch.ones(4, 3))
