"""pal.io.files: checked .npz round trips, strict JSON, bounded reads, one error type."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from pal.io.files import (
    FileFormatError,
    FileTooLargeError,
    ReadLimits,
    atomic_write_json,
    check_json,
    read_json,
    read_npz,
    versions,
    write_npz,
)


def test_round_trip_keeps_every_array_and_the_metadata(tmp_path):
    arrays = {
        "f32": np.arange(6, dtype=np.float32).reshape(2, 3),
        "f64.nan": np.array([np.nan, np.inf, -1.0]),  # arrays may hold NaN; JSON may not
        "bool": np.array([True, False]),
        "empty": np.zeros((0, 4), np.int16),
        "scalar": np.int64(3),
        "complex": np.array([1 + 2j]),
        "fortran": np.asfortranarray(np.arange(6.0).reshape(2, 3)),
        "state/nested.name": np.ones(2, np.uint8),
    }
    meta = {"seed": 1, "config": {"a": [1, 2.5, None, "x", True]}}
    for compress in (False, True):
        path = write_npz(tmp_path / "x.npz", arrays, meta, format="test/1", compress=compress)
        f = read_npz(path, format="test/1")
        assert f.meta == meta and f.format == "test/1" and {"python", "numpy", "pal"} <= set(f.versions)
        assert list(f.arrays) == list(arrays) and len(f.checksum) == 64
        for k, a in arrays.items():
            b = f.arrays[k]
            assert b.dtype == np.asarray(a).dtype and b.shape == np.shape(a), k
            np.testing.assert_array_equal(b, a, err_msg=k)


def test_reading_refuses_other_formats_and_damage_with_one_error_type(tmp_path):
    path = write_npz(tmp_path / "x.npz", {"a": np.zeros(3)}, {}, format="test/1")
    with pytest.raises(FileFormatError, match=r"x\.npz has format 'test/1', expected 'other/1'"):
        read_npz(path, format="other/1")
    with pytest.raises(
        FileFormatError, match=r"missing\.npz is not a readable test/1 file: it does not exist"
    ):
        read_npz(tmp_path / "missing.npz", format="test/1")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(FileFormatError, match=r"junk\.npz is not a readable test/1 file \(BadZipFile"):
        read_npz(tmp_path / "junk.npz", format="test/1")
    np.savez(tmp_path / "plain.npz", a=np.zeros(3))
    with pytest.raises(FileFormatError, match="no __meta__ entry"):
        read_npz(tmp_path / "plain.npz", format="test/1")
    np.savez(tmp_path / "pickled.npz", a=np.array([{"x": 1}], dtype=object))
    with pytest.raises(FileFormatError, match="dtype object"):  # refused before anything is unpickled
        read_npz(tmp_path / "pickled.npz", format="test/1")


def test_writing_refuses_objects_bad_names_and_non_json_metadata(tmp_path):
    with pytest.raises(ValueError, match="array 'o' has dtype object"):
        write_npz(tmp_path / "x.npz", {"o": np.array([None])}, {}, format="t/1")
    with pytest.raises(ValueError, match="array name '__meta__' is invalid"):
        write_npz(tmp_path / "x.npz", {"__meta__": np.zeros(1)}, {}, format="t/1")
    with pytest.raises(ValueError, match=r"meta\['loss'\]\[1\] is nan; JSON has no NaN"):
        write_npz(tmp_path / "x.npz", {}, {"loss": [0.5, float("nan")]}, format="t/1")
    with pytest.raises(ValueError, match=r"meta\['seed'\] is not JSON-serialisable \(a int64\)"):
        write_npz(tmp_path / "x.npz", {}, {"seed": np.int64(3)}, format="t/1")
    with pytest.raises(ValueError, match=r"has the key 1 of type int"):
        write_npz(tmp_path / "x.npz", {}, {"names": {1: "a"}}, format="t/1")
    assert not (tmp_path / "x.npz").exists()


def test_json_is_strict_on_both_ends(tmp_path):
    with pytest.raises(ValueError, match=r"data\['a'\]\['b'\] is inf"):
        atomic_write_json(tmp_path / "x.json", {"a": {"b": float("inf")}})
    with pytest.raises(ValueError, match=r"config\[0\] is -inf"):
        check_json([float("-inf")], "config")
    atomic_write_json(tmp_path / "x.json", {"a": [1, 2]})
    assert read_json(tmp_path / "x.json") == {"a": [1, 2]}
    (tmp_path / "bad.json").write_text('{"a": ')
    with pytest.raises(FileFormatError, match=r"bad\.json is not readable JSON"):
        read_json(tmp_path / "bad.json")
    with pytest.raises(FileTooLargeError, match="more than the 5 allowed"):
        read_json(tmp_path / "x.json", max_bytes=5)


def _npy(shape, descr="<f8", body=b""):
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue() + body


def test_sizes_are_checked_before_anything_is_inflated(tmp_path, monkeypatch):
    # a zip bomb: 8 MB of zeros in a few kB, refused from the central directory alone
    path = write_npz(tmp_path / "bomb.npz", {"z": np.zeros(10**6)}, {}, format="t/1", compress=True)
    assert path.stat().st_size < 100_000
    opened = []
    monkeypatch.setattr(zipfile.ZipFile, "open", lambda self, *a, **k: opened.append(a) or 1 / 0)
    with pytest.raises(
        FileTooLargeError, match=r"declares \d+ bytes of arrays, more than the 1000000 allowed"
    ):
        read_npz(path, format="t/1", limits=ReadLimits(max_bytes=10**6))
    assert opened == []
    monkeypatch.undo()
    assert read_npz(path, format="t/1", limits=ReadLimits(max_bytes=10**7)).arrays["z"].shape == (10**6,)
    with pytest.raises(FileTooLargeError, match="entries, more than the 1 allowed"):
        read_npz(path, format="t/1", limits=ReadLimits(max_entries=1))
    # a .npy header whose shape claims 8 TB in a 100-byte entry: refused without allocating
    with zipfile.ZipFile(tmp_path / "liar.npz", "w") as zf:
        zf.writestr("a.npy", _npy((10**12,), body=b"\0" * 16))
        zf.writestr("__meta__.npy", _npy((2,), "|u1", b"{}"))
    with pytest.raises(FileFormatError, match=r"a\.npy declares \d+ bytes but its header describes"):
        read_npz(tmp_path / "liar.npz", format="t/1")
    with pytest.raises(ValueError, match="max_bytes must be a positive int"):
        ReadLimits(max_bytes=0)


def test_flipped_npy_header_bytes_raise_the_documented_type(tmp_path):
    # ast/tokenize parse .npy headers: unbalanced brackets and odd literals must not escape as
    # SyntaxError, TokenError, TypeError or MemoryError
    bodies = [
        "{'descr': '<f8', 'fortran_order': False, 'shape': (2,",
        "{'descr': 3, 'fortran_order': False, 'shape': (2,), }",
        "{'descr': '<f8', 'fortran_order': 0, 'shape': (2,), }",
        "{'descr': '<f8', 'fortran_order': False, 'shape': (-2,), }",
        "{'descr': [('a', '<f8')], 'fortran_order': False, 'shape': (2,), }",
        "{'descr': '<f8', 'fortran_order': False, 'shape': (99999999999999999999,), }",
        "'''",
    ]
    for k, text in enumerate(bodies):
        header = text.encode().ljust(118) + b"\n"
        raw = b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + b"\0" * 16
        with zipfile.ZipFile(tmp_path / f"h{k}.npz", "w") as zf:
            zf.writestr("a.npy", raw)
        with pytest.raises(FileFormatError, match=rf"h{k}\.npz"):
            read_npz(tmp_path / f"h{k}.npz", format="t/1")


def test_versions_takes_a_default_set_of_distributions():
    v = versions()
    assert {"python", "pal", "numpy", "mujoco", "gymnasium"} <= set(v)
    assert set(versions(("numpy",))) == {"python", "numpy"}
    assert versions(("no-such-dist-xyz",))["no-such-dist-xyz"] == "not installed"
    v["numpy"] = "edited"
    assert versions()["numpy"] != "edited"  # a fresh dict every call


def test_metadata_is_stored_as_compact_json(tmp_path):
    path = write_npz(tmp_path / "x.npz", {}, {"b": 1, "a": 2}, format="t/1")
    with np.load(path, allow_pickle=False) as npz:
        doc = json.loads(npz["__meta__"].tobytes())
    assert set(doc) == {"format", "versions", "meta", "checksum"} and doc["meta"] == {"a": 2, "b": 1}
