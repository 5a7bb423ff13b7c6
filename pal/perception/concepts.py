"""Conceptual spaces (Eq. 1.3-1.7, 4.23-4.26): domains, salience, exemplars, prototypes, categories.

- A :class:`Domain` δ is a named product of integral quality dimensions (Eq. 1.4). Within a
  domain, distance is the weighted Euclidean (L2) metric ``sqrt(Σ_k v_k (x_k - y_k)²)``.
- A :class:`ConceptualSpace` is the product of its domains (Eq. 1.3) with salience weights
  w_δ > 0. Across the compared domains J, distance is the weighted L1 (Manhattan) sum
  ``Σ_{δ∈J} w_δ dist_δ`` (Eq. 1.6), the weights renormalised so that ``Σ_{δ∈J} w_δ = 1`` —
  i.e. a salience-weighted mean of the domain distances.
- An :class:`Entity` is a point c_i = [c_{i,δ}]_{δ∈J_i} defined in only some domains (Eq.
  4.23-4.25). Comparisons run over the domains both entities share, or over explicitly
  *required* domains, in which case a domain missing on either side is an error.
- Observed entities are exemplars; a prototype is the per-domain mean of the exemplars of a
  category that have that domain, with support N_{ℓ,δ} (Eq. 4.26). Categorisation is
  nearest-prototype (the Voronoi tessellation of Eq. 1.7) over one fixed set of domains, so the
  distances it compares are commensurable; ties go to the label that sorts first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Categorization", "ConceptualSpace", "Domain", "Entity"]


@dataclass(frozen=True)
class Domain:
    """A domain of integral quality dimensions.

    Attributes:
        name: domain name, e.g. ``"visual"``, ``"motion"``.
        dimensions: names of its quality dimensions.
        weights: per-dimension weights v_k > 0 of the within-domain L2 metric (default all 1).
    """

    name: str
    dimensions: tuple[str, ...]
    weights: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if not self.dimensions:
            raise ValueError(f"domain {self.name!r} has no quality dimension")
        if len(set(self.dimensions)) != len(self.dimensions):
            raise ValueError(f"domain {self.name!r} repeats a dimension name")
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=np.float64)
            if w.shape != (len(self.dimensions),) or not np.all(np.isfinite(w)) or np.any(w <= 0):
                raise ValueError(
                    f"domain {self.name!r}: weights must be {len(self.dimensions)} finite values > 0"
                )

    @property
    def size(self) -> int:
        """Number of quality dimensions of the domain."""
        return len(self.dimensions)

    def check(self, x: np.ndarray) -> np.ndarray:
        """``x`` as a finite (size,) float64 vector, or ValueError naming the domain."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.size,):
            raise ValueError(f"point in domain {self.name!r} has shape {x.shape}, expected ({self.size},)")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"point in domain {self.name!r} has NaN/inf values")
        return x

    def distance(self, x: np.ndarray, y: np.ndarray) -> float:
        """Weighted L2 distance between two points of this domain."""
        d = self.check(x) - self.check(y)
        w = np.ones(self.size) if self.weights is None else np.asarray(self.weights)
        return float(math.sqrt(float(np.sum(w * d * d))))


@dataclass(frozen=True, eq=False)
class Entity:
    """An exemplar or prototype: projections into some domains.

    Attributes:
        name: identifier (e.g. ``"box/translation"``).
        points: ``{domain name: (size,) point}``; the domains present are J_i.
        support: for prototypes, ``{domain: N_{ℓ,δ}}`` exemplars averaged; empty for exemplars.
    """

    name: str
    points: Mapping[str, np.ndarray]
    support: Mapping[str, int] = field(default_factory=dict)

    @property
    def domains(self) -> frozenset[str]:
        """Names of the domains the entity has a point in (J_i)."""
        return frozenset(self.points)


@dataclass(frozen=True)
class Categorization:
    """Nearest-prototype result: the winning ``label``, every prototype's distance, the domains used."""

    label: str
    distances: dict[str, float]
    domains: tuple[str, ...]


