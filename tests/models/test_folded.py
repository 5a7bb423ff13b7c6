"""The folded tanh MLP equals the mechanism it was folded from."""

import pytest
import torch

from models.folded import FOLD_ROWS, fold_mlp, loc_scale
from models.mechanisms import LinearMechanism, MLPMechanism


@pytest.mark.parametrize(("in_dim", "out_dim", "hidden"), [(3, 1, (32, 32)), (2, 2, ()), (4, 3, (8, 5, 6))])
def test_folded_layers_equal_the_mechanism(in_dim, out_dim, hidden):
    mech = MLPMechanism(in_dim, out_dim, hidden=hidden, seed=1)
    gen = torch.Generator().manual_seed(0)
    mech.set_normalization(
        torch.randn(in_dim, generator=gen),
        torch.rand(in_dim, generator=gen) + 0.5,
        torch.randn(out_dim, generator=gen),
        torch.rand(out_dim, generator=gen) + 0.5,
    )
    x = 3 * torch.randn(500, in_dim, generator=gen)
    folded = fold_mlp(mech)
    assert folded is not None
    with torch.no_grad():
        torch.testing.assert_close(folded(x), mech(x), atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(
            folded(x.reshape(5, 100, in_dim)), mech(x).reshape(5, 100, out_dim), atol=1e-5, rtol=1e-5
        )


def test_other_mechanisms_are_not_folded_and_small_batches_use_the_mechanism():
    assert fold_mlp(MLPMechanism(2, 1, activation="relu", seed=0)) is None
    assert fold_mlp(LinearMechanism(2, 1)) is None
    mech = MLPMechanism(2, 1, seed=0)
    mech.set_sigma(0.7)
    assert loc_scale(mech, FOLD_ROWS - 1) == mech.loc_scale
    x = torch.randn(FOLD_ROWS, 2, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        loc, scale = loc_scale(mech, FOLD_ROWS)(x)
        want_loc, want_scale = mech.loc_scale(x)
    torch.testing.assert_close(loc, want_loc, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(scale, want_scale, atol=0, rtol=0)
    assert not loc.requires_grad and not scale.requires_grad
