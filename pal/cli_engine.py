"""The engine options of ``pal babble`` and ``pal sweep``: ``--engine local|ray``, ``--ray-address``, ``--ray-timeout``.

Ray is an optional extra: :mod:`pal.lab.ray_engine` is imported only for ``--engine ray``.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from typing import Any

from pal.cli_body import UsageError

__all__ = ["add_engine_flags", "connected", "ray_engine"]


def add_engine_flags(p: argparse.ArgumentParser, what: str) -> None:
    """Add ``--engine``, ``--ray-address`` and ``--ray-timeout``; ``what`` says where the work goes."""
    p.add_argument("--engine", choices=["local", "ray"], default="local", help=f"{what} (default local)")
    p.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDRESS",
        help="existing Ray cluster (ray.init(address=...)); default: a local Ray with --workers CPUs",
    )
    p.add_argument(
        "--ray-timeout",
        type=float,
        default=30.0,
        metavar="SECONDS",
        help="seconds the Ray address has to answer (default 30)",
    )


def ray_engine(command: str, args: argparse.Namespace) -> Any:
    """The Ray engine of ``--engine ray`` (not connected yet), or None for ``--engine local``.

    Raises:
        UsageError: ``--ray-address`` without ``--engine ray``, a timeout <= 0, or Ray not installed.
    """
    if args.engine != "ray":
        if args.ray_address is not None:
            raise UsageError(f"pal {command}: --ray-address needs --engine ray")
        return None
    if not args.ray_timeout > 0:
        raise UsageError(f"pal {command}: --ray-timeout must be > 0 seconds, got {args.ray_timeout}")
    try:
        from pal.lab.ray_engine import RayEngine
    except ModuleNotFoundError as err:
        if err.name != "ray" and not str(err.name).startswith("ray."):
            raise
        raise UsageError(
            f'pal {command}: --engine ray needs Ray, an optional extra: pip install ".[ray]"'
        ) from None
    return RayEngine(args.ray_address, timeout=args.ray_timeout, cpus=args.workers)


@contextlib.contextmanager
def connected(command: str, engine: Any) -> Iterator[Any]:
    """Connect ``engine`` (None: nothing to do) for the block; a Ray that does not answer is a UsageError."""
    if engine is None:
        yield None
        return
    from pal.lab.ray_engine import RayEngineError

    try:
        engine.__enter__()
    except RayEngineError as err:
        raise UsageError(f"pal {command}: {err}") from None
    try:
        yield engine
    finally:
        engine.__exit__(None, None, None)
