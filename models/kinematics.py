"""A known law of the body: forward kinematics of a chain of hinge joints, as a fixed mechanism.

A serial chain of J hinges from a fixed base to an end point. Frame k is reached from frame
k - 1 by a fixed transform ``(R_k, t_k)`` (the bodies between two hinges, composed), then a turn
by the angle ``q_k - ref_k`` about the unit axis ``a_k`` through the point ``p_k`` (both in frame
k's coordinates). With ``T(R, t) x = R x + t`` and Rodrigues' ``Rot(a, theta) = I + sin(theta) K +
(1 - cos(theta)) K^2`` (``K`` the cross-product matrix of ``a``)::

    F_0 = I,    F_k = F_{k-1} T(R_k, t_k) T(I, p_k) T(Rot(a_k, q_k - ref_k), 0) T(I, -p_k)
    x(q) = F_J e                                  (the end point e in the last frame)

This is how MuJoCo places bodies (``mj_kinematics``: a body's frame from its parent's and its
``pos``/``quat``, then each of its hinges in order about ``xanchor``, ``xaxis``), so a chain read
from an MJCF reproduces its bodies' ``xpos`` (``pal.agent.kinematics``).

:class:`KinematicMechanism` is the effector's motion over a step, from the joint angles before
it and their change, with the angles held inside the joints' limits (MuJoCo's limit constraint
stops a joint there, a learned joint model may not)::

    dee = x(clip(q_prev + dq)) - x(clip(q_prev)) + sigma * eps        (first ``out_dim`` coordinates)

It is fixed: :func:`inference.fit` leaves it as given. It serialises with its chain.
:class:`JointLimitMechanism` holds the joint angles themselves at the limits,
``q = clip(q_prev + dq) + sigma * eps``, so that a learned ``dq`` that overshoots a limit in a
rollout does not carry the next step's parents out of the range the joints can reach.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from models.checks import as_float_tensor, check_finite_tensor, check_float, check_int
from models.mechanisms import Mechanism, Seed

__all__ = ["JointLimitMechanism", "KinematicChain", "KinematicMechanism", "KinematicPointsMechanism"]


def _array(value: Any, shape: tuple[int, ...], name: str) -> Tensor:
    """A finite float64 tensor of exactly ``shape``; the error names the value and the shape."""
    tensor = as_float_tensor(value, name, torch.float64)
    if tuple(tensor.shape) != shape:
        raise ValueError(f"{name} must have shape {shape}, got {tuple(tensor.shape)}")
    return check_finite_tensor(name, tensor)


def _limits(value: Any, joints: int | None = None) -> Tensor:
    """Joint limits ``(n, 2)`` float64 from pairs ``(low, high)``, ``None`` meaning unlimited on that side.

    Raises:
        ValueError: not ``n >= 1`` pairs (``joints`` of them when given), NaN, or low > high.
    """
    try:
        rows = [
            [float("-inf") if r[0] is None else r[0], float("inf") if r[1] is None else r[1]] for r in value
        ]
    except (TypeError, IndexError) as exc:
        raise ValueError(f"limits must be pairs (low, high), got {value!r}") from exc
    table = as_float_tensor(rows, "limits", torch.float64)
    n = joints if joints is not None else len(rows)
    if table.ndim != 2 or tuple(table.shape) != (n, 2) or n < 1 or bool(torch.isnan(table).any()):
        raise ValueError(f"limits must be {joints or 'n >= 1'} pairs (low, high), got {rows}")
    if bool((table[:, 0] > table[:, 1]).any()):
        raise ValueError(f"limits must have low <= high, got {rows}")
    return table


def _clip(q: Tensor, limits: Tensor) -> Tensor:
    """``q`` ``(..., n)`` held inside ``limits`` ``(n, 2)``."""
    low, high = limits.to(q.dtype).unbind(1)
    return torch.maximum(torch.minimum(q, high), low)


def _limits_json(limits: Tensor) -> list[list[float | None]]:
    """``(n, 2)`` limits as JSON rows, ``None`` for an infinite side."""
    return [[None if abs(v) == float("inf") else v for v in row] for row in limits.tolist()]


class KinematicChain(torch.nn.Module):
    """Forward kinematics ``x(q)`` of J hinges (module docstring).

    Args:
        rotations: ``(J, 3, 3)`` the fixed rotations R_k. translations: ``(J, 3)`` t_k.
        anchors: ``(J, 3)`` p_k. axes: ``(J, 3)`` a_k (normalised here). refs: ``(J,)`` ref_k, rad.
        end: ``(3,)`` the end point e in the last hinge's frame.
        limits: ``(J, 2)`` each joint's ``(low, high)``, rad (``-inf``/``inf`` for none).

    Shapes: :meth:`forward` ``(..., J) -> (..., 3)``.

    Raises:
        ValueError: shapes that disagree, non-finite values, a zero axis, low > high.
    """

    def __init__(
        self,
        rotations: Any,
        translations: Any,
        anchors: Any,
        axes: Any,
        refs: Any,
        end: Any,
        limits: Any,
    ) -> None:
        super().__init__()
        refs = as_float_tensor(refs, "refs", torch.float64)
        if refs.ndim != 1 or len(refs) < 1:
            raise ValueError(f"refs must be a vector of J >= 1 angles, got {refs.tolist()}")
        check_finite_tensor("refs", refs)
        j = len(refs)
        axes = _array(axes, (j, 3), "axes")
        norms = axes.norm(dim=1, keepdim=True)
        if not bool((norms > 1e-9).all()):
            raise ValueError(f"axes must be nonzero, got {axes.tolist()}")
        limits = _limits(limits, j)
        self.register_buffer("rotations", _array(rotations, (j, 3, 3), "rotations"))
        self.register_buffer("translations", _array(translations, (j, 3), "translations"))
        self.register_buffer("anchors", _array(anchors, (j, 3), "anchors"))
        self.register_buffer("axes", axes / norms)
        self.register_buffer("refs", refs)
        self.register_buffer("end", _array(end, (3,), "end"))
        self.register_buffer("limits", limits)
        self._derive()
        self.register_load_state_dict_post_hook(lambda module, _keys: module._derive())

    @property
    def joints(self) -> int:
        """J, the number of hinges."""
        return len(self.refs)

    def clip(self, q: Tensor) -> Tensor:
        """``q`` ``(..., J)`` held inside the joints' limits."""
        return _clip(q, self.limits)

    def _derive(self) -> None:
        """Per hinge: ``R_k K_k``, ``R_k K_k^2`` ``(J, 3, 3)``, ``R_k K_k p_k``, ``R_k K_k^2 p_k`` ``(J, 3)``.

        With them one hinge is ``M = R_k + sin A + (1 - cos) B`` (``R_k Rot``) and the frame's
        origin moves by ``F (t_k - sin a - (1 - cos) b)``: the anchor's ``R_k p_k`` cancels. Kept
        per dtype (derived from the chain's buffers, which are fixed).
        """
        k = torch.zeros(self.joints, 3, 3, dtype=torch.float64)
        ax = self.axes
        k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -ax[:, 2], ax[:, 1], -ax[:, 0]
        k = k - k.transpose(1, 2)
        a_mat, b_mat = self.rotations @ k, self.rotations @ k @ k
        a_vec = (a_mat @ self.anchors[..., None])[..., 0]
        b_vec = (b_mat @ self.anchors[..., None])[..., 0]
        terms = (self.rotations, a_mat, b_mat, self.translations, a_vec, b_vec, self.refs, self.end)
        self._terms = {dtype: tuple(t.to(dtype) for t in terms) for dtype in (torch.float32, torch.float64)}

    def forward(self, q: Tensor) -> Tensor:
        """The end point ``x(q)``: ``(..., J) -> (..., 3)`` (world coordinates, the base's units)."""
        rot, pos = self.frame(q)
        return pos + (rot @ self._terms[q.dtype][-1][:, None])[..., 0]

    def same_hinges(self, other: KinematicChain) -> bool:
        """True when ``other`` differs from this chain at most in its end point (one body, other points)."""
        names = ("rotations", "translations", "anchors", "axes", "refs", "limits")
        return all(torch.equal(getattr(self, n), getattr(other, n)) for n in names)

    def frame(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """The last hinge's body frame at ``q`` ``(..., J)``: rotation ``(..., 3, 3)`` and origin ``(..., 3)``.

        A point ``p`` fixed in that body is at ``origin + rotation @ p``.
        """
        if q.shape[-1] != self.joints:
            raise ValueError(f"joint angles have last dim {q.shape[-1]}, expected {self.joints}")
        if q.dtype not in self._terms:
            raise ValueError(f"joint angles must be float32 or float64, got {q.dtype}")
        rot_k, a_mat, b_mat, t_k, a_vec, b_vec, refs, _ = self._terms[q.dtype]
        theta = q - refs
        s, c = theta.sin()[..., None], (1 - theta.cos())[..., None]  # (..., J, 1)
        steps = (t_k - s * a_vec - c * b_vec)[..., None]  # (..., J, 3, 1), all hinges at once
        turns = rot_k + s[..., None] * a_mat + c[..., None] * b_mat  # (..., J, 3, 3)
        rot, pos = turns[..., 0, :, :], steps[..., 0, :, :]
        for k in range(1, self.joints):
            pos = pos + rot @ steps[..., k, :, :]
            rot = rot @ turns[..., k, :, :]
        return rot, pos[..., 0]

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments (limits as ``None`` for infinite)."""
        return {
            "rotations": self.rotations.tolist(),
            "translations": self.translations.tolist(),
            "anchors": self.anchors.tolist(),
            "axes": self.axes.tolist(),
            "refs": self.refs.tolist(),
            "end": self.end.tolist(),
            "limits": _limits_json(self.limits),
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> KinematicChain:
        """Inverse of :meth:`config`."""
        return cls(**config)


class KinematicMechanism(Mechanism):
    """``dee = x(clip(q_prev + dq)) - x(clip(q_prev))``, the first ``out_dim`` coordinates (module docstring).

    Args:
        chain: the :class:`KinematicChain` (or its :meth:`KinematicChain.config`).
        columns: for each hinge of the chain, its column in the body's joint vector q.
        joints: n, the length of q (the chain may use some of the joints only).
        out_dim: effector coordinates kept (1-3). sigma: the fixed residual sd, in the
            effector's units.

    Shapes: parents ``(..., 2 n)`` = ``[q_prev, dq]`` -> ``(..., out_dim)``.

    Raises:
        ValueError: columns that are not J distinct indices below ``joints``, ``out_dim``
            outside 1-3, an ``in_dim`` other than 2 n, sigma <= 0.
    """

    kind = "kinematic"
    serialisable = True
    config_keys = frozenset({"chain", "columns", "joints", "out_dim", "sigma", "in_dim"})

    def __init__(
        self,
        chain: Any,
        columns: Sequence[int],
        joints: int,
        out_dim: int = 3,
        sigma: float = 1e-4,
        in_dim: int | None = None,
    ) -> None:
        if isinstance(chain, Mapping):
            chain = KinematicChain.from_config(chain)
        if not isinstance(chain, KinematicChain):
            raise ValueError(f"chain must be a KinematicChain or its config, got {type(chain).__name__}")
        joints = check_int("joints", joints, minimum=1)
        cols = [check_int("columns[]", c, minimum=0) for c in columns]
        if len(cols) != chain.joints or len(set(cols)) != len(cols) or max(cols) >= joints:
            raise ValueError(
                f"columns must be {chain.joints} distinct joint indices below {joints}, got {list(columns)}"
            )
        out_dim = check_int("out_dim", out_dim, minimum=1)
        if out_dim > 3:
            raise ValueError(f"out_dim must be 1-3 coordinates of the end point, got {out_dim}")
        if in_dim is not None and in_dim != 2 * joints:
            raise ValueError(f"in_dim must be 2 n = {2 * joints} for {joints} joints, got {in_dim}")
        super().__init__(2 * joints, out_dim, check_float("sigma", sigma, minimum=0.0, min_open=True))
        self.chain, self.columns, self.joints = chain, tuple(cols), joints

    @property
    def trainable(self) -> bool:
        """False: a known law is given, not learned."""
        return False

    def core(self, z: Tensor) -> Tensor:
        """The effector's motion from ``[q_prev, dq]`` (the normalisers stay the identity)."""
        cols = list(self.columns)
        q_prev, dq = z[..., : self.joints][..., cols], z[..., self.joints :][..., cols]
        ends = self.chain(self.chain.clip(torch.stack([q_prev, q_prev + dq])))
        return (ends[1] - ends[0])[..., : self.out_dim]

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments."""
        return {
            "kind": self.kind,
            "in_dim": self.in_dim,
            "chain": self.chain.config(),
            "columns": list(self.columns),
            "joints": self.joints,
            "out_dim": self.out_dim,
            "sigma": float(self.sigma.detach()[0]),
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> KinematicMechanism:
        """Build from :meth:`config` output without ``kind``; ``seed`` is unused (nothing is random)."""
        return cls(**config)


class KinematicPointsMechanism(Mechanism):
    """Points of the body at the joint angles: ``[x_1(clip(q)), ..., x_P(clip(q))]``, one chain per point.

    Args:
        chains: P :class:`KinematicChain` (or their configs) over the same hinges.
        columns: each hinge's column in the body's joint vector q.
        joints: n, the length of q.
        sigma: the fixed residual sd, m.

    Shapes: parents ``(..., n)`` = ``q`` -> ``(..., 3 P)``.
    """

    kind = "kinematic_points"
    serialisable = True
    config_keys = frozenset({"chains", "columns", "joints", "sigma", "in_dim"})

    def __init__(
        self,
        chains: Sequence[Any],
        columns: Sequence[int],
        joints: int,
        sigma: float = 1e-4,
        in_dim: int | None = None,
    ) -> None:
        built = [KinematicChain.from_config(c) if isinstance(c, Mapping) else c for c in chains]
        if not built or not all(isinstance(c, KinematicChain) for c in built):
            raise ValueError(f"chains must be one or more KinematicChains or their configs, got {len(built)}")
        joints = check_int("joints", joints, minimum=1)
        cols = [check_int("columns[]", c, minimum=0) for c in columns]
        if any(len(cols) != c.joints for c in built) or len(set(cols)) != len(cols) or max(cols) >= joints:
            raise ValueError(
                f"columns must be {built[0].joints} distinct joint indices below {joints} for every chain, got {list(columns)}"
            )
        if in_dim is not None and in_dim != joints:
            raise ValueError(f"in_dim must be n = {joints}, got {in_dim}")
        super().__init__(joints, 3 * len(built), check_float("sigma", sigma, minimum=0.0, min_open=True))
        self.chains = torch.nn.ModuleList(built)
        self.columns, self.joints = tuple(cols), joints
        # Points of one body (chains that differ only in their end) share one pass down the chain.
        self._shared = all(built[0].same_hinges(c) for c in built[1:])
        self.register_buffer("ends", torch.stack([c.end for c in built]), persistent=False)

    @property
    def trainable(self) -> bool:
        """False: a known law is given, not learned."""
        return False

    def core(self, z: Tensor) -> Tensor:
        """The points from ``q`` (the normalisers stay the identity)."""
        q = z[..., list(self.columns)]
        if not self._shared:
            return torch.cat([c(c.clip(q)) for c in self.chains], -1)
        first = self.chains[0]
        rot, origin = first.frame(first.clip(q))
        points = origin[..., None, :] + (rot @ self.ends.to(q.dtype).T).transpose(-1, -2)  # (..., P, 3)
        return points.flatten(-2)

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments."""
        return {
            "kind": self.kind,
            "in_dim": self.in_dim,
            "chains": [c.config() for c in self.chains],
            "columns": list(self.columns),
            "joints": self.joints,
            "sigma": float(self.sigma.detach()[0]),
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> KinematicPointsMechanism:
        """Build from :meth:`config` output without ``kind``; ``seed`` is unused."""
        return cls(**config)


class JointLimitMechanism(Mechanism):
    """``q = clip(q_prev + dq, low, high) + sigma * eps`` per joint (module docstring).

    Args:
        limits: ``(n, 2)`` each joint's ``(low, high)``, rad (``None`` or inf for none).
        sigma: the fixed residual sd, rad.

    Shapes: parents ``(..., 2 n)`` = ``[q_prev, dq]`` -> ``(..., n)``.
    """

    kind = "joint_limits"
    serialisable = True
    config_keys = frozenset({"limits", "sigma", "in_dim"})

    def __init__(self, limits: Any, sigma: float = 1e-4, in_dim: int | None = None) -> None:
        table = _limits(limits)
        n = len(table)
        if in_dim is not None and in_dim != 2 * n:
            raise ValueError(f"in_dim must be 2 n = {2 * n} for {n} joints, got {in_dim}")
        super().__init__(2 * n, n, check_float("sigma", sigma, minimum=0.0, min_open=True))
        self.register_buffer("limits", table)

    @property
    def trainable(self) -> bool:
        """False: the limits are given, not learned."""
        return False

    def core(self, z: Tensor) -> Tensor:
        """``clip(q_prev + dq)`` from ``[q_prev, dq]`` (the normalisers stay the identity)."""
        n = self.out_dim
        return _clip(z[..., :n] + z[..., n:], self.limits)

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments (``None`` for an infinite limit)."""
        return {
            "kind": self.kind,
            "in_dim": self.in_dim,
            "limits": _limits_json(self.limits),
            "sigma": float(self.sigma.detach()[0]),
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> JointLimitMechanism:
        """Build from :meth:`config` output without ``kind``; ``seed`` is unused."""
        return cls(**config)
