"""``pal bench fuzz``: seeded byte flips of a world-model file and a dataset chunk.

Each flip XORs one byte of a copy of the file with a random non-zero mask and loads it
(:func:`pal.io.fuzz.flip_bytes`). A sound loader either returns content identical to the
original (a flip in bytes that carry no content) or raises its documented error type
(:class:`models.io.ModelFileError`, :class:`pal.io.dataset.DatasetFileError`): 0 silent changes
and 0 other exception types. The flips per second of each loader are reported beside the
counts. The test suite runs 2 000 flips of each target; ``pal bench fuzz`` runs 20 000.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from models import ModelFileError, WorldModel, chain_graph, load, save
from pal.checks import check_int
from pal.io.dataset import DatasetFileError, DatasetWriter, read_chunk
from pal.io.fuzz import flip_bytes
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target

__all__ = [
    "TARGETS",
    "Config",
    "FuzzTarget",
    "chunk_target",
    "model_target",
    "run",
    "same_arrays",
    "same_model",
]


@dataclass(frozen=True)
class FuzzTarget:
    """A file, its loader, an equality of loaded contents, and the loader's documented error."""

    path: Path
    load: Callable[[Path], Any]
    same: Callable[[Any, Any], bool]
    expected: type[BaseException]


def same_model(a: WorldModel, b: WorldModel) -> bool:
    """Equal graphs, mechanism configs, provenance and parameters (dtype and values)."""
    sa, sb = a.state_dict(), b.state_dict()
    return (
        list(sa) == list(sb)
        and all(sa[k].dtype == sb[k].dtype and torch.equal(sa[k], sb[k]) for k in sa)
        and a.graph.to_dict() == b.graph.to_dict()
        and a.provenance == b.provenance
        and all(a.mechanism(n).config() == b.mechanism(n).config() for n in a.graph.non_roots)
    )


def same_arrays(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    """Equal names, dtypes, shapes and values."""
    return list(a) == list(b) and all(
        a[k].dtype == b[k].dtype and a[k].shape == b[k].shape and np.array_equal(a[k], b[k], equal_nan=True)
        for k in a
    )


def model_target(directory: Path, seed: int = 0) -> FuzzTarget:
    """A small saved world model (chain graph, 3-unit MLPs) and :func:`models.io.load`."""
    model = WorldModel(chain_graph(), hidden=(3,), seed=seed)
    path = save(model, Path(directory) / "wm.npz", provenance={"seed": seed, "config": {"epochs": 1}})
    return FuzzTarget(path, load, same_model, ModelFileError)


def chunk_target(directory: Path, seed: int = 0) -> FuzzTarget:
    """One 8-row dataset chunk and :func:`pal.io.dataset.read_chunk`."""
    rng = np.random.default_rng(seed)
    with DatasetWriter(Path(directory) / "ds", {"columns": ["q.j"], "seed": seed}) as writer:
        path = writer.write_chunk(
            {"q.j": rng.normal(size=(8, 1)).astype(np.float32)},
            {
                "ctrl": rng.uniform(-1, 1, (8, 1)).astype(np.float32),
                "state": rng.normal(size=(8, 3)),
                "step": np.arange(8),
                "episode": np.zeros(8, np.int64),
            },
            {"step": 8, "policy": {"state": [1, 2, 3]}},
        )
        writer.finish(8)

    def same(
        a: tuple[dict[str, Any], dict[str, np.ndarray]], b: tuple[dict[str, Any], dict[str, np.ndarray]]
    ) -> bool:
        return a[0] == b[0] and same_arrays(a[1], b[1])

    return FuzzTarget(path, read_chunk, same, DatasetFileError)


#: name -> maker of the fuzzed file in a scratch directory.
TARGETS: dict[str, Callable[[Path, int], FuzzTarget]] = {
    "world_model": model_target,
    "dataset_chunk": chunk_target,
}


@dataclass(frozen=True)
class Config:
    """Attributes: ``seed`` (offsets, masks, the files' content), ``flips`` per target."""

    seed: int = 0
    flips: int = 20_000

    def __post_init__(self) -> None:
        check_int("flips", self.flips)


@register("fuzz", kind="bench", config=Config, quick=Config(flips=2_000), tiny=Config(flips=200))
def run(config: Config, progress_bar: bool = False) -> Report:
    """File loaders under byte flips: every load is identical to the original or refused with the documented error."""
    counts: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="pal-bench-fuzz-") as tmp:
        for name, make in TARGETS.items():
            target = make(Path(tmp) / name, config.seed)
            start = time.perf_counter()
            result = flip_bytes(
                target.path, config.flips, config.seed, target.load, target.same, expected=target.expected
            )
            seconds = time.perf_counter() - start
            counts[name] = {
                **result.to_dict(),
                "bytes": target.path.stat().st_size,
                "seconds": seconds,
                "flips_per_s": config.flips / seconds,
                "error_type": target.expected.__name__,
            }
    rows = [
        (n, c["bytes"], c["flips"], c["same"], c["refused"], c["changed"], c["wrong_error"], c["flips_per_s"])
        for n, c in counts.items()
    ]
    return Report(
        title="Byte-flip fuzzing of the file loaders",
        metrics=counts,
        tables=[
            Table(
                "Outcomes of single-byte flips",
                (
                    "file",
                    "bytes",
                    "flips",
                    "identical",
                    "refused",
                    "changed silently",
                    "wrong error type",
                    "flips/s",
                ),
                rows,
            )
        ],
        targets=[
            Target(f"{kind}.{n}", c[kind], 0, "<=", f"{label} loads of the {n.replace('_', ' ')}")
            for n, c in counts.items()
            for kind, label in (("changed", "silently changed"), ("wrong_error", "wrongly typed failed"))
        ],
        notes=[
            f"{config.flips} flips per file, seed {config.seed}; documented errors: "
            + ", ".join(f"{c['error_type']} ({n})" for n, c in counts.items())
            + "."
        ],
    )
