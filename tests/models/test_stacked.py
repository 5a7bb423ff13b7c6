"""Stacked ensemble members (one batched pass) against the members one by one."""

import pytest
import torch

from models import EnsembleMechanism, HeteroscedasticMechanism, MLPMechanism
from models.stacked import StackedMembers, stackable, stacked_members


def _normalised(m, g):
    m.set_normalization(
        torch.randn(m.in_dim, generator=g),
        torch.rand(m.in_dim, generator=g) + 0.5,
        torch.randn(m.out_dim, generator=g),
        torch.rand(m.out_dim, generator=g) + 0.5,
    )
    return m


@pytest.mark.parametrize("kind", ["mlp", "hetero"])
def test_stacked_members_equal_the_members_one_by_one(kind):
    g = torch.Generator().manual_seed(0)
    if kind == "mlp":
        members = [
            _normalised(MLPMechanism(5, 3, hidden=(16, 8), sigma=0.2 + k / 10, seed=k), g) for k in range(4)
        ]
    else:
        members = [
            _normalised(HeteroscedasticMechanism(5, 3, hidden=(16, 8), seed=k, learn_bounds=False), g)
            for k in range(4)
        ]
        for k, m in enumerate(members):
            m.recalibrate(torch.full((3,), 1.0 + k / 5))
    ens = EnsembleMechanism(members)
    paired = torch.randn(4, 7, 2, 5, generator=g)
    shared = torch.randn(6, 5, generator=g)
    want_paired = ens.member_loc_scale(paired, paired=True)
    want_shared = ens.member_loc_scale(shared)
    want_mean = ens(shared)
    got = StackedMembers(members).loc_scale(paired)
    for a, b in zip(got, want_paired, strict=True):
        torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-6)
    with stacked_members(ens):
        assert ens.stacked is not None
        for a, b in zip(ens.member_loc_scale(paired, paired=True), want_paired, strict=True):
            torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-6)
        for a, b in zip(ens.member_loc_scale(shared), want_shared, strict=True):
            torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-6)
        torch.testing.assert_close(ens(shared), want_mean, atol=1e-6, rtol=1e-6)
    assert ens.stacked is None


def test_members_of_different_shapes_do_not_stack():
    a = MLPMechanism(2, 1, hidden=(4,), seed=0)
    b = MLPMechanism(2, 1, hidden=(5,), seed=1)
    assert not stackable([a, b])
    with pytest.raises(ValueError, match="do not stack"):
        StackedMembers([a, b])
    ens = EnsembleMechanism([a, MLPMechanism(2, 1, hidden=(4,), activation="relu", seed=1)])
    with stacked_members(ens):
        assert ens.stacked is None  # the member-by-member path


def test_stacked_parents_of_the_wrong_shape_are_refused():
    s = StackedMembers([MLPMechanism(2, 1, hidden=(4,), seed=k) for k in range(3)])
    with pytest.raises(
        ValueError, match=r"stacked parents have shape \(2, 5, 2\), expected \(3, \.\.\., 2\)"
    ):
        s.loc_scale(torch.zeros(2, 5, 2))
