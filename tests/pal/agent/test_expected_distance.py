"""The model's expected distance at a plan's end against the Rayleigh mean of a linear-Gaussian walk."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models import CausalGraph, LinearMechanism, Variable, WorldModel
from pal.agent.plan import expected_distance

SIGMA = 0.01  # per-step sd of each component, m


def walk() -> WorldModel:
    """``pos.box = pos_prev.box + act + N(0, SIGMA^2 I)`` in the plane."""
    g = CausalGraph(
        [
            Variable("act", "action", 2, bounds=(-0.1, 0.1)),
            Variable("pos_prev.box", "observed", 2, lag=1, lag_of="pos.box"),
            Variable("pos.box", "observed", 2),
        ],
        [("act", "pos.box"), ("pos_prev.box", "pos.box")],
    )
    weight = np.hstack([np.eye(2), np.eye(2)])  # both parents enter with the identity
    return WorldModel(g, {"pos.box": LinearMechanism.from_coefficients(weight, sigma=SIGMA)})


def test_the_expected_distance_is_the_rayleigh_mean_of_the_walks_end():
    """After H steps aimed exactly at the target, x_H - t ~ N(0, H SIGMA^2 I_2), so
    E||x_H - t|| = sqrt(H) SIGMA sqrt(pi / 2); the mean's distance (the plan objective) is 0."""
    model, h = walk(), 4
    start, step = np.array([0.1, -0.2]), np.array([0.02, 0.01])
    sequence = np.tile(step, (h, 1))
    target = {"box": start + h * step}
    got = expected_distance(model, {"pos_prev.box": start}, sequence, target, draws=4000, seed=0)
    assert got == pytest.approx(math.sqrt(h) * SIGMA * math.sqrt(math.pi / 2), rel=0.03)
    # a target 5 cm off along x: E||(0.05, 0) + e|| with e ~ N(0, 4e-4 I), about the offset
    far = expected_distance(
        model, {"pos_prev.box": start}, sequence, {"box": target["box"] + [0.05, 0.0]}, draws=4000
    )
    assert 0.05 < far < 0.05 + 2 * SIGMA
    again = expected_distance(model, {"pos_prev.box": start}, sequence, target, draws=4000, seed=0)
    assert again == got  # seeded


def test_a_sequence_that_is_not_a_matrix_is_refused():
    with pytest.raises(ValueError, match=r"sequence must be \(H, A\), got shape \(2,\)"):
        expected_distance(walk(), {"pos_prev.box": np.zeros(2)}, np.zeros(2), {"box": np.zeros(2)})
    with pytest.raises(ValueError, match="draws"):
        expected_distance(
            walk(), {"pos_prev.box": np.zeros(2)}, np.zeros((1, 2)), {"box": np.zeros(2)}, draws=0
        )
