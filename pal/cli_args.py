"""Checked values of the ``pal`` command's flags: bounded numbers and output directories.

Each is an argparse ``type=``: a bad value is refused while the command line is parsed, as
one line that names the flag and the value (``pal babble: argument --seed: -1 is not an int in
[0, 4294967295]``), before any work starts. The limits are the library's own
(:data:`pal.checks.MAX_SEED`, :data:`pal.checks.MAX_STEPS`,
:data:`pal.sim.recording.MAX_FPS`), so the command and the API refuse the same values.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from pal.checks import MAX_SEED, MAX_STEPS
from pal.cli_body import UsageError

__all__ = [
    "DATASET_ENTRIES",
    "babble_steps",
    "bounded_float",
    "bounded_int",
    "check_dataset_dir",
    "fps",
    "out_dir",
    "seed",
]

#: Longest number text a flag may hold (Python refuses ints of more than 4300 digits itself).
_MAX_DIGITS = 100

#: Names a babbling dataset directory holds (``*`` any characters): the manifest, its chunks,
#: the writer's lock, the shards of a parallel run, a merge in progress and atomic-write temporaries.
DATASET_ENTRIES = ("metadata.json", "chunk_*.npz", "writer.lock", "shards", ".merging", ".*.tmp")


def bounded_int(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: an int in ``[low, high]``."""

    def parse(text: str) -> int:
        try:
            if len(text) > _MAX_DIGITS:
                raise ValueError(text)
            value = int(text)
        except ValueError:
            shown = text if len(text) <= 40 else f"{text[:40]}... ({len(text)} characters)"
            raise argparse.ArgumentTypeError(f"{shown!r} is not an int in [{low}, {high}]") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{value} is not an int in [{low}, {high}]")
        return value

    return parse


def bounded_float(low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a finite number in ``(low, high]``."""

    def parse(text: str) -> float:
        try:
            value = float(text) if len(text) <= _MAX_DIGITS else math.nan
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and low < value <= high):
            shown = text if len(text) <= 40 else f"{text[:40]}..."
            raise argparse.ArgumentTypeError(f"{shown!r} is not a finite number in ({low:g}, {high:g}]")
        return value

    return parse


#: ``--seed``: an int in ``[0, MAX_SEED]``.
seed = bounded_int(0, MAX_SEED)


#: ``pal babble --steps``: an int in ``[1, MAX_STEPS]``.
babble_steps = bounded_int(1, MAX_STEPS)


def fps(text: str) -> float:
    """``pal record --fps``: a finite number in ``(0, MAX_FPS]`` (:data:`pal.sim.recording.MAX_FPS`)."""
    from pal.sim.recording import MAX_FPS

    return bounded_float(0.0, MAX_FPS)(text)


def out_dir(text: str) -> str:
    """An argparse type: a directory path that is not empty (``""`` would mean the working directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is empty; name a directory (write . for the current one)")
    return text


def check_dataset_dir(out: Path) -> None:
    """Refuse an existing directory that holds files other than a babbling dataset's.

    Raises:
        UsageError: ``out`` holds an entry that no dataset writes (named in the message).
    """
    if not out.is_dir():
        return
    foreign = sorted(p.name for p in out.iterdir() if not any(p.match(g) for g in DATASET_ENTRIES))
    if foreign:
        shown = foreign[:3] + (["..."] if len(foreign) > 3 else [])
        raise UsageError(
            f"pal babble: --out {str(out)!r} is a non-empty directory that is not a pal dataset ({len(foreign)} "
            f"{'entry' if len(foreign) == 1 else 'entries'} no dataset holds: {shown}); choose a new or empty directory"
        )
