"""One-file persistence of a :class:`WorldModel`: graph JSON + state_dict + provenance.

The file is an ``.npz`` archive without pickled objects: one array per ``state_dict`` entry
(``state/<key>``) and a ``__meta__`` entry of UTF-8 JSON holding the format tag
(:data:`FORMAT`), library versions, the metadata (graph, its fingerprint, mechanism configs,
provenance) and a SHA-256 checksum over the format, versions, metadata and every array's
name, dtype, shape and bytes.

This module follows the rules of ``pal.io.files`` with its own copy of them (``models`` may not
import ``pal``): atomic writes (temp file, fsync, rename) with mode :data:`FILE_MODE`; strict
JSON (NaN/inf refused naming the key); sizes checked from the zip directory and the ``.npy``
headers before anything is inflated, and the content bounded relative to the file's size
(:class:`ReadLimits`); and every defect of a file raises :class:`ModelFileError`. The checksum
catches accidents, not forgery: a key given to :func:`save` and :func:`load` (or
``$PAL_MODEL_KEY``) signs and verifies the file with HMAC-SHA256 (:mod:`models.signing`).
On load the stored graph must match its stored fingerprint (and ``graph=`` when given).
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
from importlib import metadata
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import torch

from models.checks import check_int
from models.ensemble import EnsembleMechanism
from models.gated import GatedMechanism
from models.graph import CausalGraph
from models.mechanisms import Mechanism, make_mechanism, mechanism_classes
from models.signing import KEY_ENV, problem, resolve_key, sign
from models.world import WorldModel

__all__ = [
    "FILE_MODE",
    "FORMAT",
    "KEY_ENV",
    "ModelFileError",
    "ModelFileTooLargeError",
    "ModelSignatureError",
    "ReadLimits",
    "atomic_write",
    "check_json",
    "load",
    "read_metadata",
    "save",
    "versions",
]

#: Format tag of world-model files written here. Version 3 adds heteroscedastic and
#: ensemble mechanism configs; version 2 files (MLP and linear only) read unchanged.
FORMAT = "pal.world_model/3"
_READABLE_FORMATS = ("pal.world_model/2", FORMAT)
_OLD_FORMATS = ("pal.world_model/1",)
#: Mode of every file written here (owner read/write, everyone read), as in ``pal.io.files``.
FILE_MODE = 0o644
_GIB = 1024**3
_DISTS = ("pal", "torch", "pyro-ppl", "numpy", "networkx")
_META = "__meta__"
_DOC_KEYS = {"format", "versions", "meta", "checksum"}
_MODEL_KEYS = {"graph", "graph_fingerprint", "mechanisms", "provenance"}
#: name -> K of the discrete sites (models with discrete sites only).
_OPTIONAL_KEYS = {"discrete"}
_MAX_NPY_HEADER = 10_000
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


class ModelFileError(ValueError):
    """A world-model file is missing, truncated, corrupted, edited, of another format or graph."""


class ModelFileTooLargeError(ModelFileError):
    """A world-model file declares more data than the :class:`ReadLimits` allow."""


class ModelSignatureError(ModelFileError):
    """A key was given but the file is unsigned, or signed with another key or for other content."""


@dataclass(frozen=True)
class ReadLimits:
    """Upper bounds checked before a file's content is read.

    Attributes:
        max_bytes: total declared uncompressed size of all arrays (and the file size), bytes.
        max_entries: number of arrays in one file.
        max_meta_bytes: size of the JSON metadata, bytes.
        max_ratio: largest ratio of declared content to file size on disk (a deflate bomb
            inflates about 1000-fold), for content over ``ratio_floor_bytes`` bytes.
    """

    max_bytes: int = 2 * _GIB
    max_entries: int = 4096
    max_meta_bytes: int = 64 * 1024**2
    max_ratio: int = 64
    ratio_floor_bytes: int = 64 * 1024**2

    def __post_init__(self) -> None:
        for key in ("max_bytes", "max_entries", "max_meta_bytes", "max_ratio", "ratio_floor_bytes"):
            check_int(f"ReadLimits.{key}", getattr(self, key))


@functools.lru_cache(maxsize=16)
def _versions(dists: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
    out = [("python", platform.python_version())]
    for dist in dists:
        try:
            out.append((dist, metadata.version(dist)))
        except metadata.PackageNotFoundError:
            out.append((dist, "not installed"))
    return tuple(out)


def versions(dists: Iterable[str] = _DISTS) -> dict[str, str]:
    """Versions of Python and the libraries an artifact depends on."""
    return dict(_versions(tuple(dists)))


def atomic_write(path: str | os.PathLike[str], write: Callable[[BinaryIO], Any]) -> Path:
    """Call ``write(fileobj)`` on a temp file next to ``path``, fsync, then rename over it.

    The file gets mode :data:`FILE_MODE`; if ``write`` raises, ``path`` is left as it was and
    the temp file is removed.
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


