"""Curiosity targets and coverage metrics (thesis Eq. 4.34-4.38, 5.8-5.9).

Over a scalar target variable X with B histogram bins on [low, high]:

    inverse form (Eq. 4.34-4.35):  p_cur(k) ∝ 1 / (p_hat(k) + eps),  p_hat(k) = c_k / sum_j c_j
    count form   (Eq. 5.8):        p_cur(k) ∝ max_j c_j - c_k + eps
    locality     (Eq. 4.36):       Psi(k | x) = 1 + alpha * exp(-((mu_k - x) / sigma)^2 / 2)
    target       (Eq. 4.37, 5.9):  p_tar(k | x) ∝ p_cur(k) * Psi(k | x)

A target x* ~ p_tar (Eq. 4.38) is a bin drawn from p_tar and a uniform position in it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from models.checks import as_float_array, check_choice, check_float, check_int, describe

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["CuriositySampler", "histogram", "normalized_entropy", "occupancy"]

FORMS = ("count", "inverse")


def _values(values: Any, what: str = "values") -> np.ndarray:
    v = as_float_array(values, what)
    if v.ndim == 2 and v.shape[1] == 1:
        v = v[:, 0]
    if v.ndim != 1:
        raise ValueError(f"{what} has shape {v.shape}, expected (N,) or (N, 1) for a scalar variable")
    if not np.isfinite(v).all():
        raise ValueError(f"{what} contains {int((~np.isfinite(v)).sum())} NaN or inf entries")
    return v


def _support(low: Any, high: Any, bins: Any) -> tuple[float, float, int]:
    low = check_float("low", low)
    high = check_float("high", high)
    if not low < high:
        raise ValueError(f"need finite low < high, got low={low}, high={high}")
    return low, high, check_int("bins", bins, minimum=2)


def histogram(values: Any, low: float, high: float, bins: int) -> np.ndarray:
    """Counts ``(bins,)`` of ``values`` (``(N,)`` or ``(N, 1)``) in equal bins on [low, high].

    Values outside [low, high] are clipped into the end bins.
    """
    low, high, bins = _support(low, high, bins)
    v = np.clip(_values(values), low, high)
    counts, _ = np.histogram(v, bins=bins, range=(low, high))
    return counts


def _occupancy(counts: np.ndarray) -> float:
    return float((counts > 0).mean())


def occupancy(values: Any, low: float, high: float, bins: int = 20) -> float:
    """Fraction of the ``bins`` equal bins on [low, high] visited at least once (thesis §5.2.4)."""
    return _occupancy(histogram(values, low, high, bins))


def _entropy(counts: np.ndarray) -> float:
    c = counts.astype(float)
    if c.sum() == 0:
        raise ValueError("no values to compute an entropy from")
    p = c[c > 0] / c.sum()
    return float(-(p * np.log(p)).sum() / np.log(len(c)))


def normalized_entropy(values: Any, low: float, high: float, bins: int = 20) -> float:
    """Shannon entropy of the bin distribution divided by log(bins), in [0, 1]."""
    return _entropy(histogram(values, low, high, bins))


class CuriositySampler:
    """Curiosity-biased target density over a scalar variable.

    Args:
        low, high: modelled support X_X of the variable.
        bins: histogram bins B (thesis: 20).
        alpha: locality amplification alpha >= 0, finite (thesis: 0.5).
        sigma: locality width > 0 in the variable's units; default (high - low) / 10 (thesis).
        form: ``"count"`` (Eq. 5.8) or ``"inverse"`` (Eq. 4.34).
        eps: epsilon of Eq. 4.34 / 5.8 (> 0). In the count form it is a count; in the
            inverse form it is added to the bin probability.

    Attributes:
        counts_: ``(bins,)`` visit counts after :meth:`fit` / :meth:`partial_fit`.
        centers_: ``(bins,)`` bin centres mu_k.
    """

    def __init__(
        self,
        low: float,
        high: float,
        bins: int = 20,
        alpha: float = 0.5,
        sigma: float | None = None,
        form: str = "count",
        eps: float | None = None,
    ) -> None:
        low, high, bins = _support(low, high, bins)
        alpha = check_float("alpha", alpha, minimum=0.0)
        sigma = (
            (high - low) / 10 if sigma is None else check_float("sigma", sigma, minimum=0.0, min_open=True)
        )
        form = check_choice("form", form, FORMS)
        eps = (1.0 if form == "count" else 1e-3) if eps is None else eps
        eps = check_float("eps", eps, minimum=0.0, min_open=True)
        self.low, self.high, self.bins = float(low), float(high), bins
        self.alpha, self.sigma, self.form, self.eps = float(alpha), float(sigma), form, float(eps)
        self.edges_ = np.linspace(self.low, self.high, bins + 1)
        self.centers_ = (self.edges_[:-1] + self.edges_[1:]) / 2
        self.counts_ = np.zeros(bins, dtype=np.int64)

    # ------------------------------------------------------------------ estimation
    def fit(self, values: Any) -> CuriositySampler:
        """Reset the counts to the histogram of ``values`` (the explored density p_hat)."""
        self.counts_ = histogram(values, self.low, self.high, self.bins).astype(np.int64)
        return self

    def partial_fit(self, values: Any) -> CuriositySampler:
        """Add ``values`` to the counts (online exploration)."""
        self.counts_ = self.counts_ + histogram(values, self.low, self.high, self.bins)
        return self

    # ------------------------------------------------------------------ densities
    def curiosity(self) -> np.ndarray:
        """p_cur over bins, ``(bins,)``, sums to 1 (Eq. 4.35 or the count form of 5.8)."""
        c = self.counts_.astype(float)
        if self.form == "count":
            raw = c.max() - c + self.eps
        else:
            total = c.sum()
            p_hat = c / total if total > 0 else np.zeros_like(c)
            raw = 1.0 / (p_hat + self.eps)
        return raw / raw.sum()

    def locality(self, current: Any) -> np.ndarray:
        """Psi(mu_k | x) for each current value: ``(N, bins)`` (Eq. 4.36)."""
        x = _values(np.atleast_1d(current), "current")
        return 1.0 + self.alpha * np.exp(-0.5 * ((self.centers_[None, :] - x[:, None]) / self.sigma) ** 2)

    def density(self, current: Any | None = None) -> np.ndarray:
        """p_tar over bins: ``(bins,)`` without ``current``, else ``(N, bins)`` (Eq. 4.37, 5.9)."""
        cur = self.curiosity()
        if current is None:
            return cur
        raw = cur[None, :] * self.locality(current)
        return raw / raw.sum(1, keepdims=True)

    def sample(
        self, rng: np.random.Generator, current: Any | None = None, *, size: int | None = None
    ) -> np.ndarray:
        """Draw targets x* ~ p_tar (Eq. 4.38).

        Args:
            rng: numpy Generator (randomness is an argument).
            current: ``(N,)`` current values x(t); one target per entry. If None, ``size``
                targets are drawn from p_cur.
            size: number of targets when ``current`` is None.

        Returns:
            ``(N,)`` or ``(size,)`` target values in [low, high].
        """
        if not isinstance(rng, np.random.Generator):
            raise ValueError(
                f"rng must be a numpy.random.Generator, e.g. np.random.default_rng(0), got {describe(rng)}"
            )
        if current is None:
            if size is None:
                raise ValueError("give current values or a positive size")
            size = check_int("size", size, minimum=1)
            probs = np.broadcast_to(self.curiosity(), (size, self.bins))
        else:
            if size is not None:
                raise ValueError("size is only used without current (one target per current value)")
            probs = self.density(current)
        cdf = np.cumsum(probs, axis=1)
        u = rng.random(probs.shape[0])
        k = np.minimum((u[:, None] > cdf).sum(1), self.bins - 1)
        return self.edges_[k] + rng.random(k.shape[0]) * (self.edges_[k + 1] - self.edges_[k])

    # ------------------------------------------------------------------ reporting
    def occupancy(self) -> float:
        """Fraction of bins with at least one visit (as :func:`occupancy`)."""
        return _occupancy(self.counts_)

    def normalized_entropy(self) -> float:
        """Entropy of the visit distribution / log(bins)."""
        return _entropy(self.counts_)

    def plot(self, current: float | None = None, ax: Any = None) -> Figure:
        """Bars of visit counts with the target density overlaid; returns the Figure."""
        import matplotlib.pyplot as plt

        if current is not None:
            current = check_float("current", current)
        if ax is None:
            fig, ax = plt.subplots(figsize=(5, 3))
        else:
            fig = ax.figure
        width = self.edges_[1] - self.edges_[0]
        ax.bar(self.centers_, self.counts_, width=width * 0.9, color="#cccccc", label="visits")
        ax.set_ylabel("visits")
        twin = ax.twinx()
        dens = self.density(None if current is None else [current])
        twin.step(self.centers_, dens.reshape(-1), where="mid", color="#d62728", label="target density")
        twin.set_ylabel("p_tar")
        if current is not None:
            ax.axvline(current, color="#1f77b4", ls="--", label="current")
        ax.set_xlabel("value")
        handles = ax.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
        ax.legend(
            handles=handles, loc="upper center", bbox_to_anchor=(0.5, 1.18), ncol=3, fontsize=7, frameon=False
        )
        fig.tight_layout()
        return fig
