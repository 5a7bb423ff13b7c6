"""A fitted, robust per-dimension normaliser, so that no feature family dominates distances.

``fit(X)`` learns, per dimension, the median ``center_`` and a robust scale ``scale_`` (the
inter-quartile range / 1.349, the standard deviation of a normal with that IQR). Dimensions with
zero spread in the fitting data take the median non-zero scale of their family (or 1 if the whole
family is constant), so a constant training dimension does not blow up later deviations.

Then every family is weighted by ``1 / sqrt(family size)``: after standardising, each dimension
contributes about 1 to a squared distance, so a family's total contribution is about 1 whatever
its size — the 32 HSV bins do not outvote the single edge density, and the unbounded Hu moments
no longer dominate (the proof of concept's Table 5.4 failure). ``transform(X)`` returns
``(X - center_) / scale_ * weight_``.

Families named in ``shared`` (histograms: distributions whose bins share one unit) get one
scale instead: the median over the fitted samples of the family's L2 deviation from its
per-dimension median, and weight 1, so a typical sample contributes about 1 as well. Per-bin
standardisation would divide the nearly empty bins of a histogram by their tiny spread and let
their pixel-count noise dominate the family (measured on the tabletop records: the boat's
records drifted towards the box prototype through bins holding < 1 % of its pixels).

The learned state (trailing underscore, scikit-learn style) round-trips through JSON with
:meth:`to_dict` / :meth:`from_dict`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["NotFittedError", "RobustNormaliser"]


class NotFittedError(ValueError, AttributeError):
    """The normaliser was used before :meth:`RobustNormaliser.fit`."""


class RobustNormaliser:
    """Median/IQR standardisation with per-family weights (module docstring).

    Args:
        families: named slices partitioning the dimensions (e.g.
            :data:`pal.perception.visual.VISUAL_FAMILIES`); None: each dimension is its own family
            (weights 1).
        shared: families scaled as a whole (e.g. :data:`pal.perception.visual.VISUAL_HISTOGRAMS`).

    Raises:
        ValueError: ``shared`` names a family that ``families`` does not have.
    """

    def __init__(self, families: Mapping[str, slice] | None = None, shared: Sequence[str] = ()) -> None:
        self.families = dict(families) if families is not None else None
        self.shared = tuple(shared)
        unknown = [f for f in self.shared if self.families is None or f not in self.families]
        if unknown:
            raise ValueError(
                f"shared families {unknown} are not among the families {sorted(self.families or {})}"
            )

    def _family_index(self, dim: int) -> list[tuple[str, np.ndarray]]:
        if self.families is None:
            return [(str(j), np.array([j])) for j in range(dim)]
        covered = np.zeros(dim, dtype=int)
        groups = []
        for name, sl in self.families.items():
            idx = np.arange(dim)[sl]
            if idx.size == 0:
                raise ValueError(f"family {name!r} ({sl}) selects no dimension of {dim}")
            covered[idx] += 1
            groups.append((name, idx))
        if not np.all(covered == 1):
            raise ValueError(
                f"families must partition the {dim} dimensions; coverage counts {covered.tolist()}"
            )
        return groups

    def fit(self, X: np.ndarray) -> RobustNormaliser:
        """Learn ``center_``, ``scale_`` and ``weight_`` from (n, d) samples, n >= 2, finite.

        Raises:
            ValueError: wrong shape, too few samples, non-finite values, or families that do not
                partition the dimensions.
        """
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[0] < 2:
            raise ValueError(f"X has shape {X.shape}, expected (n >= 2, d)")
        if not np.all(np.isfinite(X)):
            raise ValueError("X contains NaN/inf")
        groups = self._family_index(X.shape[1])
        q25, med, q75 = np.percentile(X, [25, 50, 75], axis=0)
        scale = (q75 - q25) / 1.349
        weight = np.ones(X.shape[1])
        for name, idx in groups:
            if name in self.shared:
                dev = np.linalg.norm(X[:, idx] - med[idx], axis=1)
                typical = float(np.median(dev)) if np.median(dev) > 1e-12 else float(dev.mean())
                scale[idx] = typical if typical > 1e-12 else 1.0
                continue
            s = scale[idx]
            pos = s[s > 1e-12]
            fill = float(np.median(pos)) if pos.size else 1.0
            scale[idx] = np.where(s > 1e-12, s, fill)
            weight[idx] = 1.0 / np.sqrt(idx.size)
        self.center_, self.scale_, self.weight_ = med, scale, weight
        self.n_features_in_ = int(X.shape[1])
        return self

    def _check(self, X: np.ndarray) -> np.ndarray:
        if not hasattr(self, "center_"):
            raise NotFittedError("this RobustNormaliser is not fitted yet; call fit(X) first")
        X = np.asarray(X, dtype=np.float64)
        if X.shape[-1] != self.n_features_in_:
            raise ValueError(
                f"X has {X.shape[-1]} dimensions, the normaliser was fitted on {self.n_features_in_}"
            )
        return X

    def transform(self, X: np.ndarray) -> np.ndarray:
        """(..., d) -> (..., d) normalised and family-weighted."""
        X = self._check(X)
        return (X - self.center_) / self.scale_ * self.weight_

    def fit_transform(self, X: np.ndarray) -> np.ndarray:
        """Fit on (n, d) points and return them normalised: (n, d)."""
        return self.fit(X).transform(X)

    def inverse_transform(self, Z: np.ndarray) -> np.ndarray:
        """(..., d) normalised points -> (..., d) in the original units (undoes :meth:`transform`)."""
        Z = self._check(Z)
        return Z / self.weight_ * self.scale_ + self.center_

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible learned state."""
        self._check(np.zeros(getattr(self, "n_features_in_", 0)))
        fam = None if self.families is None else {k: [v.start, v.stop] for k, v in self.families.items()}
        return {
            "families": fam,
            "shared": list(self.shared),
            "center": self.center_.tolist(),
            "scale": self.scale_.tolist(),
            "weight": self.weight_.tolist(),
        }

    @staticmethod
    def from_dict(data: Mapping[str, Any]) -> RobustNormaliser:
        """A fitted normaliser from the state written by :meth:`to_dict`; ValueError if inconsistent."""
        fam = data.get("families")
        out = RobustNormaliser(
            None if fam is None else {k: slice(int(a), int(b)) for k, (a, b) in fam.items()},
            tuple(data.get("shared", ())),
        )
        out.center_ = np.asarray(data["center"], dtype=np.float64)
        out.scale_ = np.asarray(data["scale"], dtype=np.float64)
        out.weight_ = np.asarray(data["weight"], dtype=np.float64)
        out.n_features_in_ = int(out.center_.shape[0])
        if (
            out.scale_.shape != out.center_.shape
            or out.weight_.shape != out.center_.shape
            or np.any(out.scale_ <= 0)
        ):
            raise ValueError("normaliser state has inconsistent shapes or non-positive scales")
        return out
