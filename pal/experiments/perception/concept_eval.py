"""Nearest-prototype evaluation in one conceptual domain (A1's motion space, A2's visual space).

Every record is a point ``x_i`` with a label (an object, or a kind of motion). Points are first
scaled by a scaler fitted on the points that form the prototypes, then placed in a one-domain
:class:`~pal.perception.concepts.ConceptualSpace`; prototypes are per-label means (Eq. 4.26)
and categories the nearest prototype (Eq. 1.7). A scaler is anything with ``fit`` and
``transform``, made fresh for every fit by a factory:

- :class:`~pal.perception.normalise.RobustNormaliser` for heterogeneous features such as the
  54 visual ones (per-dimension median/IQR, histograms as a whole, families weighted equally);
- :class:`FamilyScaler` (one scale per family, its RMS norm over the fitted points) for
  homogeneous physical coordinates such as the motion descriptor's DCT coefficients of
  displacements (m) and rotations (rad): it only balances the units of the families.
  Per-dimension standardisation would inflate coefficients that are near zero for most records
  (rotations of the translation runs) and let them dominate;
- no scaler (``None``): raw distances, the proof of concept's protocol.

- :func:`prototype_distances`: all records form the prototypes, each record included in its
  own (the thesis's Table 5.4 protocol).
- :func:`leave_one_out`: each record is held out, the scaler and prototypes are rebuilt from
  the others, and the held-out record is categorised. A record whose label has no other
  exemplar cannot be categorised correctly; it is reported as ``None`` and counted as wrong.
- :func:`pca_2d`: a 2-D PCA projection with explained-variance fractions (Figs. 5.3-5.4).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Protocol

import numpy as np

from pal.perception import ConceptualSpace, Domain

__all__ = ["FamilyScaler", "Scaler", "leave_one_out", "loo_accuracy", "pca_2d", "prototype_distances"]


class Scaler(Protocol):
    """What the evaluation needs of a scaler."""

    def fit(self, X: np.ndarray) -> Scaler:
        """Learn the scaling from (n, d) points and return self."""
        ...

    def transform(self, X: np.ndarray) -> np.ndarray:
        """Scale (m, d) points with the fitted scaling: (m, d)."""
        ...


class FamilyScaler:
    """Divides each family of dimensions by its RMS norm over the fitted points (no centring).

    Args:
        families: named slices partitioning the dimensions.
    """

    def __init__(self, families: Mapping[str, slice]) -> None:
        self.families = dict(families)

    def fit(self, X: np.ndarray) -> FamilyScaler:
        """Learn ``scale_`` (d,) from (n >= 1, d) finite points; a family that is zero everywhere keeps scale 1."""
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[0] < 1 or not np.all(np.isfinite(X)):
            raise ValueError(f"X has shape {X.shape} or non-finite values; expected finite (n >= 1, d)")
        scale = np.ones(X.shape[1])
        covered = np.zeros(X.shape[1], dtype=int)
        for name, sl in self.families.items():
            idx = np.arange(X.shape[1])[sl]
            if idx.size == 0:
                raise ValueError(f"family {name!r} ({sl}) selects no dimension of {X.shape[1]}")
            covered[idx] += 1
            rms = float(np.sqrt(np.mean(np.sum(X[:, idx] ** 2, axis=1))))
            scale[idx] = rms if rms > 1e-12 else 1.0
        if not np.all(covered == 1):
            raise ValueError(
                f"families must partition the {X.shape[1]} dimensions; coverage {covered.tolist()}"
            )
        self.scale_ = scale
        return self

    def transform(self, X: np.ndarray) -> np.ndarray:
        """(m, d) points divided by the fitted ``scale_``: (m, d) float64."""
        if not hasattr(self, "scale_"):
            raise ValueError("this FamilyScaler is not fitted yet; call fit(X) first")
        return np.asarray(X, dtype=np.float64) / self.scale_

    def fit_transform(self, X: np.ndarray) -> np.ndarray:
        """Fit on (n, d) points and return them scaled: (n, d) float64."""
        return self.fit(X).transform(X)


def _fit(make: Callable[[], Scaler] | None, X: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    if make is None:
        return lambda x: np.asarray(x, dtype=np.float64)
    return make().fit(X).transform


def _space(name: str, dims: int) -> ConceptualSpace:
    return ConceptualSpace([Domain(name, tuple(f"{name}_{k}" for k in range(dims)))])


def prototype_distances(
    X: np.ndarray, labels: Sequence[str], scaler: Callable[[], Scaler] | None, domain: str = "space"
) -> tuple[list[dict[str, float]], dict[str, int]]:
    """Distance of every record to every label prototype, all records forming the prototypes.

    Args:
        X: (n, d) points.
        labels: n labels, one per point.
        scaler: factory of the scaler fitted on ``X`` (None: raw distances).
        domain: name of the single domain of the conceptual space built over ``X``.

    Returns:
        (per record ``{label: distance}``, ``{label: prototype support}``).
    """
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] != len(labels) or X.shape[0] < 2:
        raise ValueError(
            f"X has shape {X.shape} for {len(labels)} labels; expected (n >= 2, d) with n labels"
        )
    Z = _fit(scaler, X)(X)
    space = _space(domain, X.shape[1])
    ents = [space.entity(f"r{i}", {domain: z}) for i, z in enumerate(Z)]
    protos = space.prototypes(ents, list(labels))
    dists = [{lab: space.distance(e, p) for lab, p in protos.items()} for e in ents]
    return dists, {lab: int(p.support[domain]) for lab, p in protos.items()}


def leave_one_out(
    X: np.ndarray, labels: Sequence[str], scaler: Callable[[], Scaler] | None, domain: str = "space"
) -> list[str | None]:
    """Predicted label of each held-out record (None: its label has no other exemplar).

    The scaler (a fresh one from the factory) is fitted on the other records only.
    """
    X = np.asarray(X, dtype=np.float64)
    labels = [str(lab) for lab in labels]
    n = X.shape[0]
    if X.ndim != 2 or n != len(labels):
        raise ValueError(f"X has shape {X.shape} for {len(labels)} labels; expected (n, d) with n labels")
    out: list[str | None] = []
    space = _space(domain, X.shape[1])
    for i in range(n):
        keep = [j for j in range(n) if j != i]
        if labels[i] not in {labels[j] for j in keep} or len(keep) < 2:
            out.append(None)
            continue
        transform = _fit(scaler, X[keep])
        train = [space.entity(f"r{j}", {domain: transform(X[j])}) for j in keep]
        protos = space.prototypes(train, [labels[j] for j in keep])
        out.append(space.categorize(space.entity("held", {domain: transform(X[i])}), protos).label)
    return out


def loo_accuracy(predicted: Sequence[str | None], labels: Sequence[str]) -> float | None:
    """Fraction of held-out records categorised as their own label (None without records)."""
    if not labels:
        return None
    return sum(p == lab for p, lab in zip(predicted, labels, strict=True)) / len(labels)


def pca_2d(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project (n, d) points on their first two principal components.

    Returns:
        ((n, 2) coordinates, (2,) explained-variance fractions); with fewer than 2 points or no
        variance the coordinates are zero.
    """
    X = np.asarray(X, dtype=np.float64)
    Z = np.zeros((X.shape[0], 2))
    if X.shape[0] < 2:
        return Z, np.zeros(2)
    C = X - X.mean(axis=0)
    _, s, vt = np.linalg.svd(C, full_matrices=False)
    total = float((s**2).sum())
    if total <= 0:
        return Z, np.zeros(2)
    k = min(2, vt.shape[0])
    Z[:, :k] = C @ vt[:k].T
    explained = np.zeros(2)
    explained[:k] = s[:k] ** 2 / total
    return Z, explained
