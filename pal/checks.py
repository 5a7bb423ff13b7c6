"""Argument checks of the pal side (configs, environments, the agent), one implementation each.

Each raises ``ValueError`` naming the parameter, the value given and what was expected.
(``models.checks`` holds the same rules for the world-model side, which may not import pal.)
"""

from __future__ import annotations

import math
import numbers
from typing import Any

__all__ = [
    "MAX_LOOP_STEPS",
    "MAX_SEED",
    "MAX_STEPS",
    "check_choice",
    "check_float",
    "check_int",
    "check_seed",
]

#: The largest seed pal accepts (seeds are 32-bit: numpy, torch and MuJoCo all take them).
MAX_SEED = 2**32 - 1
#: The most transitions one babbling run records: 10^8 rows, about a day of stepping and tens of GB.
MAX_STEPS = 10**8
#: The most steps of one closed-loop run: 10^5 steps, about 11 h at 0.4 s a step, its history in memory.
MAX_LOOP_STEPS = 10**5


def _expected_int(minimum: int | None, maximum: int | None) -> str:
    if minimum is not None and maximum is not None:
        return f"{minimum} or {maximum}" if maximum == minimum + 1 else f"an int in [{minimum}, {maximum}]"
    if minimum is not None:
        return {1: "a positive int", 0: "a non-negative int"}.get(minimum, f"an int >= {minimum}")
    return "an int" if maximum is None else f"an int <= {maximum}"


def check_int(name: str, value: Any, minimum: int | None = 1, maximum: int | None = None) -> int:
    """``int(value)`` for an integer (Python or numpy, not a bool) in ``[minimum, maximum]``.

    The message follows ``models.checks.check_int``: ``epochs must be a positive int, got 0``.
    """
    expected = _expected_int(minimum, maximum)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be {expected}, got {value!r} ({type(value).__name__})")
    value = int(value)
    if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        raise ValueError(f"{name} must be {expected}, got {value}")
    return value


def check_seed(name: str, value: Any) -> int:
    """A seed: an int in ``[0, MAX_SEED]``."""
    return check_int(name, value, minimum=0, maximum=MAX_SEED)


def check_float(
    name: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    open_low: bool = False,
    open_high: bool = False,
) -> float:
    """``float(value)`` if it is a finite real number within the bounds, else ``ValueError``.

    Args:
        name: the parameter's name, for the message.
        value: an int or float (bool refused).
        low: lower bound (None: unbounded below).
        high: upper bound (None: unbounded above).
        open_low: exclude ``low`` itself.
        open_high: exclude ``high`` itself.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a number, got {value!r} ({type(value).__name__})")
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if low is not None and (x < low or (open_low and x == low)):
        raise ValueError(f"{name} must be {'>' if open_low else '>='} {low}, got {value!r}")
    if high is not None and (x > high or (open_high and x == high)):
        raise ValueError(f"{name} must be {'<' if open_high else '<='} {high}, got {value!r}")
    return x


def check_choice(name: str, value: Any, choices: tuple[Any, ...]) -> Any:
    """``value`` if it is one of ``choices``, else ``ValueError`` listing them."""
    if value not in choices:
        raise ValueError(f"{name} {value!r} unknown; expected one of {list(choices)}")
    return value
