"""Sensor transforms: observation entries -> the quantity a role needs, declared in the spec.

Gymnasium's MuJoCo tasks often give a quantity in another form than the world model's: joint
angles as cosines and sines, an effector relative to the goal. A :class:`Transform` on a
:class:`pal.agent.spec.Sensor` maps the sensor's raw entries ``r`` (n,) (and, for
:func:`absolute_from_relative`, the observation) to the quantity ``x`` (m,):

- :func:`angle_from_cos_sin`: ``r = [cos q_1..J, sin q_1..J]`` (``layout="blocks"``, Gymnasium's
  Reacher) or ``[cos q_1, sin q_1, ...]`` (``"pairs"``) -> ``q = atan2(sin, cos)`` (J,), rad in
  (-pi, pi]; inverse ``[cos q, sin q]``.
- :func:`absolute_from_relative`: ``x = r + sign * obs[to]`` (e.g. the fingertip from
  ``fingertip - target`` and the target, ``sign=+1``); inverse ``r = x - sign * obs[to]``.
- :func:`index_map`: ``x = r[order]`` (a reordering or a selection); no inverse for a selection.

Each transform checks its entries when the spec is made (:meth:`Transform.check_size`: e.g. an
odd number of cos/sin entries) and on the first observation (:meth:`Transform.check_values`:
cos^2 + sin^2 = 1 within ``tolerance``). The inverses are closed forms, no Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pal.checks import check_int

__all__ = ["COS_SIN_TOLERANCE", "Transform", "absolute_from_relative", "angle_from_cos_sin", "index_map"]

#: How far ``cos^2 + sin^2`` may be from 1 on the first observation.
COS_SIN_TOLERANCE = 1e-3

_KINDS = ("angle_from_cos_sin", "absolute_from_relative", "index_map")


@dataclass(frozen=True)
class Transform:
    """One sensor transform (module docstring); make it with the functions below.

    Attributes:
        kind: ``"angle_from_cos_sin"``, ``"absolute_from_relative"`` or ``"index_map"``.
        layout: cos/sin order, ``"blocks"`` or ``"pairs"`` (angle_from_cos_sin).
        to: observation indices of the reference (absolute_from_relative).
        sign: +1 or -1, ``x = r + sign * obs[to]`` (absolute_from_relative).
        order: indices into the raw entries (index_map).
    """

    kind: str
    layout: str = "blocks"
    to: tuple[int, ...] = ()
    sign: float = 1.0
    order: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ValueError(f"transform kind {self.kind!r} unknown; expected one of {list(_KINDS)}")
        if self.layout not in ("blocks", "pairs"):
            raise ValueError(f"cos/sin layout {self.layout!r} unknown; expected 'blocks' or 'pairs'")
        if self.sign not in (1.0, -1.0):
            raise ValueError(f"sign is {self.sign!r}; expected +1 or -1")
        object.__setattr__(self, "to", tuple(check_int("reference index", i, minimum=0) for i in self.to))
        object.__setattr__(
            self, "order", tuple(check_int("index map entry", i, minimum=0) for i in self.order)
        )
        if self.kind == "absolute_from_relative" and not self.to:
            raise ValueError("absolute_from_relative needs the reference's observation indices (to=...)")
        if self.kind == "index_map" and not self.order:
            raise ValueError("index_map needs at least one index (order=...)")

    def out_dim(self, n: int) -> int:
        """The quantity's size for ``n`` raw entries.

        Raises:
            ValueError: the entries do not fit the transform (odd cos/sin count, a reference of
                another size, an index map entry out of range).
        """
        if self.kind == "angle_from_cos_sin":
            if n % 2:
                raise ValueError(f"angle_from_cos_sin reads cos/sin pairs; got {n} entries, an odd number")
            return n // 2
        if self.kind == "absolute_from_relative":
            if len(self.to) != n:
                raise ValueError(
                    f"absolute_from_relative: reference to={list(self.to)} has {len(self.to)} entries, "
                    f"the sensor {n}; they must match"
                )
            return n
        bad = [i for i in self.order if i >= n]
        if bad:
            raise ValueError(f"index map entry {bad[0]} is out of range for {n} raw entries")
        return len(self.order)

    def _cos_sin(self, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        j = raw.shape[-1] // 2
        if self.layout == "blocks":
            return raw[..., :j], raw[..., j:]
        return raw[..., 0::2], raw[..., 1::2]

    def apply(self, raw: np.ndarray, observation: np.ndarray | None) -> np.ndarray:
        """``r (n,) -> x (m,)``; ``observation`` (the whole vector) is read by absolute_from_relative."""
        if self.kind == "angle_from_cos_sin":
            c, s = self._cos_sin(raw)
            return np.arctan2(s, c)
        if self.kind == "absolute_from_relative":
            if observation is None:
                raise ValueError("absolute_from_relative reads its reference from the observation")
            return raw + self.sign * np.asarray(observation, dtype=np.float64)[list(self.to)]
        return raw[list(self.order)]

    def inverse(self, value: np.ndarray, observation: np.ndarray | None = None) -> np.ndarray:
        """``x (m,) -> r (n,)``, the raw entries that give ``value`` (closed form).

        Raises:
            ValueError: an index map that selects (not a permutation) has no inverse.
        """
        x = np.asarray(value, dtype=np.float64)
        if self.kind == "angle_from_cos_sin":
            c, s = np.cos(x), np.sin(x)
            if self.layout == "blocks":
                return np.concatenate([c, s], -1)
            return np.stack([c, s], -1).reshape(*x.shape[:-1], -1)
        if self.kind == "absolute_from_relative":
            if observation is None:
                raise ValueError("absolute_from_relative reads its reference from the observation")
            return x - self.sign * np.asarray(observation, dtype=np.float64)[list(self.to)]
        if sorted(self.order) != list(range(len(self.order))):
            raise ValueError(
                f"index map {list(self.order)} selects entries; only a permutation has an inverse"
            )
        out = np.empty_like(x)
        out[..., list(self.order)] = x
        return out

    def check_values(self, raw: np.ndarray, what: str) -> None:
        """Check the first observation's raw entries: cos^2 + sin^2 = 1 (angle_from_cos_sin).

        Raises:
            ValueError: entries that are not cosines and sines of the same angles.
        """
        if self.kind != "angle_from_cos_sin":
            return
        c, s = self._cos_sin(np.asarray(raw, dtype=np.float64))
        norm = c**2 + s**2
        bad = np.flatnonzero(np.abs(norm - 1.0) > COS_SIN_TOLERANCE)
        if bad.size:
            k = int(bad[0])
            raise ValueError(
                f"{what}: cos^2 + sin^2 of pair {k} is {norm[k]:.4f} on the first observation, expected 1 "
                f"within {COS_SIN_TOLERANCE}; check the indices and layout={self.layout!r}"
            )


def angle_from_cos_sin(layout: str = "blocks") -> Transform:
    """Angles from cosines and sines: ``q = atan2(sin, cos)`` (module docstring)."""
    return Transform("angle_from_cos_sin", layout=layout)


def absolute_from_relative(to: tuple[int, ...], sign: float = 1.0) -> Transform:
    """An absolute quantity from one given relative to the observation entries ``to``: ``x = r + sign * obs[to]``."""
    return Transform("absolute_from_relative", to=tuple(to), sign=float(sign))


def index_map(order: tuple[int, ...]) -> Transform:
    """The raw entries reordered or selected: ``x = r[order]``."""
    return Transform("index_map", order=tuple(order))
