"""Quantiles of small samples agree with numpy's linear-interpolation percentiles."""

import numpy as np
import pytest

from pal.perception.quantiles import median, quantiles


@pytest.mark.parametrize("n", [1, 2, 7, 200, 1501])
def test_quantiles_match_numpy_percentile(n):
    x = np.random.default_rng(n).normal(size=(n, 3))
    qs = (0.0, 2.0, 25.0, 50.0, 75.0, 98.0, 100.0)
    np.testing.assert_allclose(quantiles(x, qs), np.percentile(x, qs, axis=0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(quantiles(x[:, 0], qs), np.percentile(x[:, 0], qs), rtol=0, atol=1e-12)
    np.testing.assert_allclose(median(x), np.median(x, axis=0), rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("values", "percents", "match"),
    [
        (np.zeros(0), (50.0,), "N >= 1"),
        (np.zeros((2, 2, 2)), (50.0,), "expected"),
        (np.zeros(3), (101.0,), r"\[0, 100\]"),
        (np.zeros(3), (-1.0,), r"\[0, 100\]"),
    ],
)
def test_quantiles_reject_bad_input(values, percents, match):
    with pytest.raises(ValueError, match=match):
        quantiles(values, percents)