def check_json(value: Any, name: str = "data") -> None:
    """Check that ``value`` is strict JSON (str keys, JSON types, finite numbers).

    Raises:
        ValueError: naming the key path of the first offending value.
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
    elif value is not None and not isinstance(value, (str, int)):
        raise ValueError(
            f"{name} is not JSON-serialisable (a {type(value).__name__}); JSON holds str, int, float, bool, None, lists and dicts"
        )


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _checksum(fmt: str, file_versions: Mapping[str, str], meta: Any, arrays: Mapping[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    h.update(_canonical({"format": fmt, "versions": dict(file_versions), "meta": meta}).encode())
    for name in sorted(arrays):
        a = np.asarray(arrays[name])
        h.update(_canonical([name, a.dtype.str, list(a.shape), a.nbytes]).encode())
        h.update(np.ascontiguousarray(a).reshape(-1).view(np.uint8))
    return h.hexdigest()


def _write_npz(path: Path, arrays: Mapping[str, np.ndarray], meta: dict[str, Any], key: bytes | None) -> Path:
    file_versions = versions()
    doc = {"format": FORMAT, "versions": file_versions, "meta": meta}
    doc["checksum"] = _checksum(FORMAT, file_versions, meta, arrays)
    if key is not None:
        doc["signature"] = sign(key, doc["checksum"])
    entries = {**arrays, _META: np.frombuffer(_canonical(doc).encode("utf-8"), dtype=np.uint8)}

    def write(fh: BinaryIO) -> None:
        with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, a in entries.items():
                info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                info.external_attr = FILE_MODE << 16
                with zf.open(info, "w", force_zip64=True) as out:
                    np.lib.format.write_array(out, a, allow_pickle=False)

    return atomic_write(path, write)


def _entries(path: Path, zf: zipfile.ZipFile, limits: ReadLimits) -> list[zipfile.ZipInfo]:
    infos = zf.infolist()
    if len(infos) > limits.max_entries:
        raise ModelFileTooLargeError(
            f"{path} has {len(infos)} entries, more than the {limits.max_entries} allowed"
        )
    names = [i.filename for i in infos]
    if len(set(names)) != len(names) or not all(n.endswith(".npy") for n in names):
        raise ModelFileError(f"{path}: entries {names} are not unique .npy arrays")
    for info in infos:
        if info.flag_bits & 0x1 or info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise ModelFileError(f"{path}: entry {info.filename} is encrypted or uses an unknown compression")
        if info.filename == f"{_META}.npy" and info.file_size > limits.max_meta_bytes + _MAX_NPY_HEADER:
            raise ModelFileTooLargeError(
                f"{path}: metadata declares {info.file_size} bytes, more than the {limits.max_meta_bytes} allowed"
            )
    total = sum(i.file_size for i in infos)
    size = path.stat().st_size
    if total > max(limits.ratio_floor_bytes, limits.max_ratio * size):
        raise ModelFileTooLargeError(
            f"{path} declares {total} bytes of content in a file of {size} bytes, a compression "
            f"ratio of {total / max(size, 1):.0f} above the max_ratio {limits.max_ratio} allowed for "
            f"content over {limits.ratio_floor_bytes} bytes; refused before inflating (pass "
            "limits=ReadLimits(max_ratio=...) to read a file you trust)"
        )
    if total > limits.max_bytes:
        raise ModelFileTooLargeError(
            f"{path} declares {total} bytes of arrays, more than the {limits.max_bytes} allowed "
            "(pass limits=ReadLimits(max_bytes=...) to read it)"
        )
    return infos


def _read_entry(path: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> np.ndarray:
    fmt = np.lib.format
    with zf.open(info) as fh:
        version = fmt.read_magic(fh)
        if version not in ((1, 0), (2, 0)):
            raise ModelFileError(f"{path}: {info.filename} has .npy version {version}, expected 1.0 or 2.0")
        read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
        shape, fortran, dtype = read_header(fh, max_header_size=_MAX_NPY_HEADER)
        if dtype.kind not in "biufc" or dtype.fields is not None or dtype.subdtype is not None:
            raise ModelFileError(f"{path}: {info.filename} has dtype {dtype}, expected a numeric array")
        if any(d < 0 for d in shape):
            raise ModelFileError(f"{path}: {info.filename} has the shape {shape}")
        nbytes = math.prod(shape) * dtype.itemsize
        if fh.tell() + nbytes != info.file_size:  # element count from the header vs declared size
            raise ModelFileError(
                f"{path}: {info.filename} declares {info.file_size} bytes but its header describes "
                f"{fh.tell()} + {nbytes} ({dtype} {shape})"
            )
        out = np.empty(math.prod(shape), dtype=dtype)
        if nbytes and fh.readinto(out.view(np.uint8)) != nbytes:
            raise ModelFileError(f"{path}: {info.filename} is truncated")
        if fh.read(1):
            raise ModelFileError(f"{path}: {info.filename} has trailing bytes")
    return out.reshape(shape, order="F" if fortran else "C")


def _read(
    path: str | os.PathLike[str], limits: ReadLimits, key: bytes | None = None
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"no world-model file at {path}")
    try:
        if path.stat().st_size > limits.max_bytes + limits.max_meta_bytes:
            raise ModelFileTooLargeError(
                f"{path} has {path.stat().st_size} bytes, more than the limits allow"
            )
        with zipfile.ZipFile(path) as zf:
            arrays = {i.filename[:-4]: _read_entry(path, zf, i) for i in _entries(path, zf, limits)}
        if _META not in arrays:
            raise ModelFileError(f"{path} has no {_META} entry; it was not written by models.io.save")
        blob = arrays.pop(_META)
        if blob.dtype != np.uint8 or blob.ndim != 1:
            raise ModelFileError(f"{path}: {_META} has dtype {blob.dtype} and shape {blob.shape}")
        doc = json.loads(blob.tobytes().decode("utf-8"))
    except ModelFileError:
        raise
    except _CORRUPT as err:
        raise ModelFileError(
            f"{path} is not a readable world-model file ({type(err).__name__}: {err})"
        ) from err
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if fmt in _OLD_FORMATS:
        raise ModelFileError(
            f"{path} is a {fmt} file, an older format without a metadata checksum; this version reads "
            f"{FORMAT}: rebuild the model (or load it with the pal release that wrote it) and save it again"
        )
    if fmt not in _READABLE_FORMATS:
        raise ModelFileError(f"{path}: format {fmt!r}, expected one of {list(_READABLE_FORMATS)}")
    signature = doc.pop("signature", None)
    if set(doc) != _DOC_KEYS or not isinstance(doc["meta"], dict) or not isinstance(doc["versions"], dict):
        raise ModelFileError(f"{path}: metadata is not a {{format, versions, meta, checksum}} object")
    if _checksum(fmt, doc["versions"], doc["meta"], arrays) != doc["checksum"]:
        raise ModelFileError(f"{path}: checksum mismatch; its tensors or metadata were changed after saving")
    wrong = None if key is None else problem(key, doc["checksum"], signature)
    if wrong:
        raise ModelSignatureError(f"{path} {wrong}")
    meta = doc["meta"]
    if not _MODEL_KEYS <= set(meta) <= _MODEL_KEYS | _OPTIONAL_KEYS:
        raise ModelFileError(
            f"{path}: metadata has keys {sorted(meta)}, expected {sorted(_MODEL_KEYS)} "
            f"(and optionally {sorted(_OPTIONAL_KEYS)})"
        )
    return {**meta, "format": fmt, "versions": doc["versions"]}, arrays


def _parts(mech: Mechanism) -> list[Mechanism]:
    """The mechanism and every mechanism it holds (an ensemble's members, a gated site's branches)."""
    if isinstance(mech, EnsembleMechanism):
        return [mech, *mech.members]
    if isinstance(mech, GatedMechanism):
        return [mech, *_parts(mech.on), *([] if mech.off is None else _parts(mech.off))]
    return [mech]


def save(
    model: WorldModel,
    path: str | os.PathLike[str],
    provenance: Mapping[str, Any] | None = None,
    *,
    key: bytes | str | None = None,
) -> Path:
    """Write ``model`` to one ``.npz`` file atomically.

    Args:
        model: the world model; every mechanism must be serialisable (MLP, linear,
            heteroscedastic, Bernoulli, categorical, or an ensemble of the continuous ones:
            :func:`models.mechanisms.mechanism_classes`); discrete sites are recorded,
            and every parameter finite.
        path: destination file (conventionally ``*.npz``).
        provenance: JSON-compatible extras, e.g. ``{"seed": 0, "config": {...}}`` (NaN/inf
            refused); library versions are added.
        key: sign the file with HMAC-SHA256 under this key (bytes or str); None: the
            environment variable ``PAL_MODEL_KEY`` if set, else unsigned (:mod:`models.signing`).

    Returns:
        The path written.

    Raises:
        ValueError: not a WorldModel, an unserialisable mechanism, a NaN/inf parameter, or
            provenance that is not strict JSON; the message names the offender.
    """
    if not isinstance(model, WorldModel):
        raise ValueError(f"save expects a WorldModel, got {type(model).__name__}")
    signing_key = resolve_key(key)
    mechs = {}
    for name in model.graph.non_roots:
        mech = model.mechanism(name)
        classes = mechanism_classes()
        for part in _parts(mech):
            if classes.get(part.kind) is not type(part):
                raise ValueError(
                    f"mechanism of {name!r} is (or holds) a {type(part).__name__}, which cannot be saved; "
                    f"only {', '.join(c.__name__ for c in classes.values())} are serialisable"
                )
        mechs[name] = mech.config()
    arrays = {}
    for key, value in model.state_dict().items():
        bad = int((~torch.isfinite(value)).sum())
        if bad:
            raise ValueError(
                f"parameter {key!r} has {bad} NaN/inf entries; refusing to save a broken model "
                "(check the fit that produced it)"
            )
        arrays[f"state/{key}"] = value.detach().cpu().numpy()
    prov = dict(provenance or {})
    check_json(prov, "provenance")
    meta = {
        "graph": model.graph.to_dict(),
        "graph_fingerprint": model.graph.fingerprint(),
        "mechanisms": mechs,
        "provenance": prov,
    }
    if model.discrete:
        meta["discrete"] = model.discrete
    try:
        meta = json.loads(_canonical(meta))  # exactly what load will parse
    except (TypeError, ValueError) as err:
        raise ValueError(f"model metadata is not JSON-serialisable: {err}") from None
    return _write_npz(Path(path), arrays, meta, signing_key)


def read_metadata(
    path: str | os.PathLike[str], *, limits: ReadLimits = ReadLimits(), key: bytes | str | None = None
) -> dict[str, Any]:
    """The verified JSON metadata of a saved model (format, versions, graph, mechanisms, provenance).

    Raises:
        ModelFileError: as :func:`load`.
    """
    return _read(path, limits, resolve_key(key))[0]


def load(
    path: str | os.PathLike[str],
    graph: CausalGraph | None = None,
    *,
    limits: ReadLimits = ReadLimits(),
    key: bytes | str | None = None,
) -> WorldModel:
    """Rebuild a :class:`WorldModel` saved by :func:`save`.

    Args:
        path: the file.
        graph: if given, the file must have been made for this graph.
        limits: size limits, checked before anything is inflated (default 2 GiB of arrays).
        key: require a valid HMAC-SHA256 signature under this key (bytes or str); None: the
            environment variable ``PAL_MODEL_KEY`` if set, else no signature is checked.

    Returns:
        The model, with the stored tensors (same dtype) and ``provenance`` (including
        ``versions``).

    Raises:
        ModelFileError: missing, truncated or corrupted file, an older or other format, a
            checksum mismatch, a stored graph that does not match its fingerprint (edited
            metadata), a graph mismatch, or sizes over ``limits``;
            :class:`ModelSignatureError` when a key is given and the file is unsigned or its
            signature does not match.
    """
    meta, arrays = _read(path, limits, resolve_key(key))
    try:
        file_graph = CausalGraph.from_dict(meta["graph"])
    except (KeyError, TypeError, ValueError) as err:
        raise ModelFileError(f"{path}: stored graph is invalid ({type(err).__name__}: {err})") from None
    if file_graph.fingerprint() != meta["graph_fingerprint"]:
        raise ModelFileError(
            f"{path}: the stored graph does not match its fingerprint; the metadata was edited"
        )
    if graph is not None and graph.fingerprint() != file_graph.fingerprint():
        raise ModelFileError(
            f"{path} was made for graph {file_graph!r}, which does not match the expected {graph!r}"
        )
    mech_cfgs = meta["mechanisms"]
    if not isinstance(mech_cfgs, dict) or set(mech_cfgs) != set(file_graph.non_roots):
        raise ModelFileError(f"{path}: mechanisms do not cover the non-root variables {file_graph.non_roots}")
    if not all(k.startswith("state/") for k in arrays):
        raise ModelFileError(
            f"{path}: unexpected arrays {sorted(k for k in arrays if not k.startswith('state/'))}"
        )
    for key, a in arrays.items():
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise ModelFileError(f"{path}: tensor {key!r} has NaN/inf entries")
    try:
        mechs = {name: make_mechanism(cfg) for name, cfg in mech_cfgs.items()}
        discrete = meta.get("discrete")
        if discrete is not None and not isinstance(discrete, dict):
            raise ModelFileError(f"{path}: 'discrete' must map site names to category counts")
        model = WorldModel(file_graph, mechs, discrete=discrete)
        state = {k.removeprefix("state/"): torch.from_numpy(v.copy()) for k, v in arrays.items()}
        floats = {t.dtype for t in state.values() if t.is_floating_point()}
        if len(floats) == 1:
            model = model.to(floats.pop())  # keep the stored precision (load_state_dict would cast)
        model.load_state_dict(state, strict=True)
    except (KeyError, TypeError, ValueError, RuntimeError) as err:
        raise ModelFileError(f"{path}: cannot rebuild the model ({type(err).__name__}: {err})") from None
    model.provenance = {**meta["provenance"], "versions": meta["versions"]}
    return model
