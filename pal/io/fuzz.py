"""Seeded byte-flip fuzzing of file loaders: every load must be exact or refused with one error type.

:func:`flip_bytes` flips one byte of a file at a time (XOR with a random non-zero mask, at a
random offset), loads the damaged copy and sorts the outcome:

- ``same``: the load returned content equal to the original (the flip hit bytes that carry
  no content, e.g. a zip timestamp);
- ``refused``: the load raised the documented error type;
- ``changed``: the load returned different content without an error (a silent corruption);
- ``wrong_error``: the load raised any other exception type.

A sound loader has ``changed == 0`` and ``wrong_error == 0``. The original file is never
modified: damaged copies go to a scratch directory, under the original file name.
"""

from __future__ import annotations

import os
import tempfile
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from pal.checks import check_int

__all__ = ["FuzzResult", "flip_bytes"]

T = TypeVar("T")


@dataclass(frozen=True)
class FuzzResult:
    """Outcome counts of a fuzz run.

    Attributes:
        flips: damaged loads tried.
        same, refused, changed, wrong_error: counts by outcome (module docstring).
        wrong_types: exception type name -> count, for the ``wrong_error`` outcomes.
        examples: up to 10 ``(offset, mask, outcome, detail)`` of the bad outcomes.
    """

    flips: int
    same: int
    refused: int
    changed: int
    wrong_error: int
    wrong_types: dict[str, int] = field(default_factory=dict)
    examples: tuple[tuple[int, int, str, str], ...] = ()

    @property
    def ok(self) -> bool:
        """True when no load changed content silently or raised an undocumented type."""
        return self.changed == 0 and self.wrong_error == 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible counts."""
        return {
            "flips": self.flips,
            "same": self.same,
            "refused": self.refused,
            "changed": self.changed,
            "wrong_error": self.wrong_error,
            "wrong_types": dict(self.wrong_types),
        }


def flip_bytes(
    path: str | os.PathLike[str],
    flips: int,
    seed: int,
    load: Callable[[Path], T],
    same: Callable[[T, T], bool],
    *,
    expected: type[BaseException] | tuple[type[BaseException], ...],
) -> FuzzResult:
    """Load ``flips`` copies of ``path``, each with one flipped byte, and count the outcomes.

    Args:
        path: the intact file; ``load(path)`` must succeed.
        flips: number of damaged copies to load.
        seed: seeds the offsets and masks.
        load: the loader under test; it gets the path of a damaged copy.
        same: ``same(original, loaded)`` is True when the loaded content equals the original's.
        expected: the documented error type(s) of ``load``.

    Returns:
        The outcome counts.
    """
    check_int("flips", flips, minimum=0)
    path = Path(path)
    data = path.read_bytes()
    if not data:
        raise ValueError(f"{path} is empty; there is no byte to flip")
    original = load(path)
    rng = np.random.default_rng(seed)
    offsets = rng.integers(0, len(data), size=flips)
    masks = rng.integers(1, 256, size=flips)
    counts: Counter[str] = Counter()
    wrong: Counter[str] = Counter()
    examples: list[tuple[int, int, str, str]] = []
    with tempfile.TemporaryDirectory(prefix="pal-fuzz-") as scratch:
        target = Path(scratch) / path.name
        buf = bytearray(data)
        for offset, mask in zip(offsets.tolist(), masks.tolist(), strict=True):
            buf[offset] ^= mask
            target.write_bytes(buf)
            buf[offset] ^= mask
            try:
                loaded = load(target)
            except expected:
                counts["refused"] += 1
                continue
            except Exception as err:  # the point of fuzzing: record every undocumented type
                counts["wrong_error"] += 1
                wrong[type(err).__name__] += 1
                if len(examples) < 10:
                    examples.append((offset, mask, "wrong_error", f"{type(err).__name__}: {err}"))
                continue
            if same(original, loaded):
                counts["same"] += 1
            else:
                counts["changed"] += 1
                if len(examples) < 10:
                    examples.append((offset, mask, "changed", "content differs from the original"))
    return FuzzResult(
        flips,
        counts["same"],
        counts["refused"],
        counts["changed"],
        counts["wrong_error"],
        dict(wrong),
        tuple(examples),
    )
