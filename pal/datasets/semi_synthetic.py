"""A table of the IHDP benchmark's shape whose unit-level effects are known.

Hill (2011) built the IHDP benchmark from the covariates of a real trial and simulated
outcomes ("response surface B"). The trial's covariates are not shipped with pal, so this
table draws covariates of the same shape (747 units: 6 continuous, 18 binary) and keeps
Hill's outcome surface, with a confounded binary treatment:

    X_c ~ N(0, Sigma) (6 columns, correlation 0.3),  X_b ~ Bernoulli(p_j) (18 columns)
    T   ~ Bernoulli(sigmoid(a + w . X))                     (about 19 % treated)
    Y0  = exp((X + 0.5) . beta) + N(0, 1),   Y1 = X . beta - omega + N(0, 1)
    beta_j in {0, 0.1, 0.2, 0.3, 0.4} with probabilities (0.6, 0.1, 0.1, 0.1, 0.1)

with omega set so that the average effect on the treated is 4 (as in Hill's surface B). The
unit-level effect is ``tau_i = mu1(x_i) - mu0(x_i)`` (noise-free), so the precision of a
unit-level estimate, PEHE = sqrt(mean_i (tau_hat_i - tau_i)^2), can be computed exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pal.checks import check_int

__all__ = ["EffectTable", "ihdp_like"]

#: average effect on the treated of Hill's response surface B
ATT = 4.0


@dataclass(frozen=True)
class EffectTable:
    """A table with its true unit-level effects.

    Attributes:
        columns: ordered column -> ``(N,)`` float64: ``x1..x24`` covariates, ``t`` (0/1), ``y``.
        effect: ``(N,)`` the true unit effects ``mu1(x_i) - mu0(x_i)``.
        treatment, outcome: the names of the treatment and outcome columns.
    """

    columns: dict[str, np.ndarray]
    effect: np.ndarray
    treatment: str = "t"
    outcome: str = "y"

    @property
    def covariates(self) -> list[str]:
        """The covariate columns."""
        return [c for c in self.columns if c not in (self.treatment, self.outcome)]

    def pehe(self, estimate: np.ndarray) -> float:
        """``sqrt(mean_i (estimate_i - tau_i)^2)`` of an ``(N,)`` estimate of the unit effects."""
        est = np.asarray(estimate, dtype=np.float64).reshape(-1)
        if est.shape != self.effect.shape:
            raise ValueError(f"estimate has shape {est.shape}, expected {self.effect.shape} (one per unit)")
        if not np.isfinite(est).all():
            raise ValueError("estimate has NaN or inf entries")
        return float(np.sqrt(np.mean((est - self.effect) ** 2)))


def ihdp_like(n: int = 747, seed: int = 0) -> EffectTable:
    """A confounded table with a binary treatment and known unit effects (module docstring).

    Args:
        n: rows (747 as in IHDP).
        seed: seeds the covariates, the surface and the noise (a local generator).

    Returns:
        :class:`EffectTable` with 26 columns.
    """
    n = check_int("n", n, minimum=10)
    seed = check_int("seed", seed, minimum=0)
    rng = np.random.default_rng(seed)
    cov = 0.3 + 0.7 * np.eye(6)
    xc = rng.multivariate_normal(np.zeros(6), cov, size=n)
    xb = (rng.random((n, 18)) < rng.uniform(0.1, 0.6, size=18)).astype(np.float64)
    x = np.concatenate([xc, xb], 1)
    w = np.concatenate([rng.normal(0.6, 0.2, 6), rng.normal(0.0, 0.4, 18)])
    logits = x @ w - 3.0
    t = (rng.random(n) < 1.0 / (1.0 + np.exp(-logits))).astype(np.float64)
    beta = rng.choice([0.0, 0.1, 0.2, 0.3, 0.4], size=24, p=[0.6, 0.1, 0.1, 0.1, 0.1])
    mu0 = np.exp((x + 0.5) @ beta)
    mu1 = x @ beta
    omega = float(np.mean((mu1 - mu0)[t == 1])) - ATT if t.any() else 0.0
    mu1 = mu1 - omega
    y = np.where(t == 1, mu1, mu0) + rng.normal(size=n)
    columns = {f"x{j + 1}": x[:, j] for j in range(24)}
    columns.update(t=t, y=y)
    return EffectTable(columns, mu1 - mu0)
