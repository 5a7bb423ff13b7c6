"""The agent's sensorimotor history H_t (thesis Eq. 4.4) as columns, and its world-model training columns.

One row per executed step t-1 -> t. ``act`` (A,) the executed actions; ``q_prev``, ``q`` (J,) joint
angles, rad, and with ``velocities`` ``v_prev``, ``v`` (J,) rad/s. Effector: ``hand_prev``, ``hand``
(E,) m. Per object o: ``touch`` (contact sensed over the step, 0 without touch sensing),
``meas_prev``/``meas`` (d,) its sensed or perceived position, m, and ``std`` (d,) the 1-sigma of a
perceived one (0 for a sensed one); ``est_prev``/``est`` (d,) the agent's state estimate; with
``momentum`` ``vel_prev`` (d,) its displacement over the previous step. Missing evidence is NaN
*inside this store only*: :meth:`History.columns` drops those rows, so no NaN reaches the world
model. ``truth_prev``/``truth`` (d,) are ground-truth positions and ``state`` the simulator state
before the step, copied from the environment's ``info`` when it reports them, for evaluation and
exact replay (the agent never reads them; NaN and empty otherwise). ``episode`` is the episode index.

On disk a history is a checked, compressed ``.npz`` of :mod:`pal.io.files` (format
:data:`FORMAT`): one array per field, and as metadata the joints, objects, provenance (seed
and config when known) and the caller's metadata; library versions are added.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pal.io.files import FileFormatError, check_json, read_npz, write_npz

__all__ = [
    "CONTACT_LABELS",
    "FIELDS",
    "FORMAT",
    "MOMENTUM_FIELDS",
    "SOURCES",
    "VELOCITY_FIELDS",
    "History",
    "contact_label",
    "relative",
]

#: Format tag of history files.
FORMAT = "pal.history/1"

#: Per-row fields of every history (J joints, O objects, S state entries).
FIELDS = (
    "episode",
    "act",
    "q_prev",
    "q",
    "hand_prev",
    "hand",
    "touch",
    "meas_prev",
    "meas",
    "std",
    "est_prev",
    "est",
    "truth_prev",
    "truth",
    "state",
)
#: Fields of histories with joint velocities and with object momentum.
VELOCITY_FIELDS = ("v_prev", "v")
MOMENTUM_FIELDS = ("vel_prev",)
#: Position sources of :meth:`History.columns`.
SOURCES = ("perceived", "truth")
#: What :meth:`History.columns` puts in ``contact.o``: the sensed touch as it is (a strength in
#: [0, 1]), the touch as a 0/1 switch (1 when any touch was sensed over the step), or the
#: moved rule for worlds without touch sensing (:func:`contact_label`).
CONTACT_LABELS = ("strength", "touch", "moved")


_DEFAULT_OPTIONS: dict[str, Any] = {
    "actions": None,
    "effector_dim": 3,
    "object_dim": 2,
    "velocities": False,
    "momentum": False,
}


def relative(effector: np.ndarray, position: np.ndarray) -> np.ndarray:
    """The effector relative to an object: ``ee - [pos, 0]``, ``(N, E)`` from ``(N, E)`` and ``(N, d)``, m."""
    ee = np.asarray(effector, dtype=np.float64)
    p = np.asarray(position, dtype=np.float64)
    out = ee.copy()
    k = min(p.shape[-1], ee.shape[-1])
    out[..., :k] -= p[..., :k]
    return out


def contact_label(touch: np.ndarray, dpos: np.ndarray, rule: str, floor: float = 0.0) -> np.ndarray:
    """The ``contact.o`` column ``(N, 1)`` of one object under a rule of :data:`CONTACT_LABELS`.

    ``"strength"``: the touch as sensed. ``"touch"``: 1 where ``touch > 0`` (the arm touched the
    object in some sub-step), else 0. ``"moved"`` (worlds without touch sensing): 1 where the
    object moved more than its noise floor over the step, ``||dpos|| > floor``, else 0.

    Args:
        touch: ``(N,)`` sensed touch (zeros without touch sensing).
        dpos: ``(N, d)`` the object's displacement over the step, m.
        rule: one of :data:`CONTACT_LABELS`.
        floor: the moved rule's noise floor, m (>= 0).

    Raises:
        ValueError: an unknown rule or a negative or non-finite floor, naming the value.
    """
    if rule not in CONTACT_LABELS:
        raise ValueError(f"contact rule {rule!r} unknown; expected one of {list(CONTACT_LABELS)}")
    if not np.isfinite(floor) or floor < 0:
        raise ValueError(f"the moved rule's floor must be finite and >= 0, got {floor!r}")
    t = np.asarray(touch, dtype=np.float64).reshape(-1, 1)
    if rule == "strength":
        return t
    if rule == "touch":
        return (t > 0).astype(np.float64)
    moved = np.linalg.norm(np.asarray(dpos, dtype=np.float64), axis=-1) > floor
    return moved.astype(np.float64).reshape(-1, 1)


class History:
    """Columnar sensorimotor history (module docstring).

    Args:
        joints: joint names (J).
        objects: object slot names (``pos.<o>`` ...).
        provenance: how the history was made, e.g. ``{"seed": 0, "config": {...}}``
            (JSON-compatible); :meth:`save` records it.
        actions: number of actions A (default J).
        effector_dim: E, the effector's dim.
        object_dim: d, every object's position dim.
        velocities: rows also hold joint velocities.
        momentum: rows also hold each object's previous displacement.
    """

    def __init__(
        self,
        joints: Sequence[str],
        objects: Sequence[str],
        provenance: Mapping[str, Any] | None = None,
        *,
        actions: int | None = None,
        effector_dim: int = 3,
        object_dim: int = 2,
        velocities: bool = False,
        momentum: bool = False,
    ) -> None:
        self.joints, self.objects = tuple(joints), tuple(objects)
        self.provenance: dict[str, Any] = dict(provenance or {})
        self.actions = len(self.joints) if actions is None else int(actions)
        self.effector_dim, self.object_dim = int(effector_dim), int(object_dim)
        self.velocities, self.momentum = bool(velocities), bool(momentum)
        self.fields = FIELDS + VELOCITY_FIELDS * self.velocities + MOMENTUM_FIELDS * self.momentum
        self._rows: dict[str, list[np.ndarray]] = {f: [] for f in self.fields}

    @property
    def options(self) -> dict[str, Any]:
        """The layout keywords of this history (JSON-compatible)."""
        return {
            "actions": self.actions,
            "effector_dim": self.effector_dim,
            "object_dim": self.object_dim,
            "velocities": self.velocities,
            "momentum": self.momentum,
        }

    def __len__(self) -> int:
        return len(self._rows["episode"])

    def append(self, **row: Any) -> None:
        """Add one step; every field of :attr:`fields` is required."""
        missing = sorted(set(self.fields) - set(row))
        extra = sorted(set(row) - set(self.fields))
        if missing or extra:
            raise ValueError(f"history row: missing fields {missing}, unknown fields {extra}")
        j, o, d = len(self.joints), len(self.objects), self.object_dim
        shapes = {"act": (self.actions,), "q_prev": (j,), "q": (j,), "touch": (o,)}
        shapes.update({k: (self.effector_dim,) for k in ("hand_prev", "hand")})
        shapes.update({k: (j,) for k in VELOCITY_FIELDS if self.velocities})
        for key in ("meas_prev", "meas", "std", "est_prev", "est", "truth_prev", "truth", *MOMENTUM_FIELDS):
            shapes[key] = (o, d)
        for key, shape in shapes.items():
            if key not in self._rows:
                continue
            value = np.asarray(row[key], dtype=np.float64)
            if value.shape != shape:
                raise ValueError(f"history row {key!r} has shape {value.shape}, expected {shape}")
        for key in self.fields:
            self._rows[key].append(np.array(row[key], dtype=np.int64 if key == "episode" else np.float64))

    def array(self, field: str) -> np.ndarray:
        """All rows of one field stacked: (N, ...)."""
        if field not in self._rows:
            raise ValueError(f"unknown history field {field!r}; fields are {list(self.fields)}")
        rows = self._rows[field]
        if not rows:
            raise ValueError("the history is empty")
        return np.stack(rows)

    def columns(
        self,
        source: str = "perceived",
        rows: np.ndarray | slice | None = None,
        *,
        contact: str = "strength",
        floor: float = 0.0,
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, np.ndarray]]]:
        """World-model training columns (:mod:`pal.agent.graph`), float32 ``(n, dim)`` (Eq. 4.33).

        Args:
            source: ``"perceived"`` (object positions are the measurements) or ``"truth"``.
            rows: a subset of rows (indices, boolean mask or slice); default all.
            contact: the rule of ``contact.o`` (:func:`contact_label`).
            floor: the moved rule's noise floor, m.

        Returns:
            ``(arm, objects)``: ``arm`` has ``act``, ``q_prev``, ``dq``, ``q`` (and ``v_prev``,
            ``v``), ``ee_prev``, ``dee``, ``ee`` for every row; ``objects[o]`` has
            ``pos_prev.o``, ``dpos.o``, ``pos.o``, ``rel_prev.o``, ``rel.o``, ``contact.o`` (and
            ``vel_prev.o``) plus the arm's columns for the rows where both positions of o (and
            its previous displacement) are known.
        """
        if source not in SOURCES:
            raise ValueError(f"source {source!r} unknown; expected one of {SOURCES}")
        contact_label(np.zeros(0), np.zeros((0, 1)), contact, floor)  # checks the rule and floor
        idx = np.arange(len(self))[rows if rows is not None else slice(None)]
        get = lambda f: self.array(f)[idx]  # noqa: E731
        q_prev, q, ee_prev, ee = get("q_prev"), get("q"), get("hand_prev"), get("hand")
        arm = {"act": get("act"), "q_prev": q_prev, "dq": q - q_prev, "q": q}
        if self.velocities:
            arm["v_prev"], arm["v"] = get("v_prev"), get("v")
        arm.update({"ee_prev": ee_prev, "dee": ee - ee_prev, "ee": ee})
        prev_key, key = ("meas_prev", "meas") if source == "perceived" else ("truth_prev", "truth")
        prev, now, touch = get(prev_key), get(key), get("touch")
        vel = get("vel_prev") if self.momentum else None
        objects = {}
        for k, o in enumerate(self.objects):
            ok = np.isfinite(prev[:, k]).all(1) & np.isfinite(now[:, k]).all(1)
            if vel is not None:
                ok &= np.isfinite(vel[:, k]).all(1)
            p = prev[ok, k]
            cols = {
                f"pos_prev.{o}": p,
                f"pos.{o}": now[ok, k],
                f"dpos.{o}": now[ok, k] - p,
                f"contact.{o}": contact_label(touch[ok, k], now[ok, k] - p, contact, floor),
                f"rel_prev.{o}": relative(ee_prev[ok], p),
                f"rel.{o}": relative(ee[ok], p),
                **{k: v[ok] for k, v in arm.items()},
            }
            if vel is not None:
                cols[f"vel_prev.{o}"] = vel[ok, k]
            objects[o] = cols
        as32 = lambda d: {n: np.ascontiguousarray(v, dtype=np.float32) for n, v in d.items()}  # noqa: E731
        return as32(arm), {o: as32(v) for o, v in objects.items()}

    # ------------------------------------------------------------------ persistence
    def save(
        self,
        path: str | os.PathLike[str],
        metadata: Mapping[str, Any] | None = None,
        *,
        seed: int | None = None,
        config: Any = None,
    ) -> Path:
        """Write the history atomically (module docstring); NaN stays NaN in the arrays.

        Args:
            path: destination ``.npz``.
            metadata: JSON-compatible extras, returned by :meth:`load` at the top level.
            seed: provenance seed; overrides :attr:`provenance`'s entry.
            config: provenance config (a dataclass is stored as a dict); overrides
                :attr:`provenance`'s entry.

        Raises:
            ValueError: metadata or provenance that is not strict JSON (names the key).
        """
        prov = dict(self.provenance)
        if seed is not None:
            prov["seed"] = int(seed)
        if config is not None:
            prov["config"] = (
                dataclasses.asdict(config)
                if dataclasses.is_dataclass(config) and not isinstance(config, type)
                else config
            )
        extra = dict(metadata or {})
        clash = sorted(set(extra) & {"joints", "objects", "provenance", "layout"})
        if clash:
            raise ValueError(f"metadata keys {clash} are reserved for the history's own fields")
        meta = {**self.layout_meta(), "provenance": prov, **extra}
        check_json(meta, "history metadata")
        return write_npz(path, self.arrays(), meta, format=FORMAT, compress=True)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every field as one ``(N, ...)`` array (empty dict without rows); :meth:`from_arrays` inverts it."""
        return {f: self.array(f) for f in self.fields} if len(self) else {}

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> tuple[History, dict[str, Any]]:
        """Inverse of :meth:`save`: ``(history, metadata)``.

        The metadata holds the caller's keys, ``joints``, ``objects``, ``provenance``,
        ``versions`` and ``format``.

        Raises:
            FileFormatError: missing, corrupted or inconsistent file; names it.
        """
        f = read_npz(path, format=FORMAT)
        return cls.from_arrays(f.meta, f.arrays, str(path)), {
            **f.meta,
            "versions": f.versions,
            "format": f.format,
        }

    @classmethod
    def from_arrays(cls, meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray], source: str) -> History:
        """A history from :meth:`layout_meta`'s metadata and :meth:`arrays`.

        ``source`` names where they came from in errors.

        Raises:
            FileFormatError: metadata or arrays that do not make a history; names ``source``.
        """
        joints, objects = meta.get("joints"), meta.get("objects")
        if not (
            isinstance(joints, list)
            and isinstance(objects, list)
            and isinstance(meta.get("provenance"), dict)
        ):
            raise FileFormatError(f"{source}: metadata lacks joints, objects or provenance")
        layout = meta.get("layout", {})
        if not isinstance(layout, dict) or sorted(set(layout) - set(_DEFAULT_OPTIONS)):
            raise FileFormatError(f"{source}: layout {layout!r} is not a history layout")
        out = cls(
            joints, objects, meta["provenance"], **{**_DEFAULT_OPTIONS, "actions": len(joints), **layout}
        )
        if arrays:
            if set(arrays) != set(out.fields):
                raise FileFormatError(f"{source}: fields {sorted(arrays)}, expected {sorted(out.fields)}")
            n = len(arrays["episode"])
            bad = [k for k, a in arrays.items() if a.ndim == 0 or a.shape[0] != n]
            if bad:
                raise FileFormatError(f"{source}: fields {bad} do not have the {n} rows of 'episode'")
            for key in out.fields:
                out._rows[key] = list(arrays[key])
        return out

    def layout_meta(self) -> dict[str, Any]:
        """The metadata :meth:`from_arrays` needs besides the arrays."""
        return {
            "joints": list(self.joints),
            "objects": list(self.objects),
            "provenance": dict(self.provenance),
            "layout": self.options,
        }
