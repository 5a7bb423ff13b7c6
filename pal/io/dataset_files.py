"""The on-disk layout of a :class:`~pal.io.dataset.TransitionDataset`: formats, chunks, the manifest.

A dataset is a directory::

    metadata.json         body, MJCF hash, timestep, frame skip, joints, actuators, policy,
                          seed, chunk size, library versions, the run id, the chunk
                          manifest, (when done) n_rows and complete, and metadata_checksum
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

Integrity: ``metadata.json`` carries ``metadata_checksum``, a SHA-256 over the canonical JSON
of every other key (:func:`metadata_checksum`); :func:`read_metadata` recomputes it, so an
edited key (``frame_skip`` 50 -> 5) is refused, and checks the types of the keys it knows.
Like every checksum of pal it catches accidents and careless edits, not a forger, who can
recompute it. A fresh run draws a random run id (kept on resume); the manifest in
``metadata.json`` lists every chunk's file, row range and checksum. :func:`verify_chunks`
checks each chunk against it and refuses, naming the chunk, a missing chunk, a chunk of
another run and a replaced chunk. A chunk written after the last manifest update (an
interruption in between) is accepted if it belongs to the run and follows on.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pal.io.files import DEFAULT_LIMITS, FileFormatError, ReadLimits, read_json, read_npz

__all__ = [
    "CHECKSUM_KEY",
    "CHUNK_FORMAT",
    "FORMAT",
    "METADATA",
    "ROW_ARRAYS",
    "DatasetFileError",
    "check_chunk_arrays",
    "chunk_files",
    "chunk_name",
    "column_names",
    "metadata_checksum",
    "read_chunk",
    "read_metadata",
    "verify_chunks",
]

FORMAT = "pal.transitions/4"
CHUNK_FORMAT = "pal.transitions-chunk/3"
METADATA = "metadata.json"
#: Older dataset formats, and what they lack.
_OLD_FORMATS = {
    "pal.transitions/1": "an older layout without a chunk manifest",
    "pal.transitions/2": "an older layout without the dq_prev columns",
    "pal.transitions/3": "an older layout without a metadata checksum",
}
_KINDS = ("act", "q_prev", "dq_prev", "dq", "q")
ROW_ARRAYS = ("ctrl", "state", "step", "episode")
_CHUNK_KEYS = ("file", "index", "start", "rows", "checksum")
CHECKSUM_KEY = "metadata_checksum"
#: Keys of metadata.json checked when present: key -> (types, minimum or None, description).
_OPTIONAL_TYPES: dict[str, tuple[tuple[type, ...], int | None, str]] = {
    "n_rows": ((int,), 0, "an int >= 0"),
    "steps": ((int,), 0, "an int >= 0"),
    "frame_skip": ((int,), 1, "an int >= 1"),
    "chunk_size": ((int,), 1, "an int >= 1"),
    "seed": ((int,), None, "an int"),
    "complete": ((bool,), None, "true or false"),
    "joints": ((list,), None, "a list of names"),
    "actuators": ((list,), None, "a list of names"),
}


class DatasetFileError(FileFormatError):
    """A dataset file is missing, truncated, corrupted, foreign, or inconsistent with the manifest."""


def column_names(
    joints: Sequence[str], actuated: Sequence[str] | None = None, velocities: bool = False
) -> list[str]:
    """Column names per joint.

    In order: ``act.j`` (if j is actuated), ``q_prev.j``, ``dq_prev.j``, ``dq.j``, ``q.j``, and with
    ``velocities`` ``v_prev.j``, ``v.j`` (the joint velocity before and after the step, rad/s).
    """
    actuated = set(joints if actuated is None else actuated)
    kinds = _KINDS + (("v_prev", "v") if velocities else ())
    return [f"{k}.{j}" for j in joints for k in kinds if k != "act" or j in actuated]


def chunk_name(index: int) -> str:
    """File name of chunk ``index``."""
    return f"chunk_{index:06d}.npz"


def chunk_files(root: Path) -> list[Path]:
    """The chunk files in ``root``, in order."""
    return sorted(root.glob("chunk_*.npz"))


def metadata_checksum(meta: Mapping[str, Any]) -> str:
    """Hex SHA-256 of the canonical JSON of ``meta`` without its ``metadata_checksum`` key."""
    body = {k: v for k, v in meta.items() if k != CHECKSUM_KEY}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _bad(path: Path, key: str, value: Any, expected: str) -> DatasetFileError:
    return DatasetFileError(f"{path}: {key!r} is {value!r}, expected {expected}")


def _is(value: Any, kinds: tuple[type, ...]) -> bool:
    return isinstance(value, kinds) and (bool in kinds or not isinstance(value, bool))


def _check_schema(path: Path, data: dict[str, Any]) -> None:
    """Types of the keys of ``metadata.json``; DatasetFileError naming the file, key and value."""
    if not isinstance(data.get("run_id"), str):
        raise _bad(path, "run_id", data.get("run_id"), "the run id, a str")
    columns = data.get("columns")
    if not isinstance(columns, list) or not all(isinstance(c, str) for c in columns):
        raise _bad(path, "columns", columns, "a list of column names")
    chunks = data.get("chunks")
    if not isinstance(chunks, list):
        raise _bad(path, "chunks", chunks, "the chunk manifest, a list")
    for i, c in enumerate(chunks):
        ok = isinstance(c, dict) and set(c) == set(_CHUNK_KEYS)
        ok = ok and isinstance(c["file"], str) and isinstance(c["checksum"], str)
        if not ok or not all(_is(c[k], (int,)) and c[k] >= 0 for k in ("index", "start", "rows")):
            raise _bad(path, f"chunks[{i}]", c, f"an object of {list(_CHUNK_KEYS)} (str file and checksum)")
    for key, (kinds, minimum, expected) in _OPTIONAL_TYPES.items():
        if key not in data:
            continue
        value = data[key]
        ok = _is(value, kinds) and (minimum is None or value >= minimum)
        if not ok or (isinstance(value, list) and not all(isinstance(v, str) for v in value)):
            raise _bad(path, key, value, expected)


def read_metadata(root: Path) -> dict[str, Any]:
    """Read and check ``metadata.json`` of the dataset ``root``.

    Raises:
        DatasetFileError: missing or unreadable, another or an older format, a checksum
            mismatch (the file was edited), or a key of the wrong type (named with its value).
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
    stored = data.get(CHECKSUM_KEY)
    if stored != metadata_checksum(data):
        raise DatasetFileError(
            f"{path}: {CHECKSUM_KEY} {stored!r} does not match its content; the metadata was edited "
            "or damaged after writing (babble the dataset again)"
        )
    _check_schema(path, data)
    return data


