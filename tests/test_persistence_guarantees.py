"""Both persistence layers (``pal.io.files`` and its copy in ``models.io``) give the same guarantees.

Each guarantee is checked on both sides: file mode, a checksum that covers the metadata and
each array's dtype and shape, size limits checked before reading, the NaN policy of JSON,
atomicity of an interrupted write, refusal of pickled content, and one ``versions()`` per side.
"""

from __future__ import annotations

import ast
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import models.io as model_io
import pal.io.files as pal_files
from models import WorldModel, chain_graph

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Side:
    """One persistence layer: how to write a file with given metadata, read it, and its errors."""

    name: str
    error: type[Exception]
    too_large: type[Exception]
    limits: Any
    nan_key: str

    def write(self, path: Path, value: Any = 1) -> Path:
        if self.name == "pal":
            arrays = {"w": np.arange(6, dtype=np.float32).reshape(2, 3)}
            return pal_files.write_npz(path, arrays, {"x": value}, format="test/1")
        torch.manual_seed(0)
        return model_io.save(WorldModel(chain_graph(), hidden=(3,)), path, provenance={"x": value})

    def read(self, path: Path, limits: Any = None) -> Any:
        kw = {} if limits is None else {"limits": limits}
        if self.name == "pal":
            return pal_files.read_npz(path, format="test/1", **kw)
        return model_io.load(path, **kw)


SIDES = [
    Side("pal", pal_files.FileFormatError, pal_files.FileTooLargeError, pal_files.ReadLimits, r"meta\['x'\]"),
    Side(
        "models",
        model_io.ModelFileError,
        model_io.ModelFileTooLargeError,
        model_io.ReadLimits,
        r"provenance\['x'\]",
    ),
]
sides = pytest.mark.parametrize("side", SIDES, ids=lambda s: s.name)


