"""Simulated data that behave like real measurements, for testing structure learning.

Over a random DAG (:func:`models.random_graph`), each variable is a latent quantity

    L_i = sum_{j in pa_i} w_ij g_ij(Z_j) + (a_i + b_i |s_i|) T_i,    Z_j = standardised L_j,

with ``g_ij(z) = tanh(c_ij z)`` or ``z`` (drawn), ``|w_ij|`` in [0.5, 1.5], ``s_i`` the signal
standardised, ``T_i`` Student-t noise with 3 degrees of freedom (heavy tails) and a scale
that grows with the signal (heteroscedastic noise). Roots are Student-t. What is recorded is
a measurement of L_i:

    X_i = m_i(L_i + e_i),    e_i ~ N(0, (0.2 sd(L_i))^2)    (measurement error),

with ``m_i`` the identity, ``exp`` of the standardised value (a skewed, log-normal-like
reading) or a saturation at the 90th percentile (an instrument at the top of its range),
drawn per variable. :func:`shuffled` permutes every column independently (the permutation
baseline: no dependence is left, so any edge found is false).
"""

from __future__ import annotations

import numpy as np

from models import CausalGraph, random_graph
from pal.checks import check_int

__all__ = ["measurement_data", "shuffled"]

MEASUREMENTS = ("identity", "skewed", "saturated")


def _std(v: np.ndarray) -> np.ndarray:
    return (v - v.mean()) / max(float(v.std()), 1e-12)


def measurement_data(
    d: int, n: int, seed: int, expected_parents: float = 2.0
) -> tuple[CausalGraph, dict[str, np.ndarray]]:
    """The true graph and ``n`` rows: name -> ``(n, 1)`` float64 (module docstring).

    Args:
        d: variables, >= 2.
        n: rows, >= 10.
        seed: seeds the graph, the mechanisms and the rows (local generators).
        expected_parents: mean in-degree of the DAG.
    """
    d, n = check_int("d", d, minimum=2), check_int("n", n, minimum=10)
    graph = random_graph(d, expected_parents, seed=seed)
    rng = np.random.default_rng([seed, 0xE5])
    latent: dict[str, np.ndarray] = {}
    for name in graph.topological_order():
        parents = graph.parents(name)
        signal = np.zeros(n)
        for p in parents:
            z, w = _std(latent[p]), rng.uniform(0.5, 1.5) * rng.choice([-1.0, 1.0])
            signal += w * (np.tanh(rng.uniform(1.0, 2.5) * z) if rng.random() < 0.6 else z)
        s = _std(signal) if parents else signal
        scale = rng.uniform(0.3, 0.5) * (1.0 + rng.uniform(0.5, 1.5) * np.abs(s)) if parents else 1.0
        latent[name] = signal + scale * rng.standard_t(3, n)
    data = {}
    for name in graph.names:
        value = latent[name] + 0.2 * latent[name].std() * rng.standard_normal(n)
        kind = MEASUREMENTS[int(rng.integers(len(MEASUREMENTS)))]
        if kind == "skewed":
            value = np.exp(np.clip(_std(value), -6.0, 6.0))
        elif kind == "saturated":
            value = np.minimum(value, np.quantile(value, 0.9))
        data[name] = value[:, None]
    return graph, data


def shuffled(data: dict[str, np.ndarray], seed: int) -> dict[str, np.ndarray]:
    """Every column permuted independently: the same marginals, no dependence."""
    rng = np.random.default_rng([seed, 0x5F])
    return {k: v[rng.permutation(len(v))] for k, v in data.items()}