def check_chunk_arrays(
    path: Path, arrays: Mapping[str, np.ndarray], columns: Sequence[str], widths: dict[str, int]
) -> None:
    """Shapes and dtypes of one chunk's arrays (module docstring).

    ``widths`` holds the widths of ``ctrl`` and ``state`` seen so far (filled from the first
    chunk); later chunks must agree.

    Raises:
        DatasetFileError: a missing array, or one of another shape or dtype; names the file,
            the array and its shape.
    """
    missing = [k for k in [*columns, *ROW_ARRAYS] if k not in arrays]
    if missing:
        raise DatasetFileError(f"{path}: missing arrays {missing}")
    n = len(arrays["step"])
    expected: dict[str, tuple[tuple[int, ...], str]] = {k: ((n, 1), "float32") for k in columns}
    expected.update(step=((n,), "int64"), episode=((n,), "int64"))
    for key, dtype in (("ctrl", "float32"), ("state", "float64")):
        a = arrays[key]
        width = widths.setdefault(key, a.shape[1] if a.ndim == 2 else -1)
        expected[key] = ((n, width), dtype)
    for key, (shape, dtype) in expected.items():
        a = arrays[key]
        if a.shape != shape or a.dtype != np.dtype(dtype):
            raise DatasetFileError(
                f"{path}: array {key!r} has shape {a.shape} and dtype {a.dtype}, expected {shape} {dtype}"
            )


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
