"""``TransitionDataset``: motor-babbling transitions as columnar ``.npz`` chunks + JSON metadata.

On disk a dataset is a directory::

    metadata.json         body, MJCF hash, timestep, frame skip, joints, actuators, policy,
                          seed, chunk size, library versions, and (when done) n_rows
    chunk_000000.npz      rows [0, n0)
    chunk_000001.npz      rows [n0, n0 + n1) ...

Each chunk holds, for its rows (no pickled objects; read with ``allow_pickle=False``):

- per joint j the columns ``act.<j>``, ``q_prev.<j>``, ``dq.<j>``, ``q.<j>``: float32
  ``(n, 1)``; rad for hinges (m for slides); ``act.<j>`` is the command of the actuator
  driving joint j (dimensionless ctrl), ``dq = q - q_prev`` computed in float64;
- ``ctrl``: float32 ``(n, n_actuators)``, the full applied command (for replay);
- ``state``: float64 ``(n, state_size)``, the MuJoCo state before each step
  (``mjSTATE_FULLPHYSICS | mjSTATE_WARMSTART``);
- ``step``, ``episode``: int64 ``(n,)``, global step index and episode index;
- ``__chunk__``: UTF-8 JSON with the chunk index, first row, row count, a SHA-256
  checksum of the arrays, and what a resumed run needs (RNG and simulator state).

Every file is written to a temp file and renamed into place (``os.replace``), so an
interrupted run leaves only complete chunks. This module imports neither ``models``,
``inference`` nor MuJoCo.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from pal.files import atomic_write
from pal.files import versions as _versions

__all__ = [
    "FORMAT",
    "DatasetFileError",
    "DatasetWriter",
    "TransitionDataset",
    "column_names",
    "versions",
]

FORMAT = "pal.transitions/1"
METADATA = "metadata.json"
_CHUNK_META = "__chunk__"
_KINDS = ("act", "q_prev", "dq", "q")
_ROW_ARRAYS = ("ctrl", "state", "step", "episode")


class DatasetFileError(ValueError):
    """A dataset file is missing, truncated, corrupted, or inconsistent with its metadata."""


def versions() -> dict[str, str]:
    """Versions of Python and of the libraries a dataset depends on."""
    return _versions(("pal", "numpy", "mujoco", "gymnasium"))


def column_names(joints: Sequence[str], actuated: Sequence[str] | None = None) -> list[str]:
    """Column names per joint, in order: ``act.j`` (if j is actuated), ``q_prev.j``, ``dq.j``, ``q.j``."""
    actuated = set(joints if actuated is None else actuated)
    return [f"{k}.{j}" for j in joints for k in _KINDS if k != "act" or j in actuated]


def _checksum(arrays: Mapping[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for key in sorted(arrays):
        a = np.ascontiguousarray(arrays[key])
        h.update(f"{key}|{a.dtype.str}|{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise DatasetFileError(f"{path} does not exist; is {path.parent} a dataset directory?")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DatasetFileError(f"{path} is not readable JSON ({type(err).__name__}: {err})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise DatasetFileError(
            f"{path}: format {data.get('format') if isinstance(data, dict) else None!r}, expected {FORMAT!r}"
        )
    return data


def read_chunk(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read and verify one chunk file.

    Returns:
        ``(chunk_metadata, arrays)``.

    Raises:
        DatasetFileError: truncated, corrupted (checksum), or not a chunk; names the file.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, KeyError) as err:
        raise DatasetFileError(f"{path} is truncated or corrupted ({type(err).__name__}: {err})") from None
    if _CHUNK_META not in arrays:
        raise DatasetFileError(f"{path} has no {_CHUNK_META} entry; it is not a transition chunk")
    try:
        meta = json.loads(arrays.pop(_CHUNK_META).tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DatasetFileError(f"{path}: chunk metadata is corrupted ({err})") from None
    if _checksum(arrays) != meta.get("checksum"):
        raise DatasetFileError(f"{path}: checksum mismatch; the arrays are corrupted")
    return meta, arrays


def _chunk_files(root: Path) -> list[Path]:
    return sorted(root.glob("chunk_*.npz"))


class TransitionDataset:
    """Babbling transitions, columnar per joint, with the simulator state before every step.

    Args:
        columns: name -> ``(N, 1)`` float32 arrays (see :func:`column_names`).
        ctrl: ``(N, n_actuators)`` float32 applied commands.
        states: ``(N, state_size)`` float64 MuJoCo states before each step.
        step, episode: ``(N,)`` int64 global step and episode indices.
        metadata: the dataset's metadata (``metadata.json``).
    """

    def __init__(
        self,
        columns: Mapping[str, np.ndarray],
        ctrl: np.ndarray,
        states: np.ndarray,
        step: np.ndarray,
        episode: np.ndarray,
        metadata: Mapping[str, Any],
    ) -> None:
        n = len(step)
        for name, a in {**columns, "ctrl": ctrl, "states": states, "episode": episode}.items():
            if len(a) != n:
                raise ValueError(f"array {name!r} has {len(a)} rows, expected {n}")
        for name, a in columns.items():
            if a.ndim != 2 or a.shape[1] != 1:
                raise ValueError(f"column {name!r} has shape {a.shape}, expected ({n}, 1)")
        self._columns = dict(columns)
        self.ctrl, self.states, self.step, self.episode = ctrl, states, step, episode
        self.metadata: dict[str, Any] = dict(metadata)

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return len(self.step)

    def __repr__(self) -> str:
        return (
            f"TransitionDataset(body={self.metadata.get('body')!r}, rows={len(self)}, joints={self.joints})"
        )

    @property
    def joints(self) -> list[str]:
        """Recorded joint names."""
        return list(self.metadata.get("joints", []))

    @property
    def actuators(self) -> list[str]:
        """Commanded actuator names (the columns of :attr:`ctrl`)."""
        return list(self.metadata.get("actuators", []))

    @property
    def column_names(self) -> list[str]:
        """Names of the per-joint columns."""
        return list(self._columns)

    @property
    def columns(self) -> dict[str, np.ndarray]:
        """name -> ``(N, 1)`` float32 column (the stored arrays, not copies)."""
        return dict(self._columns)

    def as_dict(self, names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Copies of the columns ``names`` (default all), name -> ``(N, 1)`` float32, for ``inference.fit``."""
        names = self.column_names if names is None else list(names)
        missing = [n for n in names if n not in self._columns]
        if missing:
            raise KeyError(f"unknown column(s) {missing}; available: {self.column_names}")
        return {n: self._columns[n].copy() for n in names}

    def state(self, i: int) -> np.ndarray:
        """The simulator state before row ``i``, float64 ``(state_size,)`` (a copy)."""
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"row {i} out of range for {n} rows")
        return self.states[i].copy()

    def subset(self, rows: slice | np.ndarray | Sequence[int]) -> TransitionDataset:
        """The rows ``rows`` (a slice, indices or a boolean mask) as a new dataset."""
        idx = rows if isinstance(rows, slice) else np.asarray(rows)
        if not isinstance(idx, slice) and idx.dtype != bool and not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(
                f"rows must be a slice, integer indices or a boolean mask, got dtype {idx.dtype}"
            )
        return TransitionDataset(
            {k: v[idx] for k, v in self._columns.items()},
            self.ctrl[idx],
            self.states[idx],
            self.step[idx],
            self.episode[idx],
            self.metadata,
        )

    def split(self, fraction: float, seed: int) -> tuple[TransitionDataset, TransitionDataset]:
        """Random split into ``(first, rest)`` with ``round(fraction * N)`` rows in ``first``.

        Args:
            fraction: share of rows in the first part, in (0, 1) (thesis: 0.8).
            seed: seeds the permutation.
        """
        if not 0 < fraction < 1:
            raise ValueError(f"fraction must be in (0, 1), got {fraction}")
        perm = np.random.default_rng(seed).permutation(len(self))
        k = round(fraction * len(self))
        return self.subset(np.sort(perm[:k])), self.subset(np.sort(perm[k:]))

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(cls, root: str | os.PathLike[str]) -> TransitionDataset:
        """Read a dataset directory written by :class:`DatasetWriter`.

        Raises:
            DatasetFileError: missing or corrupted metadata or chunk, or chunks that do not
                follow each other; the message names the file.
        """
        root = Path(root)
        meta = _read_json(root / METADATA)
        parts: list[dict[str, np.ndarray]] = []
        expected = 0
        for i, path in enumerate(_chunk_files(root)):
            cmeta, arrays = read_chunk(path)
            if cmeta.get("index") != i or cmeta.get("start") != expected:
                raise DatasetFileError(
                    f"{path}: chunk {cmeta.get('index')} starts at row {cmeta.get('start')}, expected chunk {i} "
                    f"at row {expected}; a chunk file is missing or foreign"
                )
            names = meta["columns"]
            missing = [k for k in (*names, *_ROW_ARRAYS) if k not in arrays]
            if missing:
                raise DatasetFileError(f"{path}: missing arrays {missing}")
            parts.append(arrays)
            expected += int(cmeta["rows"])
        if not parts:
            raise DatasetFileError(f"{root} holds no complete chunk file (chunk_*.npz)")

        def cat(key: str) -> np.ndarray:
            return np.concatenate([p[key] for p in parts])

        return cls(
            {k: cat(k) for k in meta["columns"]}, cat("ctrl"), cat("state"), cat("step"), cat("episode"), meta
        )


