"""One-file persistence of a :class:`WorldModel`: graph JSON + state_dict + provenance.

The file is an ``.npz`` archive without pickled objects: one float array per
``state_dict`` entry and a ``__meta__`` entry holding UTF-8 JSON (format tag, graph,
mechanism configs, provenance, SHA-256 checksum of the tensors). Writes are atomic.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import tempfile
import zipfile
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import torch

from models.graph import CausalGraph
from models.mechanisms import make_mechanism
from models.world import WorldModel

__all__ = ["ModelFileError", "atomic_write", "load", "read_metadata", "save", "versions"]

_FORMAT = "pal.world_model/1"
_META = "__meta__"


class ModelFileError(ValueError):
    """A world-model file is corrupted, truncated, of another format, or for another graph."""


def versions() -> dict[str, str]:
    """Versions of Python and the libraries an artifact depends on."""
    out = {"python": platform.python_version()}
    for dist in ("pal", "torch", "pyro-ppl", "numpy", "networkx"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def atomic_write(path: str | os.PathLike[str], write: Any) -> Path:
    """Call ``write(fileobj)`` on a temp file next to ``path``, fsync, then rename over it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _checksum(arrays: Mapping[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for key in sorted(arrays):
        h.update(key.encode())
        h.update(np.ascontiguousarray(arrays[key]).tobytes())
    return h.hexdigest()


def save(
    model: WorldModel, path: str | os.PathLike[str], provenance: Mapping[str, Any] | None = None
) -> Path:
    """Write ``model`` to one ``.npz`` file atomically.

    Args:
        model: the world model; every mechanism must be serialisable (MLP or linear).
        path: destination file (conventionally ``*.npz``).
        provenance: JSON-compatible extras, e.g. ``{"seed": 0, "config": {...}}``;
            library versions are added.

    Returns:
        The path written.
    """
    if not isinstance(model, WorldModel):
        raise ValueError(f"save expects a WorldModel, got {type(model).__name__}")
    mechs = {}
    for name in model.graph.non_roots:
        mech = model.mechanism(name)
        if mech.kind not in ("mlp", "linear"):
            raise ValueError(
                f"mechanism of {name!r} is a {type(mech).__name__}, which cannot be saved; "
                "only MLP and linear mechanisms are serialisable"
            )
        mechs[name] = mech.config()
    arrays = {f"state/{k}": v.detach().cpu().numpy() for k, v in model.state_dict().items()}
    prov = {"versions": versions(), **dict(provenance or {})}
    meta = {
        "format": _FORMAT,
        "graph": model.graph.to_dict(),
        "graph_fingerprint": model.graph.fingerprint(),
        "mechanisms": mechs,
        "provenance": prov,
        "checksum": _checksum(arrays),
    }
    try:
        blob = json.dumps(meta, sort_keys=True).encode()
    except TypeError as err:
        raise ValueError(f"provenance is not JSON-serialisable: {err}") from None
    arrays[_META] = np.frombuffer(blob, dtype=np.uint8)
    return atomic_write(path, lambda fh: np.savez(fh, **arrays))


def _read(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"no world-model file at {path}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as err:
        raise ModelFileError(
            f"{path} is not a readable world-model file ({type(err).__name__}: {err})"
        ) from None
    if _META not in arrays:
        raise ModelFileError(f"{path} has no {_META} entry; it was not written by models.io.save")
    try:
        meta = json.loads(arrays.pop(_META).tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ModelFileError(f"{path}: metadata is corrupted ({err})") from None
    if meta.get("format") != _FORMAT:
        raise ModelFileError(f"{path}: format {meta.get('format')!r}, expected {_FORMAT!r}")
    if _checksum(arrays) != meta.get("checksum"):
        raise ModelFileError(f"{path}: checksum mismatch; the tensors are corrupted")
    return meta, arrays


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The JSON metadata of a saved model (graph, mechanisms, provenance)."""
    return _read(path)[0]


def load(path: str | os.PathLike[str], graph: CausalGraph | None = None) -> WorldModel:
    """Rebuild a :class:`WorldModel` saved by :func:`save`.

    Args:
        path: the file.
        graph: if given, the file must have been made for this graph.

    Raises:
        ModelFileError: corrupted or truncated file, wrong format, or a graph mismatch.
    """
    meta, arrays = _read(path)
    try:
        file_graph = CausalGraph.from_dict(meta["graph"])
    except (KeyError, ValueError) as err:
        raise ModelFileError(f"{path}: stored graph is invalid ({err})") from None
    if graph is not None and graph.fingerprint() != file_graph.fingerprint():
        raise ModelFileError(
            f"{path} was made for graph {file_graph!r}, which does not match the expected {graph!r}"
        )
    try:
        mechs = {name: make_mechanism(cfg) for name, cfg in meta["mechanisms"].items()}
        model = WorldModel(file_graph, mechs)
        state = {k.removeprefix("state/"): torch.from_numpy(v.copy()) for k, v in arrays.items()}
        model.load_state_dict(state, strict=True)
    except (KeyError, ValueError, RuntimeError) as err:
        raise ModelFileError(f"{path}: cannot rebuild the model ({type(err).__name__}: {err})") from None
    model.provenance = dict(meta.get("provenance", {}))
    return model
