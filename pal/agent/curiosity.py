"""Curiosity targets over a 2-D object variable (an object's table position), thesis Eq. 4.34-4.38.

:class:`inference.CuriositySampler` works on a scalar variable. An object position is 2-D and
its coverage is a property of the plane, not of each axis, so the agent histograms it on a grid
of ``bx x by`` cells over [low, high] and applies the same densities cell-wise:

    count form (Eq. 5.8):   p_cur(k) ∝ max_j c_j - c_k + eps
    locality   (Eq. 4.36):  Psi(k | x) = 1 + alpha * exp(-|(mu_k - x) / sigma|^2 / 2)
    target     (Eq. 4.37):  p_tar(k | x) ∝ p_cur(k) * Psi(k | x)

A target x* ~ p_tar (Eq. 4.38) is a cell drawn from p_tar and a uniform point in it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pal.checks import check_int

__all__ = ["GridCuriosity", "grid_occupancy"]


def _points(values: object, what: str = "points") -> np.ndarray:
    p = np.asarray(values, dtype=float)
    if p.ndim == 1 and p.shape[0] == 2:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{what} has shape {p.shape}, expected (N, 2) table positions in metres")
    if not np.isfinite(p).all():
        raise ValueError(f"{what} contains NaN or inf; pass only observed positions")
    return p


def _cells(points: np.ndarray, low: np.ndarray, high: np.ndarray, bins: tuple[int, int]) -> np.ndarray:
    frac = (np.clip(points, low, high) - low) / (high - low)
    idx = np.minimum((frac * np.array(bins)).astype(int), np.array(bins) - 1)
    return idx[:, 0] * bins[1] + idx[:, 1]


def grid_occupancy(
    points: object, low: Sequence[float], high: Sequence[float], bins: tuple[int, int] = (8, 8)
) -> float:
    """Fraction of the ``bins`` grid cells over [low, high] that hold at least one point (coverage)."""
    p = _points(points)
    lo, hi = np.asarray(low, float), np.asarray(high, float)
    if p.shape[0] == 0:
        return 0.0
    inside = np.all((p >= lo) & (p <= hi), axis=1)
    cells = _cells(p[inside], lo, hi, bins)
    return float(np.unique(cells).size / (bins[0] * bins[1]))


class GridCuriosity:
    """Count-form curiosity with locality on a 2-D grid (module docstring).

    Args:
        low, high: (2,) corners of the modelled region, metres.
        bins: cells per axis.
        alpha: locality amplification (>= 0).
        sigma: locality width, metres; default a tenth of the region's diagonal.
        eps: count offset (> 0).
    """

    def __init__(
        self,
        low: Sequence[float],
        high: Sequence[float],
        bins: tuple[int, int] = (8, 8),
        alpha: float = 0.5,
        sigma: float | None = None,
        eps: float = 1.0,
    ) -> None:
        self.low, self.high = np.asarray(low, float), np.asarray(high, float)
        if self.low.shape != (2,) or self.high.shape != (2,) or not np.all(self.low < self.high):
            raise ValueError(f"need (2,) low < high, got low={low}, high={high}")
        if len(bins) != 2:
            raise ValueError(f"bins must be two ints >= 2 (cells per axis), got {bins!r}")
        bins = (check_int("bins[0]", bins[0], minimum=2), check_int("bins[1]", bins[1], minimum=2))
        sigma = float(np.linalg.norm(self.high - self.low) / 10) if sigma is None else float(sigma)
        if not (alpha >= 0 and sigma > 0 and eps > 0):
            raise ValueError(f"need alpha >= 0, sigma > 0 and eps > 0, got {alpha}, {sigma}, {eps}")
        self.bins, self.alpha, self.sigma, self.eps = bins, float(alpha), sigma, float(eps)
        ex, ey = (np.linspace(self.low[i], self.high[i], self.bins[i] + 1) for i in range(2))
        self.edges_ = (ex, ey)
        cx, cy = (ex[:-1] + ex[1:]) / 2, (ey[:-1] + ey[1:]) / 2
        self.centers_ = np.stack(np.meshgrid(cx, cy, indexing="ij"), -1).reshape(-1, 2)
        self.counts_ = np.zeros(self.bins[0] * self.bins[1], dtype=np.int64)

    def partial_fit(self, points: object) -> GridCuriosity:
        """Add visited positions (N, 2) to the counts."""
        p = _points(points)
        np.add.at(self.counts_, _cells(p, self.low, self.high, self.bins), 1)
        return self

    def counts_at(self, points: object) -> np.ndarray:
        """``(N,)`` counts of the cells of positions (N, 2), m (positions outside the region: the nearest edge cell)."""
        return self.counts_[_cells(_points(points), self.low, self.high, self.bins)]

    def curiosity(self) -> np.ndarray:
        """p_cur over cells (bx * by,), sums to 1 (count form, Eq. 5.8)."""
        c = self.counts_.astype(float)
        raw = c.max() - c + self.eps
        return raw / raw.sum()

    def density(self, current: object) -> np.ndarray:
        """p_tar over cells given the current position (2,) (Eq. 4.36-4.37)."""
        x = _points(current, "current")[0]
        psi = 1.0 + self.alpha * np.exp(-0.5 * np.sum(((self.centers_ - x) / self.sigma) ** 2, axis=1))
        raw = self.curiosity() * psi
        return raw / raw.sum()

    def sample(self, rng: np.random.Generator, current: object) -> np.ndarray:
        """A target x* ~ p_tar(. | current), (2,) metres (Eq. 4.38)."""
        if not isinstance(rng, np.random.Generator):
            raise ValueError("rng must be a numpy.random.Generator, e.g. np.random.default_rng(0)")
        k = int(rng.choice(self.centers_.shape[0], p=self.density(current)))
        i, j = divmod(k, self.bins[1])
        (ex, ey) = self.edges_
        return np.array([rng.uniform(ex[i], ex[i + 1]), rng.uniform(ey[j], ey[j + 1])])

    def occupancy(self) -> float:
        """Fraction of cells visited at least once."""
        return float((self.counts_ > 0).mean())
