"""Wall-clock timing shared by the benchmarks (``pal bench NAME``).

Every figure is the median of ``repeats`` timed calls (``time.perf_counter``) after
``warmup`` untimed calls, so lazy initialisation, allocator growth and first-call
dispatch costs stay out of it. :func:`measure_interleaved` alternates the contenders
within each repeat, so a change in machine load hits both sides of a ratio alike. The CPU
time of the calling thread (``time.thread_time``) is recorded beside the wall time: on a
loaded machine it moves far less, and with one torch thread it is the whole cost of a call.
"""

from __future__ import annotations

import contextlib
import statistics
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import torch

from pal.checks import check_int

__all__ = ["Timing", "measure", "measure_interleaved", "ratio", "torch_threads"]


@dataclass(frozen=True)
class Timing:
    """Timed repeats of one call.

    Attributes:
        seconds: wall time of each timed repeat, s.
        result: return value of the last call (not compared, not printed).
        cpu_seconds: CPU time of the calling thread in each timed repeat, s.
    """

    seconds: tuple[float, ...]
    result: Any = field(default=None, repr=False, compare=False)
    cpu_seconds: tuple[float, ...] = ()

    @property
    def median(self) -> float:
        """Median wall time, s."""
        return statistics.median(self.seconds)

    @property
    def ms(self) -> float:
        """Median wall time, ms."""
        return 1e3 * self.median

    @property
    def cpu_median(self) -> float:
        """Median CPU time of the calling thread, s (0 when not recorded)."""
        return statistics.median(self.cpu_seconds) if self.cpu_seconds else 0.0


def _check(repeats: int, warmup: int) -> None:
    check_int("repeats", repeats)
    check_int("warmup", warmup, minimum=0)


def measure(fn: Callable[[], Any], repeats: int = 5, warmup: int = 1, no_grad: bool = False) -> Timing:
    """Time ``fn()``: ``warmup`` untimed calls, then ``repeats`` timed ones.

    Args:
        fn: the call to time, without arguments.
        repeats: number of timed calls (>= 1).
        warmup: number of untimed calls before them (>= 0).
        no_grad: run every call under ``torch.no_grad()``.

    Returns:
        :class:`Timing` with one wall time per timed call.
    """
    return measure_interleaved({"fn": fn}, repeats, warmup, no_grad)["fn"]


def measure_interleaved(
    fns: Mapping[str, Callable[[], Any]], repeats: int = 5, warmup: int = 1, no_grad: bool = False
) -> dict[str, Timing]:
    """Time several calls, alternating them inside each repeat (see :func:`measure`).

    Returns:
        name -> :class:`Timing`.
    """
    _check(repeats, warmup)
    if not fns:
        raise ValueError("fns is empty; give at least one call to time")
    ctx = torch.no_grad if no_grad else contextlib.nullcontext
    times: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    results: dict[str, Any] = {}
    with ctx():
        for _ in range(warmup):
            for fn in fns.values():
                fn()
        for _ in range(repeats):
            for name, fn in fns.items():
                start, start_cpu = time.perf_counter(), time.thread_time()
                results[name] = fn()
                times[name].append(time.perf_counter() - start)
                cpu[name].append(time.thread_time() - start_cpu)
    return {k: Timing(tuple(v), results[k], tuple(cpu[k])) for k, v in times.items()}


def ratio(numerator: float | None, denominator: float | None) -> float | None:
    """``numerator / denominator``, or None when either is missing or the denominator is 0."""
    if numerator is None or denominator is None or denominator == 0:
        return None
    return numerator / denominator


@contextlib.contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run the block with ``torch.set_num_threads(threads)`` (None: leave it), then restore it."""
    if threads is None:
        yield
        return
    check_int("threads", threads)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)
