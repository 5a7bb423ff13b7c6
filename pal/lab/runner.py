"""Running registered entries: configuration from the command line, timing, provenance, output checks.

:func:`configure` builds an entry's config from ``--quick``, ``--set a.b=v`` and the body
flags; :func:`check_output_dir` refuses an unusable ``--out`` before any work starts;
:func:`execute` runs the entry and returns a :class:`RunRecord` that
:mod:`pal.lab.render` writes.
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pal.io.files import versions
from pal.lab import configs
from pal.lab.registry import Entry
from pal.lab.report import Report

__all__ = ["LOG_FORMAT", "OutputError", "RunRecord", "check_output_dir", "configure", "execute", "log_like"]

log = logging.getLogger(__name__)

#: The command line's log lines; its worker processes log the same way (:func:`log_like`).
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def log_like(level: int) -> None:
    """Log at ``level`` to stderr in :data:`LOG_FORMAT`: a worker process set up like the command that started it."""
    logging.basicConfig(level=level, format=LOG_FORMAT, stream=sys.stderr)
    logging.getLogger().setLevel(level)


class OutputError(ValueError):
    """An output location that cannot be written: a file where a directory is needed, or no permission."""


@dataclass(frozen=True)
class RunRecord:
    """One finished run with its provenance.

    Attributes:
        name, kind: the registry entry.
        config: the configuration as nested dicts.
        seed: the run's seed.
        versions: Python's and the libraries' versions.
        seconds: wall time of ``run``, s.
        report: what the run returned.
    """

    name: str
    kind: str
    config: dict[str, Any]
    seed: int
    versions: dict[str, str]
    seconds: float
    report: Report

    @property
    def figures(self) -> tuple[str, ...]:
        """Names of the report's figures."""
        return tuple(self.report.figures)


def configure(
    entry: Entry,
    *,
    quick: bool = False,
    sets: Sequence[str] = (),
    fields: Mapping[str, Any] | None = None,
    tiny: bool = False,
) -> Any:
    """The entry's config: default, quick or tiny, then ``fields`` and ``sets`` applied in order.

    Args:
        entry: the registry entry.
        quick: start from the quick config instead of the full protocol.
        tiny: start from the tiny config (the smallest that runs every code path; not with ``quick``).
        sets: ``"a.b=VALUE"`` strings (``--set``); VALUE is JSON or a bare string.
        fields: dotted path -> value, applied before ``sets`` (e.g. from the body flags).

    Raises:
        configs.ConfigError: a malformed item, an unknown path or a value of the wrong type.
        ValueError: the config's own checks refuse a value.
    """
    if quick and tiny:
        raise ValueError("choose one of quick and tiny, not both")
    config = entry.quick if quick else entry.tiny if tiny else entry.default()
    for path, value in (fields or {}).items():
        config = configs.override(config, path, value)
    for item in sets:
        config = configs.apply_set(config, item)
    return config


def check_output_dir(path: str | os.PathLike[str]) -> Path:
    """Create ``path`` if needed and prove it writable, before any work starts.

    Raises:
        OutputError: ``path`` (or a parent) is a file, or a file cannot be created in it.
    """
    out = Path(path)
    for parent in (out, *out.parents):
        if parent.exists() and not parent.is_dir():
            raise OutputError(f"--out {str(path)!r}: {parent} is a file, expected a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as err:
        raise OutputError(f"--out {str(path)!r} is not writable ({err.strerror or err})") from None
    return out


def execute(entry: Entry, config: Any = None, *, progress_bar: bool = False) -> RunRecord:
    """Run ``entry`` on ``config`` (default: its full protocol) and time it.

    Raises:
        ValueError: ``config`` is not an instance of the entry's config type.
        TypeError: ``run`` did not return a :class:`Report`.
    """
    config = entry.default() if config is None else config
    if not isinstance(config, entry.config):
        raise ValueError(
            f"{entry.kind} {entry.name!r} expects a {entry.config.__qualname__}, got {type(config).__name__}"
        )
    start = time.perf_counter()
    report = entry.run(config, progress_bar)
    seconds = time.perf_counter() - start
    if not isinstance(report, Report):
        raise TypeError(f"{entry.kind} {entry.name!r} returned {type(report).__name__}, expected a Report")
    log.info("%s %s took %.1f s", entry.kind, entry.name, seconds)
    return RunRecord(
        name=entry.name,
        kind=entry.kind,
        config=configs.to_dict(config),
        seed=int(config.seed),
        versions=versions(
            ("pal", "torch", "pyro-ppl", "numpy", "mujoco", "opencv-python-headless", "gymnasium")
        ),
        seconds=seconds,
        report=report,
    )
