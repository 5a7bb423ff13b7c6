"""The agent's sensorimotor history H_t (thesis Eq. 4.4) as columns, and its world-model training columns.

One row per executed step t-1 -> t. Per joint j: ``act`` (servo target, rad), ``q_prev``, ``q`` (rad).
Hand: ``hand_prev``, ``hand`` (3,) m. Per object o: ``touch`` (fraction of the step in contact),
``meas_prev``/``meas`` (2,) perceived table position, m, and ``std`` (2,) its 1-sigma; ``est_prev``/
``est`` (2,) the agent's state estimate. Missing evidence is NaN *inside this store only*:
:meth:`History.columns` drops those rows, so no NaN reaches the world model. ``truth_prev``/``truth``
(2,) are ground-truth positions kept for evaluation (the agent never reads them), ``state`` is the
simulator state before the step (for exact replay), ``episode`` the episode index.

On disk a history is a checked, compressed ``.npz`` of :mod:`pal.files` (format
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

from pal.files import FileFormatError, check_json, read_npz, write_npz

__all__ = ["FIELDS", "FORMAT", "SOURCES", "History"]

#: Format tag of history files.
FORMAT = "pal.history/1"

#: Per-row fields and their trailing shapes (J joints, O objects, S state entries).
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
#: Position sources of :meth:`History.columns`.
SOURCES = ("perceived", "truth")


class History:
    """Columnar sensorimotor history (module docstring).

    Args:
        joints: short joint names (``act.<j>``, ``q.<j>`` ...).
        objects: object slot names (``pos.<o>`` ...).
        provenance: how the history was made, e.g. ``{"seed": 0, "config": {...}}``
            (JSON-compatible); :meth:`save` records it.
    """

    def __init__(
        self, joints: Sequence[str], objects: Sequence[str], provenance: Mapping[str, Any] | None = None
    ) -> None:
        self.joints, self.objects = tuple(joints), tuple(objects)
        self.provenance: dict[str, Any] = dict(provenance or {})
        self._rows: dict[str, list[np.ndarray]] = {f: [] for f in FIELDS}

    def __len__(self) -> int:
        return len(self._rows["episode"])

    def append(self, **row: Any) -> None:
        """Add one step; every field of :data:`FIELDS` is required."""
        missing = sorted(set(FIELDS) - set(row))
        extra = sorted(set(row) - set(FIELDS))
        if missing or extra:
            raise ValueError(f"history row: missing fields {missing}, unknown fields {extra}")
        shapes = {
            "act": (len(self.joints),),
            "q_prev": (len(self.joints),),
            "q": (len(self.joints),),
            "hand_prev": (3,),
            "hand": (3,),
            "touch": (len(self.objects),),
        }
        for key in ("meas_prev", "meas", "std", "est_prev", "est", "truth_prev", "truth"):
            shapes[key] = (len(self.objects), 2)
        for key, shape in shapes.items():
            value = np.asarray(row[key], dtype=np.float64)
            if value.shape != shape:
                raise ValueError(f"history row {key!r} has shape {value.shape}, expected {shape}")
        for key in FIELDS:
            self._rows[key].append(np.array(row[key], dtype=np.int64 if key == "episode" else np.float64))

    def array(self, field: str) -> np.ndarray:
        """All rows of one field stacked: (N, ...)."""
        if field not in self._rows:
            raise ValueError(f"unknown history field {field!r}; fields are {list(FIELDS)}")
        rows = self._rows[field]
        if not rows:
            raise ValueError("the history is empty")
        return np.stack(rows)

    def columns(
        self, source: str = "perceived", rows: np.ndarray | slice | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, np.ndarray]]]:
        """World-model training columns, float32 ``(n, dim)`` (Eq. 4.33 needs realized parents).

        Args:
            source: ``"perceived"`` (object positions are the measurements) or ``"truth"``.
            rows: a subset of rows (indices, boolean mask or slice); default all.

        Returns:
            ``(arm, objects)``: ``arm`` has ``act.j``, ``q_prev.j``, ``dq.j``, ``q.j``,
            ``hand_prev``, ``hand`` for every row; ``objects[o]`` has ``pos_prev.o``, ``dpos.o``,
            ``pos.o``, ``contact.o`` plus ``hand_prev`` and ``hand`` for the rows where both
            positions of o are known.
        """
        if source not in SOURCES:
            raise ValueError(f"source {source!r} unknown; expected one of {SOURCES}")
        idx = np.arange(len(self))[rows if rows is not None else slice(None)]
        a = {f: self.array(f)[idx] for f in ("act", "q_prev", "q", "hand_prev", "hand", "touch")}
        arm: dict[str, np.ndarray] = {}
        for c, j in enumerate(self.joints):
            arm[f"act.{j}"] = a["act"][:, c : c + 1]
            arm[f"q_prev.{j}"] = a["q_prev"][:, c : c + 1]
            arm[f"dq.{j}"] = a["q"][:, c : c + 1] - a["q_prev"][:, c : c + 1]
            arm[f"q.{j}"] = a["q"][:, c : c + 1]
        arm["hand_prev"], arm["hand"] = a["hand_prev"], a["hand"]
        prev_key, key = ("meas_prev", "meas") if source == "perceived" else ("truth_prev", "truth")
        prev, now = self.array(prev_key)[idx], self.array(key)[idx]
        objects = {}
        for k, o in enumerate(self.objects):
            ok = np.isfinite(prev[:, k]).all(1) & np.isfinite(now[:, k]).all(1)
            objects[o] = {
                f"pos_prev.{o}": prev[ok, k],
                f"pos.{o}": now[ok, k],
                f"dpos.{o}": now[ok, k] - prev[ok, k],
                f"contact.{o}": a["touch"][ok, k : k + 1],
                "hand_prev": a["hand_prev"][ok],
                "hand": a["hand"][ok],
            }
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
        clash = sorted(set(extra) & {"joints", "objects", "provenance"})
        if clash:
            raise ValueError(f"metadata keys {clash} are reserved for the history's own fields")
        meta = {"joints": list(self.joints), "objects": list(self.objects), "provenance": prov, **extra}
        check_json(meta, "history metadata")
        arrays = {f: self.array(f) for f in FIELDS} if len(self) else {}
        return write_npz(path, arrays, meta, format=FORMAT, compress=True)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> tuple[History, dict[str, Any]]:
        """Inverse of :meth:`save`: ``(history, metadata)``.

        The metadata holds the caller's keys, ``joints``, ``objects``, ``provenance``,
        ``versions`` and ``format``.

        Raises:
            FileFormatError: missing, corrupted or inconsistent file; names it.
        """
        f = read_npz(path, format=FORMAT)
        meta, arrays = f.meta, f.arrays
        joints, objects = meta.get("joints"), meta.get("objects")
        if not (
            isinstance(joints, list)
            and isinstance(objects, list)
            and isinstance(meta.get("provenance"), dict)
        ):
            raise FileFormatError(f"{path}: metadata lacks joints, objects or provenance")
        out = cls(joints, objects, meta["provenance"])
        if arrays:
            if set(arrays) != set(FIELDS):
                raise FileFormatError(f"{path}: fields {sorted(arrays)}, expected {sorted(FIELDS)}")
            n = len(arrays["episode"])
            bad = [k for k, a in arrays.items() if a.ndim == 0 or a.shape[0] != n]
            if bad:
                raise FileFormatError(f"{path}: fields {bad} do not have the {n} rows of 'episode'")
            for key in FIELDS:
                out._rows[key] = list(arrays[key])
        return out, {**meta, "versions": f.versions, "format": f.format}
