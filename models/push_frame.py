"""The push frame: an object's surroundings seen along the line from the object to the effector.

Pushing on a level table looks the same from every horizontal direction: turn the whole scene
about the vertical axis through the object, and the object's displacement turns with it. A
mechanism fed world-frame vectors must learn this symmetry from data, one push direction at a
time; fed the vectors in the push frame it has it by construction. For an object at ``o`` and
the effector at ``e`` before the step, the frame turns the x-y plane by ``-phi`` with

    phi = atan2(e_y - o_y, e_x - o_x),      c = cos phi,  s = sin phi
    to_frame(v)   = ( c v_x + s v_y, -s v_x + c v_y, v_z, ...)      (the first two components)
    from_frame(u) = ( c u_x - s u_y,  s u_x + c u_y, u_z, ...)

so the effector lies on the frame's +x axis. :class:`PushFrameMechanism` gives a learned mechanism
its parents in this frame and :class:`FromPushFrameMechanism` turns its push-frame output back;
both are fixed (definitions, not learned) and serialisable. ``(c, s)`` are computed as ``(dx, dy) / sqrt(dx^2 +
dy^2 + eps^2)``: finite with a finite gradient everywhere, and (0, 0) (the frame collapses) only
when the effector is exactly above the object's centre.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from models.checks import check_float, check_int
from models.mechanisms import Mechanism, Seed

__all__ = [
    "EPS",
    "FromPushFrameMechanism",
    "PushFrameMechanism",
    "frame_angle",
    "from_push_frame",
    "to_push_frame",
]

#: Distance (in the vectors' units, m) below which the frame's direction fades to zero.
EPS = 1e-6


def frame_angle(effector: Tensor, origin: Tensor) -> tuple[Tensor, Tensor]:
    """``(cos phi, sin phi)``, each ``(..., 1)``, of the direction from ``origin`` to ``effector`` in x-y.

    Args:
        effector: ``(..., >= 2)`` the effector's position (x, y first).
        origin: ``(..., >= 2)`` the object's position, broadcastable against ``effector``.
    """
    _check("effector", effector)
    _check("origin", origin)
    dx = effector[..., :1] - origin[..., :1]
    dy = effector[..., 1:2] - origin[..., 1:2]
    r = (dx.pow(2) + dy.pow(2) + EPS**2).sqrt()
    return dx / r, dy / r


def to_push_frame(vectors: Tensor, cos: Tensor, sin: Tensor) -> Tensor:
    """World-frame ``vectors`` ``(..., >= 2)`` in the push frame (module docstring); other components kept.

    ``cos``, ``sin``: ``(..., 1)`` from :func:`frame_angle`, broadcastable against ``vectors``.
    """
    return _turn(vectors, cos, -sin)


def from_push_frame(vectors: Tensor, cos: Tensor, sin: Tensor) -> Tensor:
    """Push-frame ``vectors`` ``(..., >= 2)`` back in the world frame: the inverse of :func:`to_push_frame`."""
    return _turn(vectors, cos, sin)


def _turn(v: Tensor, c: Tensor, s: Tensor) -> Tensor:
    _check("vectors", v)
    x, y = v[..., :1], v[..., 1:2]
    rx, ry = c * x - s * y, s * x + c * y
    return torch.cat([rx, ry, v[..., 2:].expand(*rx.shape[:-1], v.shape[-1] - 2)], -1)


def _check(name: str, t: Tensor) -> None:
    if not isinstance(t, Tensor) or t.ndim == 0 or t.shape[-1] < 2:
        shape = tuple(t.shape) if isinstance(t, Tensor) else type(t).__name__
        raise ValueError(f"{name} must be a tensor (..., >= 2) with x, y first, got {shape}")


class PushFrameMechanism(Mechanism):
    """The object's surroundings in its push frame: every parent vector turned by ``-phi`` (module docstring).

    The parents are vectors relative to the object (the effector before and after the step, other
    points of the body, the object's previous displacement); ``phi`` is the direction of the
    ``reference`` one (the effector before the step), so that one's output lies on the +x axis.

    Args:
        vectors: the size of each parent vector in order (>= 2 each: x, y first); ``in_dim`` and
            ``out_dim`` are their sum.
        sigma: the fixed residual sd (a definition, not a prediction).
        reference: the index in ``vectors`` of the vector that defines ``phi``.

    Shapes: parents ``(..., sum(vectors))`` -> ``(..., sum(vectors))``.
    """

    kind = "push_frame"
    serialisable = True
    config_keys = frozenset({"vectors", "sigma", "in_dim", "reference"})

    def __init__(
        self, vectors: Sequence[int], sigma: float = 1e-4, in_dim: int | None = None, reference: int = 0
    ) -> None:
        sizes = [check_int("vectors[]", v, minimum=2) for v in vectors]
        if not sizes:
            raise ValueError("vectors must list at least one parent vector")
        if in_dim is not None and in_dim != sum(sizes):
            raise ValueError(f"in_dim must be sum(vectors) = {sum(sizes)}, got {in_dim}")
        reference = check_int("reference", reference, minimum=0, maximum=len(sizes) - 1)
        super().__init__(sum(sizes), sum(sizes), check_float("sigma", sigma, minimum=0.0, min_open=True))
        self.vectors, self.reference = tuple(sizes), reference

    @property
    def trainable(self) -> bool:
        """False: a definition, not learned."""
        return False

    def core(self, z: Tensor) -> Tensor:
        """Each vector of ``z`` turned into the frame of the first (the normalisers stay the identity)."""
        parts = z.split(list(self.vectors), -1)
        ref = parts[self.reference]
        c, s = frame_angle(ref, torch.zeros_like(ref[..., :2]))
        size = self.vectors[0]
        if all(v == size for v in self.vectors):  # one turn of all vectors, (..., n, size)
            stacked = z.unflatten(-1, (len(self.vectors), size))
            return to_push_frame(stacked, c[..., None, :], s[..., None, :]).flatten(-2)
        return torch.cat([to_push_frame(p, c, s) for p in parts], -1)

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments."""
        return {
            "kind": self.kind,
            "in_dim": self.in_dim,
            "vectors": list(self.vectors),
            "sigma": float(self.sigma.detach()[0]),
            "reference": self.reference,
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> PushFrameMechanism:
        """Build from :meth:`config` output without ``kind``; ``seed`` is unused."""
        return cls(**config)


class FromPushFrameMechanism(Mechanism):
    """A push-frame displacement back in the world frame: parents ``[r, u]`` -> ``from_frame(u)``, ``phi`` from ``r``.

    With ``base``, parents ``[b, r, u]`` -> ``b + from_frame(u)``: a position moved by the
    displacement in one site (``pos = pos_prev + from_frame(dpos)``), so that inference over it
    needs no latent copy of the world-frame displacement.

    Args:
        reference: the size of ``r`` (the effector relative to the object before the step, >= 2).
        out_dim: the size of ``u``, of ``b`` and of the output (>= 2).
        sigma: the fixed residual sd.
        base: read ``b`` first and add it.

    Shapes: parents ``(..., [out_dim +] reference + out_dim)`` -> ``(..., out_dim)``.
    """

    kind = "from_push_frame"
    serialisable = True
    config_keys = frozenset({"reference", "out_dim", "sigma", "in_dim", "base"})

    def __init__(
        self, reference: int, out_dim: int, sigma: float = 1e-4, in_dim: int | None = None, base: bool = False
    ) -> None:
        reference = check_int("reference", reference, minimum=2)
        out_dim = check_int("out_dim", out_dim, minimum=2)
        if not isinstance(base, bool):
            raise ValueError(f"base must be a bool, got {base!r}")
        width = reference + out_dim + (out_dim if base else 0)
        if in_dim is not None and in_dim != width:
            what = "out_dim + reference + out_dim" if base else "reference + out_dim"
            raise ValueError(f"in_dim must be {what} = {width}, got {in_dim}")
        super().__init__(width, out_dim, check_float("sigma", sigma, minimum=0.0, min_open=True))
        self.reference, self.base = reference, base

    @property
    def trainable(self) -> bool:
        """False: a definition, not learned."""
        return False

    def core(self, z: Tensor) -> Tensor:
        """``u`` turned back by ``phi`` of ``r``, plus ``b`` with ``base`` (the normalisers stay the identity)."""
        d = self.out_dim
        b, z = (z[..., :d], z[..., d:]) if self.base else (None, z)
        r, u = z[..., : self.reference], z[..., self.reference :]
        c, s = frame_angle(r, torch.zeros_like(r[..., :2]))
        turned = from_push_frame(u, c, s)
        return turned if b is None else b + turned

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments."""
        return {
            "kind": self.kind,
            "in_dim": self.in_dim,
            "reference": self.reference,
            "out_dim": self.out_dim,
            "sigma": float(self.sigma.detach()[0]),
            "base": self.base,
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> FromPushFrameMechanism:
        """Build from :meth:`config` output without ``kind``; ``seed`` is unused."""
        return cls(**config)
