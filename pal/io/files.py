"""The one persistence layer of pal: atomic writes, strict JSON, checked ``.npz`` files, provenance.

Rules every pal artifact follows (``models.io`` keeps its own copy of them, since ``models``
may not import ``pal``; ``tests/test_persistence_guarantees.py`` holds both sides equal):

- **Atomic writes.** A write goes to a temp file next to the target, is fsynced, then renamed
  over it. A reader never sees a half-written file; a write interrupted by an exception leaves
  the old file intact and no temp file behind. Every written file has mode :data:`FILE_MODE`.
- **Strict JSON.** JSON has no NaN or infinity: they are refused with an error naming the key
  path (``meta['loss'][3] is nan``). Keys must be strings, values JSON types.
- **Checked ``.npz``.** :func:`write_npz` stores arrays (numeric or bool, never objects, so
  they load without pickle) and a ``__meta__`` entry of UTF-8 JSON: the format tag, library
  versions, the caller's metadata and a SHA-256 checksum over the format, versions, metadata
  and every array's name, dtype, shape and bytes.
- **Bounded reads.** :func:`read_npz` checks sizes before inflating anything: the entry
  count and declared uncompressed sizes from the zip central directory, the ratio of that
  declared content to the file's size on disk (a deflate bomb of 2 MB declaring 2 GB is
  refused: at most ``max_ratio`` = 64 times the file above 64 MiB), then each ``.npy``
  header's dtype and shape (element count x item size) against the declared size. Anything
  above :class:`ReadLimits` (2 GiB in total by default) is refused. The inflated stream of an
  entry is read into an array of the checked size and may not run past it.
- **One error type.** Whatever is wrong with a file (missing, truncated, flipped bytes,
  another format, over the limits), reading raises :class:`FileFormatError` naming the file.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import platform
import struct
import tempfile
import tokenize
import zipfile
import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from pal.checks import check_int

__all__ = [
    "DEFAULT_DISTS",
    "DEFAULT_LIMITS",
    "FILE_MODE",
    "GIB",
    "FileFormatError",
    "FileTooLargeError",
    "NpzFile",
    "ReadLimits",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_json",
    "check_json",
    "checksum",
    "read_json",
    "read_npz",
    "versions",
    "write_npz",
]

#: Mode of every file pal writes (owner read/write, everyone read).
FILE_MODE = 0o644
GIB = 1024**3
#: Distributions whose versions :func:`versions` records by default.
DEFAULT_DISTS = ("pal", "numpy", "scipy", "opencv-python-headless", "mujoco", "gymnasium")
_META = "__meta__"
_DOC_KEYS = {"format", "versions", "meta", "checksum"}
_NPY_VERSIONS = {(1, 0), (2, 0)}
_MAX_NPY_HEADER = 10_000  # bytes; numpy writes a few dozen
#: What the zip and ``.npy`` parsers raise on damaged input (ast/tokenize parse ``.npy`` headers).
_CORRUPT = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    EOFError,
    OSError,
    ValueError,
    struct.error,
    zlib.error,
    NotImplementedError,
    RuntimeError,
    OverflowError,
    MemoryError,
    RecursionError,
    SyntaxError,
    tokenize.TokenError,
)


class FileFormatError(ValueError):
    """A file is missing, truncated, corrupted, of another format, or over the read limits."""


class FileTooLargeError(FileFormatError):
    """A file declares more data than the :class:`ReadLimits` allow (checked before inflating)."""


@dataclass(frozen=True)
class ReadLimits:
    """Upper bounds checked before a file's content is read.

    Attributes:
        max_bytes: total declared uncompressed size of all entries (and the file's own
            size), bytes.
        max_entries: number of arrays in one file.
        max_meta_bytes: size of the JSON metadata, bytes.
        max_ratio: largest compression ratio, declared content bytes per byte of the file
            on disk, of a file whose content exceeds ``ratio_floor_bytes``. A deflate
            stream can inflate about 1000-fold, so without it a 2 MB file could make a
            reader fill 2 GB; with it a file's content costs at most ``max_ratio`` times
            its size (or ``ratio_floor_bytes``). Files written uncompressed have a ratio of 1.
        ratio_floor_bytes: content up to this many bytes is read whatever its compression
            ratio.
    """

    max_bytes: int = 2 * GIB
    max_entries: int = 4096
    max_meta_bytes: int = 64 * 1024**2
    max_ratio: int = 64
    ratio_floor_bytes: int = 64 * 1024**2

    def __post_init__(self) -> None:
        for key in ("max_bytes", "max_entries", "max_meta_bytes", "max_ratio", "ratio_floor_bytes"):
            check_int(f"ReadLimits.{key}", getattr(self, key))


DEFAULT_LIMITS = ReadLimits()


@functools.lru_cache(maxsize=16)
def _versions(dists: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
    out = [("python", platform.python_version())]
    for dist in dists:
        try:
            out.append((dist, importlib_metadata.version(dist)))
        except importlib_metadata.PackageNotFoundError:
            out.append((dist, "not installed"))
    return tuple(out)


def versions(dists: Iterable[str] = DEFAULT_DISTS) -> dict[str, str]:
    """Python's version and those of the installed distributions ``dists`` (provenance)."""
    return dict(_versions(tuple(dists)))


