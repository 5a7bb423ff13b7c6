"""The push frame: turning the scene about the vertical axis leaves its push-frame view unchanged."""

import math

import pytest
import torch

from models import KinematicChain, KinematicPointsMechanism
from models.push_frame import (
    FromPushFrameMechanism,
    PushFrameMechanism,
    frame_angle,
    from_push_frame,
    to_push_frame,
)


def _turned(v: torch.Tensor, angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    out = v.clone()
    out[..., 0], out[..., 1] = c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]
    return out


def test_the_effector_lies_on_the_frames_x_axis_and_the_round_trip_is_exact():
    g = torch.Generator().manual_seed(0)
    origin, effector = (
        torch.randn(50, 3, generator=g, dtype=torch.float64),
        torch.randn(50, 3, generator=g, dtype=torch.float64),
    )
    c, s = frame_angle(effector, origin)
    local = to_push_frame(effector - origin, c, s)
    torch.testing.assert_close(local[:, 0], (effector - origin)[:, :2].norm(dim=1), rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(local[:, 1:2], torch.zeros(50, 1, dtype=torch.float64), rtol=0, atol=1e-12)
    torch.testing.assert_close(local[:, 2], (effector - origin)[:, 2])  # the vertical is kept
    v = torch.randn(50, 4, 3, generator=g, dtype=torch.float64)
    back = from_push_frame(to_push_frame(v, c[:, None], s[:, None]), c[:, None], s[:, None])
    torch.testing.assert_close(back, v, rtol=0, atol=1e-9)  # c^2 + s^2 = 1 - EPS^2 / r^2


def test_a_scene_turned_about_the_vertical_looks_the_same_in_the_push_frame():
    g = torch.Generator().manual_seed(1)
    origin = torch.zeros(20, 2, dtype=torch.float64)  # a planar object at the turn's centre
    effector, other = (
        torch.randn(20, 3, generator=g, dtype=torch.float64),
        torch.randn(20, 3, generator=g, dtype=torch.float64),
    )
    for angle in (0.3, 2.0, -2.9):
        c0, s0 = frame_angle(effector, origin)
        c1, s1 = frame_angle(_turned(effector, angle), origin)
        torch.testing.assert_close(to_push_frame(_turned(other, angle), c1, s1), to_push_frame(other, c0, s0))


def test_the_frame_stays_finite_above_the_centre_and_refuses_bad_shapes():
    here = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    c, s = frame_angle(here, torch.zeros(1, 3, dtype=torch.float64))
    (c + s).sum().backward()
    assert torch.isfinite(here.grad).all() and float(c.detach()) == 0.0 and float(s.detach()) == 0.0
    with pytest.raises(ValueError, match=r"vectors must be a tensor \(\.\.\., >= 2\).*\(3, 1\)"):
        to_push_frame(torch.zeros(3, 1), c, s)
    with pytest.raises(ValueError, match="effector must be a tensor"):
        frame_angle([0.0, 1.0], torch.zeros(2))


def test_the_frame_mechanisms_turn_and_turn_back_and_check_their_layout():
    g = torch.Generator().manual_seed(2)
    rel, other, vel = (torch.randn(8, k, generator=g) for k in (3, 6, 2))
    local = PushFrameMechanism([3, 3, 3, 2])(torch.cat([rel, other, vel], -1))
    c, s = frame_angle(rel, torch.zeros(8, 2))
    torch.testing.assert_close(
        local[:, 3:9].reshape(8, 2, 3), to_push_frame(other.reshape(8, 2, 3), c[:, None], s[:, None])
    )
    torch.testing.assert_close(local[:, 9:], to_push_frame(vel, c, s))
    back = FromPushFrameMechanism(3, 2)(torch.cat([rel, local[:, 9:]], -1))
    torch.testing.assert_close(back, vel, atol=1e-6, rtol=0)
    assert not PushFrameMechanism([2]).trainable and not FromPushFrameMechanism(2, 2).trainable
    same = torch.cat([rel, other], -1)  # vectors of one size take the stacked path
    turned = PushFrameMechanism([3, 3, 3])(same)
    parts = [to_push_frame(v, c, s) for v in same.split(3, -1)]
    torch.testing.assert_close(turned, torch.cat(parts, -1), atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="vectors must list at least one"):
        PushFrameMechanism([])
    with pytest.raises(ValueError, match=r"vectors\[\] must be"):
        PushFrameMechanism([3, 1])
    with pytest.raises(ValueError, match="in_dim must be reference \\+ out_dim = 5, got 6"):
        FromPushFrameMechanism(3, 2, in_dim=6)
    with pytest.raises(ValueError, match="columns must be"):
        KinematicPointsMechanism([_chain()], [0, 0], joints=2)


def _chain(
    end=(1, 0, 0), axes=((0, 0, 1), (0, 0, 1)), refs=(0, 0), limits=((None, None),) * 2
) -> KinematicChain:
    """Two hinges, links of 1 m along x (by default both about z, ending 1 m beyond the second)."""
    return KinematicChain(
        torch.eye(3).expand(2, 3, 3), [[0, 0, 0], [1, 0, 0]], torch.zeros(2, 3), axes, refs, end, limits
    )


def test_the_points_mechanism_places_each_point_by_its_own_chain():
    far = _chain()
    near = _chain(end=(0.5, 0, 0))
    mech = KinematicPointsMechanism([far, near], [0, 1], joints=2)
    q = torch.tensor([[math.pi / 2, 0.0]])
    torch.testing.assert_close(mech(q), torch.tensor([[0.0, 2.0, 0.0, 0.0, 1.5, 0.0]]), atol=1e-6, rtol=0)
    rebuilt = KinematicPointsMechanism(**{k: v for k, v in mech.config().items() if k != "kind"})
    torch.testing.assert_close(rebuilt(q), mech(q))


def test_points_of_one_body_share_one_pass_and_equal_their_own_chains():
    ends = ([1, 0, 0], [0.5, 0.2, 0], [0, -0.1, 0.3])
    bounded = ((-1.0, 1.0), (None, None))
    chains = [_chain(end, ((0, 0, 1), (0, 1, 0)), (0.1, 0), bounded) for end in ends]
    other = _chain((1, 0, 0), ((0, 0, 1), (1, 0, 0)), (0.1, 0), bounded)  # another axis: its own pass
    q = torch.randn(4, 5, 2, generator=torch.Generator().manual_seed(3), dtype=torch.float64) * 2
    for group in (chains, [*chains, other]):
        mech = KinematicPointsMechanism(group, [0, 1], joints=2)
        assert mech._shared == (group is chains)
        expected = torch.cat([c(c.clip(q)) for c in group], -1)
        torch.testing.assert_close(mech.core(q), expected, atol=1e-12, rtol=0)
        torch.testing.assert_close(mech.core(q.float()), expected.float(), atol=1e-5, rtol=0)


def test_the_frame_may_be_set_by_any_parent_and_a_position_moved_in_one_site():
    g = torch.Generator().manual_seed(4)
    vel, rel, u, base = (torch.randn(6, k, generator=g) for k in (3, 3, 3, 3))
    local = PushFrameMechanism([3, 3], reference=1)(torch.cat([vel, rel], -1))
    c, s = frame_angle(rel, torch.zeros(6, 2))
    torch.testing.assert_close(local, torch.cat([to_push_frame(vel, c, s), to_push_frame(rel, c, s)], -1))
    assert torch.allclose(local[:, 4], torch.zeros(6), atol=1e-6)  # the reference lies on +x
    moved = FromPushFrameMechanism(3, 3, base=True)(torch.cat([base, rel, u], -1))
    torch.testing.assert_close(moved, base + FromPushFrameMechanism(3, 3)(torch.cat([rel, u], -1)))
    for mech in (PushFrameMechanism([3, 3], reference=1), FromPushFrameMechanism(3, 3, base=True)):
        rebuilt = type(mech)(**{k: v for k, v in mech.config().items() if k != "kind"})
        assert rebuilt.config() == mech.config()
    with pytest.raises(ValueError, match="reference"):
        PushFrameMechanism([3, 3], reference=2)
    with pytest.raises(ValueError, match="in_dim must be out_dim \\+ reference \\+ out_dim = 9, got 6"):
        FromPushFrameMechanism(3, 3, in_dim=6, base=True)
    with pytest.raises(ValueError, match="base must be a bool"):
        FromPushFrameMechanism(3, 3, base=1)
