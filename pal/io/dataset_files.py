"""The on-disk layout of a :class:`~pal.io.dataset.TransitionDataset`: formats, chunks, the manifest.

A dataset is a directory::

    metadata.json         body, MJCF hash, timestep, frame skip, joints, actuators, policy,
                          seed, chunk size, library versions, the run id, the chunk
                          manifest, and (when done) n_rows
    chunk_000000.npz      rows [0, n0)
    chunk_000001.npz      rows [n0, n0 + n1) ...
    writer.lock           only while a writer runs (:mod:`pal.io.locks`)

Each chunk is a checked ``.npz`` of :mod:`pal.io.files` (format :data:`CHUNK_FORMAT`: no pickled
objects, a SHA-256 over arrays and metadata) holding, for its rows:

- per joint j the columns ``act.<j>``, ``q_prev.<j>``, ``dq_prev.<j>``, ``dq.<j>``, ``q.<j>``:
  float32 ``(n, 1)``; rad for hinges (m for slides); ``act.<j>`` is the command of the
  actuator driving joint j (dimensionless ctrl), ``dq = q - q_prev`` computed in float64,
  and ``dq_prev`` is the previous row's ``dq`` within an episode (0 at its first row);
- ``ctrl``: float32 ``(n, n_actuators)``, the full applied command (for replay);
- ``state``: float64 ``(n, state_size)``, the MuJoCo state before each step
  (``mjSTATE_FULLPHYSICS | mjSTATE_WARMSTART``);
- ``step``, ``episode``: int64 ``(n,)``, global step index and episode index;

and as metadata the run id, chunk index, first row, row count and what a resumed run needs
(RNG and simulator state).

Integrity: a fresh run draws a random run id (kept on resume); the manifest in
``metadata.json`` lists every chunk's file, row range and checksum. :func:`verify_chunks`
checks each chunk against it and refuses, naming the chunk, a missing chunk, a chunk of
another run and a replaced chunk. A chunk written after the last manifest update (an
interruption in between) is accepted if it belongs to the run and follows on.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pal.io.files import DEFAULT_LIMITS, FileFormatError, ReadLimits, read_json, read_npz

__all__ = [
    "CHUNK_FORMAT",
    "FORMAT",
    "METADATA",
    "ROW_ARRAYS",
    "DatasetFileError",
    "chunk_files",
    "chunk_name",
    "column_names",
    "read_chunk",
    "read_metadata",
    "verify_chunks",
]

FORMAT = "pal.transitions/3"
CHUNK_FORMAT = "pal.transitions-chunk/3"
METADATA = "metadata.json"
#: Older dataset formats, and what they lack.
_OLD_FORMATS = {
    "pal.transitions/1": "an older layout without a chunk manifest",
    "pal.transitions/2": "an older layout without the dq_prev columns",
}
_KINDS = ("act", "q_prev", "dq_prev", "dq", "q")
ROW_ARRAYS = ("ctrl", "state", "step", "episode")
_CHUNK_KEYS = ("file", "index", "start", "rows", "checksum")


class DatasetFileError(FileFormatError):
    """A dataset file is missing, truncated, corrupted, foreign, or inconsistent with the manifest."""


def column_names(joints: Sequence[str], actuated: Sequence[str] | None = None) -> list[str]:
    """Column names per joint, in order: ``act.j`` (if j is actuated), ``q_prev.j``, ``dq_prev.j``, ``dq.j``, ``q.j``."""
    actuated = set(joints if actuated is None else actuated)
    return [f"{k}.{j}" for j in joints for k in _KINDS if k != "act" or j in actuated]


def chunk_name(index: int) -> str:
    """File name of chunk ``index``."""
    return f"chunk_{index:06d}.npz"


def chunk_files(root: Path) -> list[Path]:
    """The chunk files in ``root``, in order."""
    return sorted(root.glob("chunk_*.npz"))


def read_metadata(root: Path) -> dict[str, Any]:
    """Read and check ``metadata.json`` of the dataset ``root``.

    Raises:
        DatasetFileError: missing or unreadable, another or an older format, or no valid
            run id, columns or manifest.
    """
    path = root / METADATA
    if not path.is_file():
        raise DatasetFileError(f"{path} does not exist; is {root} a dataset directory?")
    try:
        data = read_json(path)
    except FileFormatError as err:
        raise DatasetFileError(str(err)) from err
    fmt = data.get("format") if isinstance(data, dict) else None
    if isinstance(fmt, str) and fmt in _OLD_FORMATS:
        raise DatasetFileError(
            f"{path}: format {fmt!r} is {_OLD_FORMATS[fmt]}; babble the dataset "
            f"again into a new directory (this version reads {FORMAT!r})"
        )
    if fmt != FORMAT:
        raise DatasetFileError(f"{path}: format {fmt!r}, expected {FORMAT!r}")
    chunks = data.get("chunks")
    ok = (
        isinstance(data.get("run_id"), str)
        and isinstance(data.get("columns"), list)
        and isinstance(chunks, list)
        and all(isinstance(c, dict) and set(c) == set(_CHUNK_KEYS) for c in chunks)
    )
    if not ok:
        raise DatasetFileError(f"{path} lacks a valid run_id, columns or chunk manifest")
    return data


def read_chunk(
    path: str | os.PathLike[str], *, limits: ReadLimits = DEFAULT_LIMITS
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read and verify one chunk file.

    Returns:
        ``(chunk_metadata, arrays)``; the metadata holds ``run_id``, ``index``, ``start``,
        ``rows``, ``resume`` and the file's ``checksum``.

    Raises:
        DatasetFileError: missing, truncated, corrupted (checksum), over ``limits``, not a
            chunk, or rows that disagree; names the file.
    """
    path = Path(path)
    try:
        f = read_npz(path, format=CHUNK_FORMAT, limits=limits)
    except FileFormatError as err:
        raise DatasetFileError(str(err)) from err
    meta = f.meta
    if not (
        isinstance(meta.get("run_id"), str)
        and all(isinstance(meta.get(k), int) for k in ("index", "start", "rows"))
        and isinstance(meta.get("resume"), dict)
    ):
        raise DatasetFileError(f"{path}: chunk metadata lacks run_id, index, start, rows or resume")
    bad = {k: a.shape for k, a in f.arrays.items() if a.ndim == 0 or a.shape[0] != meta["rows"]}
    if bad or any(k not in f.arrays for k in ROW_ARRAYS):
        raise DatasetFileError(f"{path}: arrays {bad or sorted(f.arrays)} do not hold {meta['rows']} rows")
    return {**meta, "checksum": f.checksum}, f.arrays


