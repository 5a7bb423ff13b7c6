"""Ensemble disagreement as the experimental-design criterion."""

from __future__ import annotations

import math

import pytest
import torch

from inference import FitSchedule
from inference.ensemble import Ensemble
from models import CausalGraph, LinearMechanism, Role, Variable, WorldModel


def member(slope: float) -> WorldModel:
    g = CausalGraph([Variable("a", Role.ACTION, bounds=(-1, 1)), Variable("y", Role.LATENT)], [("a", "y")])
    return WorldModel(g, {"y": LinearMechanism.from_coefficients([[slope]], sigma=0.5)})


def test_information_is_bald_for_gaussian_members_and_choose_takes_the_largest():
    ens = Ensemble([member(1.0), member(3.0)])
    info = ens.information({"a": torch.tensor([[0.0], [1.0]])}, ["y"])
    # at a = 1 the members predict 1 and 3: variance 1, sigma^2 = 0.25
    assert info[0].item() == pytest.approx(0.0)
    assert info[1].item() == pytest.approx(0.5 * math.log(1 + 1 / 0.25))
    cands = torch.tensor([[[0.0], [0.5], [-0.9]], [[0.1], [0.0], [0.2]]])  # (N=2, C=3, 1)
    chosen, best = ens.choose({}, {"a": cands}, ["y"])
    torch.testing.assert_close(chosen["a"], torch.tensor([[-0.9], [0.2]]))
    assert best.shape == (2,)
    torch.testing.assert_close(ens.predict({"a": torch.tensor([[1.0]])})["y"], torch.tensor([[2.0]]))


def test_fit_trains_members_on_bootstrap_resamples():
    torch.manual_seed(0)
    ens = Ensemble.create(lambda s: WorldModel(member(1.0).graph, kind="linear"), k=3)
    a = torch.rand(200, 1) * 2 - 1
    ens.fit(
        {"a": a, "y": 2 * a + 0.1 * torch.randn(200, 1)},
        schedule=FitSchedule(epochs=60, batch_size=64, lr=0.05),
    )
    slopes = [
        m.predict({"a": torch.tensor([[1.0]])})["y"].item()
        - m.predict({"a": torch.tensor([[0.0]])})["y"].item()
        for m in ens.members
    ]
    assert all(abs(s - 2.0) < 0.1 for s in slopes) and len(set(slopes)) == 3


def test_ensemble_checks_its_inputs():
    with pytest.raises(ValueError, match="at least 2 members"):
        Ensemble([member(1.0)])
    ens = Ensemble([member(1.0), member(2.0)])
    with pytest.raises(ValueError, match="target 'a' is a root"):
        ens.information({"a": torch.zeros(1, 1)}, ["a"])
    with pytest.raises(ValueError, match="candidates is empty"):
        ens.choose({"a": torch.zeros(1, 1)}, {}, ["y"])
