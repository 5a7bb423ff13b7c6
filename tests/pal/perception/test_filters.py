"""The 1€ filter: hand-computed steps, timestamp awareness, vectorisation, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pal.perception.filters import OneEuroConfig, OneEuroFilter, one_euro


def alpha(cutoff: float, dt: float) -> float:
    return 1.0 / (1.0 + 1.0 / (2 * math.pi * cutoff) / dt)


def test_first_steps_match_the_formula():
    f = OneEuroFilter()  # min_cutoff 1, beta 0, d_cutoff 1
    assert f(np.array([0.0]), 0.0).tolist() == [0.0]
    a = alpha(1.0, 0.1)
    assert f(np.array([1.0]), 0.1)[0] == pytest.approx(a)
    # a longer interval lets more of the new sample through: the filter reads the timestamps
    g = OneEuroFilter()
    g(np.array([0.0]), 0.0)
    assert g(np.array([1.0]), 0.5)[0] == pytest.approx(alpha(1.0, 0.5))
    assert alpha(1.0, 0.5) > a


def test_beta_reduces_lag_and_components_are_independent():
    ts = np.arange(50) / 30.0
    ramp = np.stack([ts, np.zeros_like(ts), 5.0 * np.ones_like(ts)], axis=1)
    slow = one_euro(ramp, ts, OneEuroConfig(beta=0.0))
    fast = one_euro(ramp, ts, OneEuroConfig(beta=5.0))
    assert abs(fast[-1, 0] - ts[-1]) < abs(slow[-1, 0] - ts[-1])
    assert np.allclose(slow[:, 1], 0.0) and np.allclose(slow[:, 2], 5.0)  # constants pass unchanged
    stateful = OneEuroFilter(OneEuroConfig(beta=5.0))
    assert np.allclose([stateful(x, t) for x, t in zip(ramp, ts, strict=True)], fast)
    stateful.reset()
    assert stateful.last_time is None


def test_bad_input():
    f = OneEuroFilter()
    f(np.zeros(3), 1.0)
    with pytest.raises(ValueError, match="does not increase"):
        f(np.zeros(3), 1.0)
    with pytest.raises(ValueError, match="shape"):
        f(np.zeros(2), 2.0)
    with pytest.raises(ValueError, match="finite"):
        f(np.array([np.nan, 0, 0]), 3.0)
    with pytest.raises(ValueError, match="min_cutoff"):
        OneEuroConfig(min_cutoff=0.0)
    with pytest.raises(ValueError, match="timestamps"):
        one_euro(np.zeros((3, 2)), np.zeros(2))