# ---------------------------------------------------------------------------- atomic writes
def atomic_write(path: str | os.PathLike[str], write: Callable[[BinaryIO], Any]) -> Path:
    """Call ``write(fileobj)`` on a temp file next to ``path``, fsync, then rename it over ``path``.

    The file gets mode :data:`FILE_MODE`. If ``write`` raises, the temp file is removed and
    ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, FILE_MODE)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` atomically."""
    return atomic_write(path, lambda fh: fh.write(data))


def check_json(value: Any, name: str = "data") -> None:
    """Check that ``value`` is strict JSON: str keys, JSON types, finite numbers.

    Raises:
        ValueError: naming the key path of the first offending value, e.g. ``meta['loss'] is nan``.
    """
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"{name} is {value}; JSON has no NaN or infinity (store None or a string)")
    elif isinstance(value, Mapping):
        for key, item in value.items():
            if not isinstance(key, str):
                raise ValueError(
                    f"{name} has the key {key!r} of type {type(key).__name__}; JSON keys are str"
                )
            check_json(item, f"{name}[{key!r}]")
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            check_json(item, f"{name}[{i}]")
    elif value is not None and not isinstance(value, (str, int)):  # bool is an int
        raise ValueError(
            f"{name} is not JSON-serialisable (a {type(value).__name__}); JSON holds str, int, float, bool, None, lists and "
            "dicts (convert numpy values with .item() or .tolist())"
        )


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def atomic_write_json(path: str | os.PathLike[str], data: Any, *, name: str = "data") -> Path:
    """Write ``data`` as indented UTF-8 JSON; NaN/inf are refused naming the key (see :func:`check_json`)."""
    check_json(data, name)
    text = json.dumps(data, indent=2, sort_keys=True, allow_nan=False) + "\n"
    return atomic_write_bytes(path, text.encode("utf-8"))


