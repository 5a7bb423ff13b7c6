"""Forward kinematics of a hinge chain as a fixed mechanism, against the planar two-link arm's closed form."""

import math

import pytest
import torch

from models import (
    CausalGraph,
    JointLimitMechanism,
    KinematicChain,
    KinematicMechanism,
    Variable,
    WorldModel,
    load,
    save,
)
from models.mechanisms import make_mechanism

L1, L2 = 0.3, 0.2


def planar_arm(limits=((-math.inf, math.inf), (-math.inf, math.inf))):
    """Two hinges about z, the second L1 along x from the first, the end L2 further."""
    eye = torch.eye(3).expand(2, 3, 3)
    return KinematicChain(
        rotations=eye,
        translations=[[0.0, 0.0, 0.0], [L1, 0.0, 0.0]],
        anchors=torch.zeros(2, 3),
        axes=[[0.0, 0.0, 2.0], [0.0, 0.0, 1.0]],  # normalised by the chain
        refs=[0.0, 0.0],
        end=[L2, 0.0, 0.0],
        limits=limits,
    )


def closed_form(q):
    a, b = q[..., 0], q[..., 1]
    return torch.stack(
        [L1 * a.cos() + L2 * (a + b).cos(), L1 * a.sin() + L2 * (a + b).sin(), torch.zeros_like(a)], -1
    )


def test_the_chain_is_the_planar_arm_closed_form_and_clips_at_its_limits():
    q = torch.rand(64, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 6 - 3
    torch.testing.assert_close(planar_arm()(q), closed_form(q), atol=1e-12, rtol=0)
    limited = planar_arm(limits=((-1.0, 1.0), (-0.5, 0.5)))
    clipped = limited.clip(torch.tensor([[2.0, -2.0], [0.3, 0.1]], dtype=torch.float64))
    torch.testing.assert_close(clipped, torch.tensor([[1.0, -0.5], [0.3, 0.1]], dtype=torch.float64))


def test_an_anchor_off_the_origin_turns_about_that_point():
    chain = KinematicChain(
        torch.eye(3)[None],
        [[0.0, 0.0, 0.0]],
        [[1.0, 0.0, 0.0]],
        [[0.0, 0.0, 1.0]],
        [0.0],
        [0.0, 0.0, 0.0],
        [[-9, 9]],
    )
    # the base origin turned by 90 degrees about (1, 0, 0) lands at (1, -1, 0)
    torch.testing.assert_close(
        chain(torch.tensor([math.pi / 2], dtype=torch.float64)),
        torch.tensor([1.0, -1.0, 0.0], dtype=torch.float64),
        atol=1e-12,
        rtol=0,
    )


def test_the_mechanism_is_the_effector_motion_with_angles_held_at_the_limits():
    chain = planar_arm(limits=((-1.0, 1.0), (-2.0, 2.0)))
    # the joint vector has 3 entries; the chain reads columns 2 and 0
    mech = KinematicMechanism(chain, columns=[2, 0], joints=3, out_dim=2)
    q_prev = torch.tensor([[0.4, 9.0, 0.5]], dtype=torch.float64)
    dq = torch.tensor([[0.2, 5.0, 0.9]], dtype=torch.float64)  # joint a would reach 1.4: held at 1.0
    got = mech(torch.cat([q_prev, dq], -1).float())
    before = closed_form(torch.tensor([[0.5, 0.4]], dtype=torch.float64))
    after = closed_form(torch.tensor([[1.0, 0.6]], dtype=torch.float64))
    torch.testing.assert_close(got.double(), (after - before)[:, :2], atol=1e-6, rtol=0)
    assert not mech.trainable and mech.in_dim == 6 and mech.out_dim == 2


def test_a_model_with_the_mechanism_saves_and_loads(tmp_path):
    graph = CausalGraph(
        [Variable("q_prev", "observed", 2), Variable("dq", "observed", 2), Variable("dee", "latent", 3)],
        [("q_prev", "dee"), ("dq", "dee")],
    )
    mech = KinematicMechanism(planar_arm(limits=((-1.0, 1.0), (-2.0, 2.0))), columns=[0, 1], joints=2)
    model = WorldModel(graph, {"dee": mech})
    save(model, tmp_path / "m")
    loaded = load(tmp_path / "m")
    x = torch.tensor([[0.3, -0.2, 0.1, 0.4]])
    torch.testing.assert_close(loaded.mechanism("dee")(x), mech(x))
    assert make_mechanism(mech.config()).columns == (0, 1)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"columns": [0, 0]}, "distinct joint indices below 2"),
        ({"columns": [0, 2]}, "distinct joint indices below 2"),
        ({"out_dim": 4}, "out_dim must be 1-3"),
        ({"in_dim": 5}, "in_dim must be 2 n = 4"),
        ({"sigma": 0.0}, "sigma"),
    ],
)
def test_bad_mechanism_arguments_name_the_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        KinematicMechanism(planar_arm(), **{"columns": [0, 1], "joints": 2, **kwargs})


def test_bad_chains_name_the_value():
    args = dict(
        rotations=torch.eye(3)[None], translations=[[0, 0, 0]], anchors=[[0, 0, 0]], refs=[0.0], end=[1, 0, 0]
    )
    with pytest.raises(ValueError, match="axes must be nonzero"):
        KinematicChain(**args, axes=[[0, 0, 0]], limits=[[-1, 1]])
    with pytest.raises(ValueError, match="low <= high"):
        KinematicChain(**args, axes=[[0, 0, 1]], limits=[[1, -1]])
    with pytest.raises(ValueError, match=r"translations must have shape \(1, 3\)"):
        KinematicChain(**{**args, "translations": [[0, 0]]}, axes=[[0, 0, 1]], limits=[[-1, 1]])
    with pytest.raises(ValueError, match="last dim 3, expected 1"):
        KinematicChain(**args, axes=[[0, 0, 1]], limits=[[-1, 1]])(torch.zeros(3))


def test_a_loaded_state_replaces_the_derived_terms_too():
    chain, other = planar_arm(), planar_arm()
    with torch.no_grad():
        other.translations[1, 0] = 0.5  # a longer first link
    chain.load_state_dict(other.state_dict())
    q = torch.tensor([[0.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(chain(q), torch.tensor([[0.5 + L2, 0.0, 0.0]], dtype=torch.float64))
    with pytest.raises(ValueError, match="float32 or float64"):
        chain(q.half())


def test_joint_limits_hold_the_angles_and_an_open_side_round_trips_as_none():
    mech = JointLimitMechanism([[None, 1.0], [-2.0, None]])
    out = mech(torch.tensor([[0.8, -1.5, 0.5, -1.0]]))  # q_prev + dq = (1.3, -2.5)
    torch.testing.assert_close(out, torch.tensor([[1.0, -2.0]]))
    out = mech(torch.tensor([[-50.0, 40.0, 0.0, 5.0]]))  # the open sides do not hold
    torch.testing.assert_close(out, torch.tensor([[-50.0, 45.0]]))
    assert mech.config()["limits"] == [[None, 1.0], [-2.0, None]]
    assert make_mechanism(mech.config()).limits.tolist() == mech.limits.tolist()
    with pytest.raises(ValueError, match="low <= high"):
        JointLimitMechanism([[1.0, -1.0]])
    with pytest.raises(ValueError, match="pairs"):
        JointLimitMechanism([[1.0]])
    with pytest.raises(ValueError, match="in_dim must be 2 n = 4"):
        JointLimitMechanism([[0, 1], [0, 1]], in_dim=3)