class DatasetWriter:
    """Writes a dataset directory chunk by chunk, atomically; can continue an interrupted one.

    Args:
        root: the dataset directory.
        metadata: JSON-compatible description (``format``, ``columns`` and ``versions`` are
            added). On resume, it must match the stored one except for ``steps``.
        resume: continue the dataset in ``root`` if there is one. Without it, a directory
            that already holds a dataset is an error.

    Attributes:
        resume_info: what the last complete chunk recorded for resuming (``None`` when
            starting fresh).
        rows: number of rows already on disk.
    """

    def __init__(
        self, root: str | os.PathLike[str], metadata: Mapping[str, Any], *, resume: bool = False
    ) -> None:
        self.root = Path(root)
        try:  # a JSON round trip, so that the stored and the current metadata compare equal
            self.metadata = json.loads(
                json.dumps({"format": FORMAT, **dict(metadata), "versions": versions()})
            )
        except TypeError as err:
            raise ValueError(f"dataset metadata is not JSON-serialisable: {err}") from None
        self.resume_info: dict[str, Any] | None = None
        self.rows = 0
        self._index = 0
        existing = (self.root / METADATA).exists() or bool(_chunk_files(self.root))
        if existing and not resume:
            raise ValueError(
                f"{self.root} already holds a dataset; pass resume=True (pal babble --resume) to continue it, or use an empty directory"
            )
        if existing:
            self._resume()
        atomic_write(self.root / METADATA, self._json_writer(self.metadata))

    @staticmethod
    def _json_writer(data: Mapping[str, Any]) -> Callable[[BinaryIO], Any]:
        text = json.dumps(data, indent=2, sort_keys=True) + "\n"
        return lambda fh: fh.write(text.encode())

    def _resume(self) -> None:
        stored = _read_json(self.root / METADATA)
        ignore = {"steps", "versions", "n_rows", "complete", "mjcf_path"}
        keys = (set(stored) | set(self.metadata)) - ignore
        diff = sorted(k for k in keys if stored.get(k) != self.metadata.get(k))
        if diff:
            detail = ", ".join(f"{k}: stored {stored.get(k)!r} vs now {self.metadata.get(k)!r}" for k in diff)
            raise ValueError(f"cannot resume {self.root}: its configuration differs ({detail})")
        for tmp in self.root.glob(".chunk_*.tmp"):
            tmp.unlink()  # the chunk an interrupted run was writing
        files = _chunk_files(self.root)
        for i, path in enumerate(files):
            cmeta, _ = read_chunk(path)
            if cmeta.get("index") != i or cmeta.get("start") != self.rows:
                raise DatasetFileError(
                    f"{path}: chunk {cmeta.get('index')} at row {cmeta.get('start')} does not follow chunk {i - 1}"
                )
            self.rows += int(cmeta["rows"])
            self.resume_info = cmeta.get("resume")
        self._index = len(files)

    def write_chunk(
        self, columns: Mapping[str, np.ndarray], rows: Mapping[str, np.ndarray], resume: Mapping[str, Any]
    ) -> Path:
        """Write the next chunk.

        Args:
            columns: name -> ``(n, 1)`` float32 for every name in ``metadata["columns"]``.
            rows: ``ctrl``, ``state``, ``step``, ``episode`` arrays with n rows.
            resume: JSON-compatible state needed to continue after this chunk.

        Returns:
            The chunk's path.
        """
        arrays = {
            **{k: np.asarray(v) for k, v in columns.items()},
            **{k: np.asarray(rows[k]) for k in _ROW_ARRAYS},
        }
        n = len(arrays["step"])
        meta = {
            "format": FORMAT,
            "index": self._index,
            "start": self.rows,
            "rows": n,
            "checksum": _checksum(arrays),
            "resume": dict(resume),
        }
        arrays[_CHUNK_META] = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8)
        path = atomic_write(self.root / f"chunk_{self._index:06d}.npz", lambda fh: np.savez(fh, **arrays))
        self._index += 1
        self.rows += n
        return path

    def finish(self, steps: int) -> None:
        """Record the final row count in ``metadata.json``."""
        self.metadata.update(n_rows=self.rows, complete=self.rows >= steps)
        atomic_write(self.root / METADATA, self._json_writer(self.metadata))