def _rewrite(path: Path, edit) -> None:
    """Rewrite a written file with ``edit(doc, arrays)`` applied, keeping the stored checksum."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    doc = json.loads(arrays.pop("__meta__").tobytes())
    edit(doc, arrays)
    arrays["__meta__"] = np.frombuffer(json.dumps(doc).encode(), dtype=np.uint8)
    np.savez(path, **arrays)


def _first_2d(arrays: dict[str, np.ndarray]) -> str:
    return next(k for k, a in arrays.items() if a.ndim == 2 and a.shape[0] != a.shape[1])


def test_both_sides_share_the_constants():
    assert pal_files.FILE_MODE == model_io.FILE_MODE == 0o644
    assert pal_files.ReadLimits() == pal_files.DEFAULT_LIMITS
    assert pal_files.ReadLimits().max_bytes == model_io.ReadLimits().max_bytes == 2 * 1024**3
    assert issubclass(pal_files.FileTooLargeError, pal_files.FileFormatError)
    assert issubclass(model_io.ModelFileTooLargeError, model_io.ModelFileError)
    assert issubclass(pal_files.FileFormatError, ValueError) and issubclass(
        model_io.ModelFileError, ValueError
    )


def test_both_sides_compute_the_same_checksum():
    arrays = {"b": np.arange(3.0), "a": np.ones((2, 2), np.int8)}
    meta, vers = {"k": [1, "x", None]}, {"python": "3"}
    assert pal_files.checksum("f/1", vers, meta, arrays) == model_io._checksum("f/1", vers, meta, arrays)


@sides
def test_every_written_file_has_one_mode_whatever_the_umask(side, tmp_path):
    old = os.umask(0o077)
    try:
        path = side.write(tmp_path / "x.npz")
        pal_files.atomic_write_json(tmp_path / "x.json", {"a": 1})
    finally:
        os.umask(old)
    assert (path.stat().st_mode & 0o777) == 0o644
    assert ((tmp_path / "x.json").stat().st_mode & 0o777) == 0o644


@sides
def test_the_checksum_covers_the_metadata(side, tmp_path):
    path = side.write(tmp_path / "x.npz", value=1)
    _rewrite(path, lambda doc, arrays: None)
    side.read(path)  # an unchanged rewrite still reads

    def edit(doc, arrays):
        (doc["meta"]["provenance"] if side.name == "models" else doc["meta"])["x"] = 2

    _rewrite(path, edit)
    with pytest.raises(side.error, match="checksum mismatch"):
        side.read(path)
    path = side.write(tmp_path / "y.npz")
    _rewrite(path, lambda doc, arrays: doc["versions"].update(numpy="0.0"))
    with pytest.raises(side.error, match="checksum mismatch"):
        side.read(path)


@sides
@pytest.mark.parametrize("change", ["dtype", "shape"])
def test_the_checksum_covers_each_arrays_dtype_and_shape(side, tmp_path, change):
    path = side.write(tmp_path / "x.npz")

    def edit(doc, arrays):
        key = _first_2d(arrays)
        a = arrays[key]
        arrays[key] = (
            a.view(np.int32 if a.dtype == np.float32 else np.int64) if change == "dtype" else a.T.copy()
        )
        assert arrays[key].tobytes() == a.tobytes() or change == "shape"

    _rewrite(path, edit)
    with pytest.raises(side.error, match="checksum mismatch"):
        side.read(path)


@sides
def test_size_limits_are_checked_before_reading(side, tmp_path):
    path = side.write(tmp_path / "x.npz")
    with pytest.raises(side.too_large, match="more than the 64 allowed"):
        side.read(path, side.limits(max_bytes=64))
    with pytest.raises(side.too_large, match="more than the 1 allowed"):
        side.read(path, side.limits(max_entries=1))
    side.read(path, side.limits(max_bytes=10**6))  # an override reads it


@sides
def test_content_beyond_the_compression_ratio_is_refused_before_inflating(side, tmp_path):
    from tests.hostile import npz_bomb

    assert side.limits() == side.limits(max_ratio=64, ratio_floor_bytes=64 * 1024**2)
    path = npz_bomb(tmp_path / "bomb.npz", "w", n_bytes=1900 << 20)  # 2 MB declaring 1.99 GB
    assert path.stat().st_size < 2 * 10**6
    with pytest.raises(side.too_large, match=r"bomb\.npz declares 1992294528 bytes .* compression ratio"):
        side.read(path)
    with pytest.raises(side.too_large, match=r"more than the 1000000 allowed"):  # the next check
        side.read(path, side.limits(max_ratio=10**4, max_bytes=10**6))
    small = side.write(tmp_path / "x.npz")  # stored uncompressed: a ratio below 1
    side.read(small, side.limits(max_ratio=1, ratio_floor_bytes=1))


@sides
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), [0.0, float("-inf")]])
def test_json_refuses_nan_and_inf_naming_the_key(side, tmp_path, bad):
    with pytest.raises(ValueError, match=side.nan_key + r".* is (nan|inf|-inf); JSON has no NaN"):
        side.write(tmp_path / "x.npz", value=bad)
    assert not (tmp_path / "x.npz").exists()


@sides
def test_an_interrupted_write_leaves_the_old_file_and_no_temp_file(side, tmp_path, monkeypatch):
    path = side.write(tmp_path / "x.npz", value=1)
    before = path.read_bytes()
    real, calls = np.lib.format.write_array, []

    def crash_after_one_array(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt("interrupted in the middle of the file")
        return real(*args, **kwargs)

    monkeypatch.setattr(np.lib.format, "write_array", crash_after_one_array)
    with pytest.raises(KeyboardInterrupt):
        side.write(path, value=2)
    monkeypatch.undo()
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["x.npz"]
    side.read(path)


@sides
def test_pickled_content_is_refused_without_unpickling(side, tmp_path):
    np.savez(tmp_path / "x.npz", __meta__=np.array([{"format": "test/1"}], dtype=object))
    with pytest.raises(side.error, match="dtype object"):
        side.read(tmp_path / "x.npz")


@sides
def test_a_corrupt_file_raises_the_documented_type_naming_it(side, tmp_path):
    path = side.write(tmp_path / "x.npz")
    blob = path.read_bytes()
    for k, damaged in enumerate([blob[: len(blob) // 2], blob[:40], b"", b"PK\x05\x06" + b"\0" * 18]):
        target = tmp_path / f"d{k}.npz"
        target.write_bytes(damaged)
        with pytest.raises(side.error, match=rf"d{k}\.npz"):
            side.read(target)


def _defs(package: str, name: str) -> list[str]:
    found = []
    for path in sorted((ROOT / package).rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        found += [
            str(path.relative_to(ROOT))
            for n in ast.walk(tree)
            if isinstance(n, ast.FunctionDef) and n.name == name
        ]
    return found


def test_one_versions_function_per_side():
    assert _defs("pal", "versions") == ["pal/io/files.py"]
    assert _defs("models", "versions") == ["models/io.py"]


def test_no_source_loads_with_pickle():
    needle = "allow_pickle=" + "True"  # split, so that a grep of the tree finds no such call here
    for package in ("pal", "models", "inference"):
        for path in (ROOT / package).rglob("*.py"):
            assert needle not in path.read_text(), path