def read_json(path: str | os.PathLike[str], *, max_bytes: int = DEFAULT_LIMITS.max_meta_bytes) -> Any:
    """Read a JSON file of at most ``max_bytes``.

    Raises:
        FileFormatError: missing, too large, not UTF-8 or not JSON; names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path} does not exist")
    try:
        if path.stat().st_size > max_bytes:
            raise FileTooLargeError(
                f"{path} has {path.stat().st_size} bytes, more than the {max_bytes} allowed"
            )
        return json.loads(path.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        if isinstance(err, FileFormatError):
            raise
        raise FileFormatError(f"{path} is not readable JSON ({type(err).__name__}: {err})") from err


# ---------------------------------------------------------------------------- checked npz
def checksum(fmt: str, file_versions: Mapping[str, str], meta: Any, arrays: Mapping[str, np.ndarray]) -> str:
    """Hex SHA-256 digest of a checked npz's content.

    It covers the format tag, versions and metadata (canonical JSON) and every array's name,
    dtype, shape and C-order bytes, in name order.
    """
    h = hashlib.sha256()
    h.update(_canonical({"format": fmt, "versions": dict(file_versions), "meta": meta}).encode())
    for name in sorted(arrays):
        a = np.asarray(arrays[name])
        h.update(_canonical([name, a.dtype.str, list(a.shape), a.nbytes]).encode())
        h.update(np.ascontiguousarray(a).reshape(-1).view(np.uint8))
    return h.hexdigest()


def _check_array(name: Any, value: Any) -> np.ndarray:
    if not isinstance(name, str) or not name or name == _META or "\0" in name or name.startswith("/"):
        raise ValueError(f"array name {name!r} is invalid; expected a non-empty str other than {_META!r}")
    a = np.asarray(value)
    if a.dtype.kind not in "biufc" or a.dtype.fields is not None or a.dtype.subdtype is not None:
        raise ValueError(
            f"array {name!r} has dtype {a.dtype}; only numeric and bool arrays are stored (no objects, no pickle)"
        )
    return a


def _write_zip(fh: BinaryIO, arrays: Mapping[str, np.ndarray], compress: bool) -> None:
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(fh, "w", compression=method, allowZip64=True) as zf:
        for name, a in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))  # reproducible bytes
            info.compress_type = method
            info.external_attr = FILE_MODE << 16
            with zf.open(info, "w", force_zip64=True) as out:
                np.lib.format.write_array(out, a, allow_pickle=False)


def write_npz(
    path: str | os.PathLike[str],
    arrays: Mapping[str, np.ndarray],
    meta: Mapping[str, Any],
    *,
    format: str,
    compress: bool = False,
) -> Path:
    """Write ``arrays`` and the JSON ``meta`` as one checked ``.npz`` file, atomically.

    Args:
        path: destination.
        arrays: name -> numeric or bool array (any shape).
        meta: JSON-compatible metadata (NaN/inf refused); library versions are added.
        format: format tag, e.g. ``"pal.history/1"``; :func:`read_npz` requires it.
        compress: deflate the entries (smaller, slower).

    Raises:
        ValueError: an object or structured array, a bad array name, or metadata that is not
            strict JSON (the message names the key).
    """
    checked = {name: _check_array(name, value) for name, value in arrays.items()}
    check_json(meta, "meta")
    if not isinstance(format, str) or not format:
        raise ValueError(f"format must be a non-empty str tag, got {format!r}")
    file_versions = versions()
    meta = json.loads(_canonical(dict(meta)))  # exactly what a reader will parse
    doc = {"format": format, "versions": file_versions, "meta": meta}
    doc["checksum"] = checksum(format, file_versions, meta, checked)
    blob = np.frombuffer(_canonical(doc).encode("utf-8"), dtype=np.uint8)
    return atomic_write(path, lambda fh: _write_zip(fh, {**checked, _META: blob}, compress))


@dataclass(frozen=True, eq=False)
class NpzFile:
    """The verified content of a file written by :func:`write_npz`.

    Attributes:
        path: the file.
        format: its format tag.
        meta: the caller's metadata.
        arrays: name -> array.
        versions: library versions of the writer.
        checksum: SHA-256 of the content (see :func:`checksum`).
    """

    path: Path
    format: str
    meta: dict[str, Any]
    arrays: dict[str, np.ndarray]
    versions: dict[str, str]
    checksum: str


def _entries(path: Path, zf: zipfile.ZipFile, limits: ReadLimits) -> list[zipfile.ZipInfo]:
    infos = zf.infolist()
    if len(infos) > limits.max_entries:
        raise FileTooLargeError(
            f"{path} has {len(infos)} entries, more than the {limits.max_entries} allowed"
        )
    names = [i.filename for i in infos]
    if len(set(names)) != len(names) or not all(n.endswith(".npy") for n in names):
        raise FileFormatError(f"{path}: entries {names} are not unique .npy arrays")
    for info in infos:
        if info.flag_bits & 0x1 or info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise FileFormatError(
                f"{path}: entry {info.filename} is encrypted or uses an unknown compression"
            )
        if info.filename == f"{_META}.npy" and info.file_size > limits.max_meta_bytes + _MAX_NPY_HEADER:
            raise FileTooLargeError(
                f"{path}: metadata declares {info.file_size} bytes, more than the {limits.max_meta_bytes} allowed"
            )
    total = sum(i.file_size for i in infos)
    size = path.stat().st_size
    if total > max(limits.ratio_floor_bytes, limits.max_ratio * size):
        raise FileTooLargeError(
            f"{path} declares {total} bytes of content in a file of {size} bytes, a compression "
            f"ratio of {total / max(size, 1):.0f} above the max_ratio {limits.max_ratio} allowed for "
            f"content over {limits.ratio_floor_bytes} bytes; refused before inflating (pass "
            "limits=ReadLimits(max_ratio=...) to read a file you trust)"
        )
    if total > limits.max_bytes:
        raise FileTooLargeError(
            f"{path} declares {total} bytes of arrays, more than the {limits.max_bytes} allowed "
            "(pass limits=ReadLimits(max_bytes=...) to read it)"
        )
    return infos


def _read_entry(path: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> np.ndarray:
    fmt = np.lib.format
    with zf.open(info) as fh:
        version = fmt.read_magic(fh)
        if version not in _NPY_VERSIONS:
            raise FileFormatError(f"{path}: {info.filename} has .npy version {version}, expected 1.0 or 2.0")
        read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
        shape, fortran, dtype = read_header(fh, max_header_size=_MAX_NPY_HEADER)
        if dtype.kind not in "biufc" or dtype.fields is not None or dtype.subdtype is not None:
            raise FileFormatError(
                f"{path}: {info.filename} has dtype {dtype}, expected a numeric or bool array"
            )
        if any(d < 0 for d in shape):
            raise FileFormatError(f"{path}: {info.filename} has the shape {shape}")
        nbytes = math.prod(shape) * dtype.itemsize
        if fh.tell() + nbytes != info.file_size:  # element count from the header vs declared size
            raise FileFormatError(
                f"{path}: {info.filename} declares {info.file_size} bytes but its header describes "
                f"{fh.tell()} + {nbytes} ({dtype} {shape})"
            )
        out = np.empty(math.prod(shape), dtype=dtype)
        if nbytes and fh.readinto(out.view(np.uint8)) != nbytes:
            raise FileFormatError(f"{path}: {info.filename} is truncated")
        if fh.read(1):
            raise FileFormatError(f"{path}: {info.filename} has trailing bytes")
    return out.reshape(shape, order="F" if fortran else "C")


def read_npz(path: str | os.PathLike[str], *, format: str, limits: ReadLimits = DEFAULT_LIMITS) -> NpzFile:
    """Read and verify a file written by :func:`write_npz`.

    Args:
        path: the file.
        format: the expected format tag.
        limits: size limits, checked before anything is inflated.

    Raises:
        FileFormatError: missing, truncated or corrupted file, another format, a checksum
            mismatch, or (:class:`FileTooLargeError`) sizes over ``limits``; names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path} is not a readable {format} file: it does not exist")
    try:
        if path.stat().st_size > limits.max_bytes + limits.max_meta_bytes:
            raise FileTooLargeError(f"{path} has {path.stat().st_size} bytes, more than the limits allow")
        with zipfile.ZipFile(path) as zf:
            arrays = {i.filename[:-4]: _read_entry(path, zf, i) for i in _entries(path, zf, limits)}
        if _META not in arrays:
            raise FileFormatError(f"{path} has no {_META} entry; it was not written by write_npz")
        blob = arrays.pop(_META)
        if blob.dtype != np.uint8 or blob.ndim != 1:
            raise FileFormatError(f"{path}: {_META} has dtype {blob.dtype} and shape {blob.shape}")
        doc = json.loads(blob.tobytes().decode("utf-8"))
    except FileFormatError:
        raise
    except _CORRUPT as err:
        raise FileFormatError(
            f"{path} is not a readable {format} file ({type(err).__name__}: {err})"
        ) from err
    if not isinstance(doc, dict) or set(doc) != _DOC_KEYS:
        raise FileFormatError(f"{path}: metadata is not a {{format, versions, meta, checksum}} object")
    if doc["format"] != format:
        raise FileFormatError(f"{path} has format {doc['format']!r}, expected {format!r}")
    if not (isinstance(doc["meta"], dict) and isinstance(doc["versions"], dict)):
        raise FileFormatError(f"{path}: meta and versions must be JSON objects")
    if checksum(format, doc["versions"], doc["meta"], arrays) != doc["checksum"]:
        raise FileFormatError(f"{path}: checksum mismatch; its arrays or metadata were changed after writing")
    return NpzFile(path, format, doc["meta"], arrays, doc["versions"], doc["checksum"])