def verify_chunks(
    root: Path, meta: Mapping[str, Any], limits: ReadLimits
) -> tuple[list[dict[str, Any]], list[tuple[dict[str, Any], dict[str, np.ndarray]]]]:
    """Read every chunk of ``root`` and check it against the manifest in ``meta``.

    Returns:
        The manifest (with the trailing chunks of this run that it did not list yet) and the
        chunks read, ``(chunk_metadata, arrays)`` in order.

    Raises:
        DatasetFileError: a listed chunk is missing, a chunk is corrupted, of another run,
            out of order or replaced, or the row count disagrees with ``n_rows``.
    """
    manifest = [dict(c) for c in meta["chunks"]]
    files = chunk_files(root)
    for i, entry in enumerate(manifest):
        if entry["index"] != i or entry["file"] != chunk_name(i):
            raise DatasetFileError(
                f"{root / METADATA}: manifest entry {i} is {entry}, expected {chunk_name(i)}"
            )
        if not (root / entry["file"]).is_file():
            end = entry["start"] + entry["rows"]
            raise DatasetFileError(
                f"{root / entry['file']} is missing: the manifest lists it with rows "
                f"[{entry['start']}, {end}) of this run"
            )
    read: list[tuple[dict[str, Any], dict[str, np.ndarray]]] = []
    start = 0
    for i, path in enumerate(files):
        if path.name != chunk_name(i):
            raise DatasetFileError(f"{root / chunk_name(i)} is missing; {path.name} follows a gap")
        cmeta, arrays = read_chunk(path, limits=limits)
        if cmeta["run_id"] != meta["run_id"]:
            raise DatasetFileError(
                f"{path} belongs to run {cmeta['run_id']}, not to this dataset's run {meta['run_id']}; "
                "it was copied from another dataset"
            )
        if cmeta["index"] != i or cmeta["start"] != start:
            raise DatasetFileError(
                f"{path}: chunk {cmeta['index']} starts at row {cmeta['start']}, expected chunk {i} at row {start}"
            )
        if i < len(manifest):
            entry = manifest[i]
            if (entry["start"], entry["rows"], entry["checksum"]) != (
                start,
                cmeta["rows"],
                cmeta["checksum"],
            ):
                raise DatasetFileError(
                    f"{path} does not match the manifest (rows [{entry['start']}, "
                    f"{entry['start'] + entry['rows']}), checksum {entry['checksum'][:12]}...); it was replaced"
                )
        elif "n_rows" in meta:
            raise DatasetFileError(f"{path} is not in the manifest of the finished dataset {root}")
        else:  # written by this run just before an interruption, before the manifest was updated
            manifest.append(
                {
                    "file": path.name,
                    "index": i,
                    "start": start,
                    "rows": cmeta["rows"],
                    "checksum": cmeta["checksum"],
                }
            )
        read.append((cmeta, arrays))
        start += cmeta["rows"]
    if "n_rows" in meta and meta["n_rows"] != start:
        raise DatasetFileError(f"{root}: metadata says {meta['n_rows']} rows but the chunks hold {start}")
    return manifest, read
