"""C3's counterfactual answer re-decides a contact switch under the counterfactual action (closed form)."""

import numpy as np
import pytest
import torch

from models import BernoulliMechanism, CausalGraph, GatedMechanism, LinearMechanism, Variable, WorldModel
from pal.experiments.closed_loop.c3 import Config, counterfactual_answers

FLOOR, SIGMA_ON = 1e-3, 0.1


def switched():
    """a -> c ~ Bernoulli(sigmoid(100 a)) (contact when the hand is at a > 0); x | c=1 ~ N(2a, 0.1), x | c=0 ~ N(0, 1e-3)."""
    graph = CausalGraph(
        [Variable(n, "observed") for n in ("a", "c", "x")], [("a", "c"), ("a", "x"), ("c", "x")]
    )
    on = LinearMechanism.from_coefficients([[2.0, 0.0]], 0.0, SIGMA_ON)
    return WorldModel(
        graph,
        {"c": BernoulliMechanism.from_coefficients([100.0], 0.0), "x": GatedMechanism("c", on, FLOOR)},
    )


def test_a_counterfactual_action_that_moves_the_hand_away_turns_the_switch_off():
    # unit 0: contact, u = (1.2 - 2 * 0.5) / 0.1 = 2, a' = -0.5 moves the hand away: the off branch, 1e-3 * 2;
    # unit 1: contact kept at a' = 0.8: 2 * 0.8 + 0.1 * 2; unit 2: no contact, u = 5e-4 / 1e-3 = 0.5,
    # a' = 0.5 makes contact: 2 * 0.5 + 0.1 * 0.5
    factual = {
        "a": torch.tensor([[0.5], [0.5], [-0.5]]),
        "c": torch.tensor([[1.0], [1.0], [0.0]]),
        "x": torch.tensor([[1.2], [1.2], [5e-4]]),
    }
    do = {"a": torch.tensor([[-0.5], [0.8], [0.5]])}
    out = counterfactual_answers(switched(), factual, do, "x", num_samples=50, seed=0)
    np.testing.assert_allclose(
        out["cf"][:, 0], [FLOOR * 2, 1.6 + SIGMA_ON * 2, 1.0 + SIGMA_ON * 0.5], atol=1e-6
    )
    # the interventional answer is the mixture mean at a' (P(contact) = 0 or 1 here): no residual
    np.testing.assert_allclose(out["interventional"][:, 0], [0.0, 1.6, 1.0], atol=1e-6)


def test_c3_config_names_distinct_forms():
    assert Config().forms == ("gated", "smooth")
    with pytest.raises(ValueError, match="forms 'rigid' unknown"):
        Config(forms=("gated", "rigid"))
    with pytest.raises(ValueError, match="distinct displacement forms"):
        Config(forms=("gated", "gated"))
