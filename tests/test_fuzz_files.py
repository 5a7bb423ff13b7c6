"""Seeded byte-flip fuzzing: a flipped byte either leaves the content identical or is refused.

2,000 single-byte flips each, of a small saved world model (through ``models.io.load``) and
of a small dataset chunk (through ``pal.io.dataset.read_chunk``): 0 silent content changes and 0
exceptions of another type than the documented one.
"""

from __future__ import annotations

import numpy as np
import pytest

from models import ModelFileError
from pal.experiments.bench.fuzz import TARGETS, same_arrays
from pal.io.dataset import DatasetFileError
from pal.io.files import FileFormatError, read_npz, write_npz
from pal.io.fuzz import FuzzResult, flip_bytes

FLIPS = 2000


def assert_sound(result: FuzzResult) -> None:
    assert result.flips == FLIPS == result.same + result.refused + result.changed + result.wrong_error
    assert result.changed == 0 and result.wrong_error == 0, (result.wrong_types, result.examples)
    assert result.refused > FLIPS // 2  # most flips hit content, which the checksum catches


#: targets whose flips take seconds (the fitted world model, a dataset chunk)
SLOW_TARGETS = {"world_model", "dataset_chunk"}


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_TARGETS else n for n in sorted(TARGETS)]
)
def test_file_survives_byte_flips(name, tmp_path):
    target = TARGETS[name](tmp_path, 0)
    assert target.expected in (ModelFileError, DatasetFileError)
    assert_sound(flip_bytes(target.path, FLIPS, 1, target.load, target.same, expected=target.expected))


def test_deflated_npz_survives_byte_flips(tmp_path):
    arrays = {
        "a": np.arange(12, dtype=np.float32).reshape(3, 4),
        "flag": np.array([True, False]),
        "n": np.int64(7),
    }
    path = write_npz(tmp_path / "x.npz", arrays, {"k": [1, None, "s"]}, format="test/1", compress=True)

    def load_(p):
        return read_npz(p, format="test/1")

    def same(a, b):
        return a.meta == b.meta and a.versions == b.versions and same_arrays(a.arrays, b.arrays)

    result = flip_bytes(path, 1000, 2, load_, same, expected=FileFormatError)
    assert result.ok and result.refused > 500, (result.wrong_types, result.examples)


def test_flip_bytes_reports_silent_changes_and_wrong_error_types(tmp_path):
    path = tmp_path / "raw.bin"
    path.write_bytes(bytes(range(64)))

    def careless(p):  # returns whatever is there, and sometimes raises an undocumented type
        data = p.read_bytes()
        if data[0] != 0:
            raise KeyError("first byte")
        return data

    result = flip_bytes(path, 200, 0, careless, lambda a, b: a == b, expected=ValueError)
    assert result.changed + result.wrong_error == 200 and result.wrong_error > 0
    assert result.wrong_types == {"KeyError": result.wrong_error} and not result.ok
    assert path.read_bytes() == bytes(range(64))  # the original is never modified