class ConceptualSpace:
    """The space C = Π δ with salience weights (module docstring).

    Args:
        domains: the domains (names unique).
        salience: ``{domain: w_δ > 0}``; default equal salience.
    """

    def __init__(self, domains: Sequence[Domain], salience: Mapping[str, float] | None = None) -> None:
        names = [d.name for d in domains]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"a conceptual space needs >= 1 domain with unique names; got {names}")
        self.domains: dict[str, Domain] = {d.name: d for d in domains}
        sal = {n: 1.0 for n in names} if salience is None else {str(k): float(v) for k, v in salience.items()}
        if set(sal) != set(names):
            raise ValueError(
                f"salience is given for {sorted(sal)}, expected exactly the domains {sorted(names)}"
            )
        bad = {k: v for k, v in sal.items() if not (math.isfinite(v) and v > 0)}
        if bad:
            raise ValueError(f"salience weights must be finite and > 0 (Eq. 1.6); got {bad}")
        self.salience = sal

    def weights(self, domains: Sequence[str]) -> dict[str, float]:
        """Salience of ``domains`` renormalised to sum to 1 (Eq. 1.6)."""
        J = list(dict.fromkeys(domains))
        unknown = [d for d in J if d not in self.domains]
        if unknown:
            raise ValueError(f"unknown domains {unknown}; the space has {sorted(self.domains)}")
        if not J:
            raise ValueError("no domain to compare over")
        total = sum(self.salience[d] for d in J)
        return {d: self.salience[d] / total for d in J}

    def entity(self, name: str, points: Mapping[str, np.ndarray]) -> Entity:
        """An exemplar, its points checked against their domains (Eq. 4.24-4.25)."""
        checked = {}
        for dom, x in points.items():
            if dom not in self.domains:
                raise ValueError(
                    f"entity {name!r}: unknown domain {dom!r}; the space has {sorted(self.domains)}"
                )
            checked[dom] = self.domains[dom].check(x)
        if not checked:
            raise ValueError(f"entity {name!r} has no projection into any domain")
        return Entity(name, checked)

    def compared_domains(self, a: Entity, b: Entity, domains: Sequence[str] | None = None) -> tuple[str, ...]:
        """J for a comparison: ``domains`` if given (each required on both sides), else the shared ones.

        Raises:
            ValueError: a required domain is missing on either side, or nothing is shared.
        """
        if domains is not None:
            for d in domains:
                missing = [e.name for e in (a, b) if d not in e.points]
                if missing:
                    raise ValueError(
                        f"required domain {d!r} is missing on {missing}; they have {sorted(a.domains)} and {sorted(b.domains)}"
                    )
            return tuple(dict.fromkeys(domains))
        shared = tuple(d for d in self.domains if d in a.points and d in b.points)
        if not shared:
            raise ValueError(
                f"{a.name!r} ({sorted(a.domains)}) and {b.name!r} ({sorted(b.domains)}) share no domain"
            )
        return shared

    def distance(self, a: Entity, b: Entity, domains: Sequence[str] | None = None) -> float:
        """dist_{C_J}(a, b) = Σ_{δ∈J} w_δ dist_δ(a_δ, b_δ) (Eq. 1.6) over J = :meth:`compared_domains`."""
        J = self.compared_domains(a, b, domains)
        w = self.weights(J)
        return float(sum(w[d] * self.domains[d].distance(a.points[d], b.points[d]) for d in J))

    def prototype(self, name: str, exemplars: Sequence[Entity]) -> Entity:
        """Per-domain mean of the exemplars that have the domain (Eq. 4.26), with its support."""
        if not exemplars:
            raise ValueError(f"prototype {name!r} needs at least one exemplar")
        points, support = {}, {}
        for dom in self.domains:
            xs = [e.points[dom] for e in exemplars if dom in e.points]
            if xs:
                points[dom] = np.mean(np.stack([self.domains[dom].check(x) for x in xs]), axis=0)
                support[dom] = len(xs)
        return Entity(name, points, support)

    def prototypes(self, exemplars: Sequence[Entity], labels: Sequence[str]) -> dict[str, Entity]:
        """One prototype per label, from the exemplars carrying it."""
        if len(exemplars) != len(labels):
            raise ValueError(f"{len(exemplars)} exemplars but {len(labels)} labels")
        groups: dict[str, list[Entity]] = {}
        for e, lab in zip(exemplars, labels, strict=True):
            groups.setdefault(str(lab), []).append(e)
        return {lab: self.prototype(lab, es) for lab, es in sorted(groups.items())}

    def categorize(
        self, entity: Entity, prototypes: Mapping[str, Entity], domains: Sequence[str] | None = None
    ) -> Categorization:
        """Nearest prototype (Eq. 1.7) over one set of domains for all prototypes.

        Args:
            entity: the exemplar to categorize.
            prototypes: label -> prototype.
            domains: required domains; default the entity's domains that every prototype has.

        Raises:
            ValueError: no prototypes, a required domain missing, or no usable domain.
        """
        if not prototypes:
            raise ValueError("categorize needs at least one prototype")
        if domains is None:
            common = [
                d
                for d in self.domains
                if d in entity.points and all(d in p.points for p in prototypes.values())
            ]
            if not common:
                raise ValueError(f"{entity.name!r} shares no domain with every prototype")
            domains = common
        dist = {lab: self.distance(entity, p, domains) for lab, p in prototypes.items()}
        best = min(sorted(dist), key=lambda lab: dist[lab])
        return Categorization(best, dist, tuple(domains))
