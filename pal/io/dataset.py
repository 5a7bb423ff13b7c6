"""``TransitionDataset``: motor-babbling transitions as columnar ``.npz`` chunks + a JSON manifest.

The directory layout, the chunk format and the manifest checks are in
:mod:`pal.io.dataset_files`. :class:`DatasetWriter` writes a dataset chunk by chunk, atomically,
and can continue an interrupted run; one writer at a time may write a directory (a lock file,
:mod:`pal.io.locks`; a stale lock of a killed writer is taken over with a warning).
:meth:`TransitionDataset.load` verifies every chunk against the manifest. This module
imports neither ``models``, ``inference`` nor MuJoCo.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pal.io.dataset_files import (
    CHECKSUM_KEY,
    CHUNK_FORMAT,
    FORMAT,
    METADATA,
    ROW_ARRAYS,
    DatasetFileError,
    check_chunk_arrays,
    chunk_files,
    chunk_name,
    column_names,
    metadata_checksum,
    read_chunk,
    read_metadata,
    verify_chunks,
)
from pal.io.files import DEFAULT_LIMITS, ReadLimits, atomic_write_json, check_json, versions, write_npz
from pal.io.locks import LOCK_NAME, DirectoryLock, DirectoryLockedError

__all__ = [
    "CHUNK_FORMAT",
    "FORMAT",
    "METADATA",
    "DatasetFileError",
    "DatasetWriter",
    "DirectoryLockedError",
    "TransitionDataset",
    "column_names",
    "read_chunk",
]


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
        rows = f"{len(self)} of {self.planned_rows} planned" if not self.complete else str(len(self))
        return f"TransitionDataset(body={self.metadata.get('body')!r}, rows={rows}, joints={self.joints})"

    @property
    def complete(self) -> bool:
        """True when the writer finished the run (``metadata.json`` says ``complete``)."""
        return self.metadata.get("complete") is True

    @property
    def planned_rows(self) -> int | None:
        """The rows the run aimed at (``steps`` of the metadata), None when it does not say."""
        steps = self.metadata.get("steps")
        return steps if isinstance(steps, int) else None

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
        """The columns, name -> ``(N, 1)`` float32 (the stored arrays, not copies)."""
        return dict(self._columns)

    def to_dict(self, names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
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
    def load(
        cls,
        root: str | os.PathLike[str],
        *,
        limits: ReadLimits = DEFAULT_LIMITS,
        allow_incomplete: bool = False,
    ) -> TransitionDataset:
        """Read a dataset directory written by :class:`DatasetWriter`, verifying the manifest.

        Args:
            root: the dataset directory.
            limits: size limits per chunk file, checked before anything is inflated.
            allow_incomplete: read a dataset whose writer did not finish (killed or still
                running); :attr:`complete` is then False and ``len`` and
                :attr:`planned_rows` say how many rows it holds of how many planned.

        Raises:
            DatasetFileError: missing, edited or corrupted metadata or chunk, a chunk missing
                from the manifest's row ranges, a chunk of another run, a replaced chunk, an
                array of the wrong shape or dtype, or an incomplete dataset without
                ``allow_incomplete``; the message names the file.
        """
        root = Path(root)
        meta = read_metadata(root)
        _, chunks = verify_chunks(root, meta, limits)
        rows = sum(c["rows"] for c, _ in chunks)
        if meta.get("complete") is not True and not allow_incomplete:
            raise DatasetFileError(
                f"{root} is incomplete: its chunks hold {rows} of the {meta.get('steps', 'unknown')} planned "
                "rows (its writer did not finish); finish it with pal babble --resume, or pass "
                "allow_incomplete=True to read the rows it holds"
            )
        if not chunks:
            raise DatasetFileError(f"{root} holds no complete chunk file (chunk_*.npz)")
        widths: dict[str, int] = {}
        for (_, arrays), path in zip(chunks, chunk_files(root), strict=True):
            check_chunk_arrays(path, arrays, meta["columns"], widths)

        def cat(key: str) -> np.ndarray:
            return np.concatenate([arrays[key] for _, arrays in chunks])

        return cls(
            {k: cat(k) for k in meta["columns"]}, cat("ctrl"), cat("state"), cat("step"), cat("episode"), meta
        )


class DatasetWriter:
    """Writes a dataset directory chunk by chunk, atomically; can continue an interrupted one.

    The writer holds the directory's lock (:mod:`pal.io.locks`) from construction until
    :meth:`finish` or :meth:`close`; use it as a context manager so that an exception
    releases it too.

    Args:
        root: the dataset directory.
        metadata: JSON-compatible description with ``columns``, the per-joint column names
            (``format``, ``run_id``, the manifest and ``versions`` are added). On resume, it
            must match the stored one except for ``steps``.
        resume: continue the dataset in ``root`` if there is one. Without it, a directory
            that already holds a dataset is an error.

    Attributes:
        resume_info: what the last complete chunk recorded for resuming (``None`` when
            starting fresh).
        rows: number of rows already on disk.
        run_id: the run's id (random for a fresh run, the stored one on resume).

    Raises:
        DirectoryLockedError: another writer holds ``root``.
        ValueError: ``root`` holds a dataset and not ``resume``, the configuration differs,
            or the metadata is not strict JSON.
        DatasetFileError: a stored file is corrupted, missing or foreign.
    """

    def __init__(
        self, root: str | os.PathLike[str], metadata: Mapping[str, Any], *, resume: bool = False
    ) -> None:
        self.root = Path(root)
        meta = {"format": FORMAT, **dict(metadata), "versions": versions()}
        check_json(meta, "dataset metadata")
        columns = meta.get("columns")
        if not isinstance(columns, list) or not all(isinstance(c, str) for c in columns):
            raise ValueError(
                f"dataset metadata needs 'columns', the list of column names (see column_names), got {columns!r}"
            )
        self.metadata: dict[str, Any] = json.loads(json.dumps(meta))  # compares equal to the stored one
        for key in ("n_rows", "complete", "chunks", "run_id", CHECKSUM_KEY):
            self.metadata.pop(key, None)
        self.resume_info: dict[str, Any] | None = None
        self.rows = 0
        self._chunks: list[dict[str, Any]] = []
        self._lock = DirectoryLock(self.root, LOCK_NAME)
        self._lock.acquire()
        try:
            existing = (self.root / METADATA).exists() or bool(chunk_files(self.root))
            if existing and not resume:
                raise ValueError(
                    f"{self.root} already holds a dataset; pass resume=True (pal babble --resume) to continue it, or use an empty directory"
                )
            if existing:  # the stored metadata stays as it is until the next chunk
                self.run_id = self._resume()
            else:
                self.run_id = uuid.uuid4().hex
                self._write_metadata()
        except BaseException:
            self._lock.release()
            raise

    def _write_metadata(self) -> None:
        meta = {**self.metadata, "run_id": self.run_id, "chunks": self._chunks}
        meta[CHECKSUM_KEY] = metadata_checksum(meta)
        atomic_write_json(self.root / METADATA, meta, name="dataset metadata")

    def _resume(self) -> str:
        stored = read_metadata(self.root)
        ignore = {
            "steps",
            "versions",
            "n_rows",
            "complete",
            "mjcf_path",
            "chunks",
            "run_id",
            "effective_ranges",
            CHECKSUM_KEY,
        }
        keys = (set(stored) | set(self.metadata)) - ignore
        diff = sorted(k for k in keys if stored.get(k) != self.metadata.get(k))
        if diff:
            detail = ", ".join(f"{k}: stored {stored.get(k)!r} vs now {self.metadata.get(k)!r}" for k in diff)
            raise ValueError(f"cannot resume {self.root}: its configuration differs ({detail})")
        for tmp in self.root.glob(".chunk_*.tmp"):
            tmp.unlink()  # the chunk an interrupted run was writing
        stored.pop("n_rows", None)  # an extension may add chunks after the finished ones
        self._chunks, chunks = verify_chunks(self.root, stored, DEFAULT_LIMITS)
        for cmeta, _ in chunks:
            self.rows += cmeta["rows"]
            self.resume_info = cmeta["resume"]
        return str(stored["run_id"])

    @property
    def closed(self) -> bool:
        """True after :meth:`finish` or :meth:`close` (the lock is released)."""
        return not self._lock.held

    def write_chunk(
        self, columns: Mapping[str, np.ndarray], rows: Mapping[str, np.ndarray], resume: Mapping[str, Any]
    ) -> Path:
        """Write the next chunk, then record it in the manifest.

        Args:
            columns: name -> ``(n, 1)`` float32 for every name in ``metadata["columns"]``.
            rows: ``ctrl``, ``state``, ``step``, ``episode`` arrays with n rows.
            resume: JSON-compatible state needed to continue after this chunk.

        Returns:
            The chunk's path.

        Raises:
            ValueError: the writer is closed, or arrays are missing or of unequal length.
        """
        if self.closed:
            raise ValueError(f"the writer of {self.root} is closed")
        expected = list(self.metadata["columns"])
        if sorted(columns) != sorted(expected):
            raise ValueError(
                f"columns {sorted(columns)} differ from the dataset's columns {sorted(expected)}"
            )
        missing = [k for k in ROW_ARRAYS if k not in rows]
        if missing:
            raise ValueError(f"rows lack the arrays {missing}; expected {list(ROW_ARRAYS)}")
        arrays = {
            **{k: np.asarray(columns[k]) for k in expected},
            **{k: np.asarray(rows[k]) for k in ROW_ARRAYS},
        }
        n = len(arrays["step"])
        bad = {k: a.shape for k, a in arrays.items() if a.ndim == 0 or a.shape[0] != n}
        if bad or n == 0:
            raise ValueError(f"chunk arrays {bad} do not all have the {n} rows of 'step' (n >= 1)")
        index = len(self._chunks)
        meta = {"run_id": self.run_id, "index": index, "start": self.rows, "rows": n, "resume": dict(resume)}
        path = write_npz(self.root / chunk_name(index), arrays, meta, format=CHUNK_FORMAT)
        cmeta, _ = read_chunk(path)  # read back: verifies the file and gives its checksum
        entry = {
            "file": path.name,
            "index": index,
            "start": self.rows,
            "rows": n,
            "checksum": cmeta["checksum"],
        }
        self._chunks.append(entry)
        self.rows += n
        self._write_metadata()
        return path

    def finish(self, steps: int, extra: Mapping[str, Any] | None = None) -> None:
        """Record the final row count in ``metadata.json`` and release the lock.

        Args:
            steps: the rows the run aimed at (``complete`` is ``rows >= steps``).
            extra: JSON-compatible entries added to the metadata, e.g. what was measured on
                the finished data (``effective_ranges``).
        """
        if self.closed:
            raise ValueError(f"the writer of {self.root} is closed")
        if extra:
            check_json(dict(extra), "dataset metadata")
            self.metadata.update(json.loads(json.dumps(dict(extra))))
        self.metadata.update(n_rows=self.rows, complete=self.rows >= steps)
        self._write_metadata()
        self.close()

    def close(self) -> None:
        """Release the lock without marking the dataset finished (idempotent)."""
        self._lock.release()

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        self.close()
