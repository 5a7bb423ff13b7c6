"""Argument checks shared by :mod:`models` and :mod:`inference`.

Each check returns the normalised value or raises ``ValueError`` with a message that names
the parameter, the value it got and what was expected, e.g.
``epochs must be an int >= 1, got '10' (str)``. Nothing is coerced silently: a string is
never parsed as a number and a bool is never taken for an int or a float.

Numeric arrays follow one rule (:func:`as_float_tensor`, :func:`as_float_array`): tensors
and numpy arrays of any floating dtype are converted to the requested floating dtype;
integer, bool, complex, string and object arrays are refused, because they are not values
of a continuous variable. Python numbers and nested lists of Python numbers are accepted.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "as_float_array",
    "as_float_tensor",
    "check_bool",
    "check_callable",
    "check_choice",
    "check_edges",
    "check_finite_tensor",
    "check_float",
    "check_generator",
    "check_hidden",
    "check_int",
    "check_keywords",
    "check_mapping",
    "check_names",
    "check_seed",
    "describe",
]


def describe(value: Any, limit: int = 60) -> str:
    """``repr(value)`` shortened to ``limit`` characters, with its type name."""
    if isinstance(value, Tensor):
        text = f"tensor of shape {tuple(value.shape)} and dtype {value.dtype}"
        return text if value.numel() > 4 else f"{text}: {value.detach().cpu().tolist()}"
    if isinstance(value, np.ndarray):
        text = f"array of shape {value.shape} and dtype {value.dtype}"
        return text if value.size > 4 else f"{text}: {value.tolist()}"
    text = repr(value)
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    return f"{text} ({type(value).__name__})"


def _is_bool(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_))


def check_int(name: str, value: Any, minimum: int | None = 1, maximum: int | None = None) -> int:
    """An int in ``[minimum, maximum]`` (bools and floats such as 2.0 are refused)."""
    if minimum is not None and maximum is not None:
        expected = (
            f"{minimum} or {maximum}" if maximum == minimum + 1 else f"an int in [{minimum}, {maximum}]"
        )
    elif minimum == 1:
        expected = "a positive int"
    elif minimum == 0:
        expected = "a non-negative int"
    elif minimum is not None:
        expected = f"an int >= {minimum}"
    elif maximum is not None:
        expected = f"an int <= {maximum}"
    else:
        expected = "an int"
    if _is_bool(value) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be {expected}, got {describe(value)}")
    value = int(value)
    if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        raise ValueError(f"{name} must be {expected}, got {value}")
    return value


def check_seed(name: str, value: Any) -> int:
    """A seed: an int >= 0."""
    return check_int(name, value, minimum=0)


def check_float(
    name: str,
    value: Any,
    *,
    minimum: float | None = None,
    maximum: float | None = None,
    min_open: bool = False,
    max_open: bool = False,
    finite: bool = True,
) -> float:
    """A real number (int, float or a 0-d array of them; not bool or str), finite unless ``finite=False``.

    Args:
        name: the parameter name used in the message.
        value: the value to check.
        minimum: optional lower bound.
        maximum: optional upper bound.
        min_open: exclude ``minimum`` itself.
        max_open: exclude ``maximum`` itself.
        finite: refuse inf (NaN is always refused).
    """
    parts = []
    if minimum is not None:
        parts.append(f"{'>' if min_open else '>='} {minimum:g}")
    if maximum is not None:
        parts.append(f"{'<' if max_open else '<='} {maximum:g}")
    kind = "a finite number" if finite else "a number"
    expected = f"{' and '.join(parts)} ({kind})" if parts else kind
    if (
        isinstance(value, (Tensor, np.ndarray))
        and value.ndim == 0
        and value.dtype not in (torch.bool, np.bool_)
    ):
        value = value.item()  # a 0-d tensor or array is a number
    if _is_bool(value) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be {expected}, got {describe(value)}")
    value = float(value)
    if math.isnan(value) or (finite and math.isinf(value)):
        raise ValueError(f"{name} must be {expected}, got {value}")
    if minimum is not None and (value < minimum or (min_open and value == minimum)):
        raise ValueError(f"{name} must be {expected}, got {value:g}")
    if maximum is not None and (value > maximum or (max_open and value == maximum)):
        raise ValueError(f"{name} must be {expected}, got {value:g}")
    return value


def check_hidden(value: Any, name: str = "hidden") -> tuple[int, ...]:
    """MLP hidden layer widths: a sequence of ints >= 1 (empty for an affine map)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise ValueError(f"{name} must be a sequence of layer widths, e.g. (32, 32), got {describe(value)}")
    return tuple(check_int(f"{name}[{k}]", h, minimum=1) for k, h in enumerate(value))


def check_bool(name: str, value: Any) -> bool:
    """A bool (0, 1 and strings are refused)."""
    if not _is_bool(value):
        raise ValueError(f"{name} must be True or False, got {describe(value)}")
    return bool(value)


def check_choice(name: str, value: Any, choices: Sequence[str]) -> str:
    """One of the string ``choices``."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} {value!r} unknown; expected one of {list(choices)}")
    return value


def check_callable(name: str, value: Any) -> Callable[..., Any]:
    """A callable."""
    if not callable(value):
        raise ValueError(f"{name} must be callable, got {describe(value)}")
    return value


def check_generator(name: str, value: Any) -> torch.Generator | None:
    """A ``torch.Generator`` or None."""
    if value is not None and not isinstance(value, torch.Generator):
        raise ValueError(
            f"{name} must be a torch.Generator or None, got {describe(value)}; "
            "e.g. torch.Generator().manual_seed(0)"
        )
    return value


def check_mapping(name: str, value: Any, *, allow_none: bool = False) -> Mapping[Any, Any]:
    """A mapping (``None`` becomes ``{}`` when ``allow_none``)."""
    if value is None and allow_none:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} must be a mapping, got {describe(value)}")
    return value


def check_names(name: str, value: Any, *, allow_empty: bool = True, unique: bool = True) -> list[str]:
    """A sequence of strings (a bare string is refused: it is not a list of names)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, Iterable) or isinstance(value, Mapping):
        raise ValueError(f"{name} must be a sequence of names, got {describe(value)}")
    out = list(value)
    for item in out:
        if not isinstance(item, str):
            raise ValueError(f"{name} must contain names (str), got {describe(item)}")
    if not allow_empty and not out:
        raise ValueError(f"{name} is empty; expected at least one name")
    if unique:
        dup = sorted({n for n in out if out.count(n) > 1})
        if dup:
            raise ValueError(f"{name} names {dup} more than once")
    return out


def check_edges(name: str, value: Any) -> list[tuple[str, str]]:
    """A sequence of ``(parent, child)`` pairs of names."""
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Iterable):
        raise ValueError(f"{name} must be a sequence of (parent, child) pairs, got {describe(value)}")
    out = []
    for edge in value:
        if (
            isinstance(edge, (str, bytes))
            or not isinstance(edge, Sequence)
            or len(edge) != 2
            or not all(isinstance(e, str) for e in edge)
        ):
            raise ValueError(f"{name}: edge {edge!r} is not a (parent, child) pair of names")
        out.append((edge[0], edge[1]))
    return out


def check_keywords(name: str, value: Any, allowed: Iterable[str]) -> dict[str, Any]:
    """A mapping of keyword arguments whose keys are all in ``allowed`` (None means ``{}``)."""
    kwargs = dict(check_mapping(name, value, allow_none=True))
    allowed = sorted(allowed)
    unknown = sorted(str(k) for k in kwargs if k not in allowed)
    if unknown:
        raise ValueError(f"{name} has unknown keys {unknown}; expected some of {allowed}")
    return kwargs


def _kind_error(what: str, dtype: Any) -> ValueError:
    if isinstance(dtype, np.dtype) and dtype.kind in "USOV":
        return ValueError(f"{what} is not numeric: it has dtype {dtype}, expected floats")
    return ValueError(
        f"{what} has dtype {dtype}, expected a floating dtype (values of a continuous variable); "
        "convert it with .astype(float) or .float() if that is what you mean"
    )


def as_float_tensor(value: Any, what: str, dtype: torch.dtype | None = None) -> Tensor:
    """``value`` as a floating tensor of ``dtype`` (default: torch's default dtype).

    Floating tensors and arrays of any precision are converted (a tensor keeps its
    autograd graph); integer, bool, complex, string and object data are refused. Python
    numbers and nested lists of them are accepted. Finiteness is not checked here.

    Raises:
        ValueError: naming ``what`` and the dtype or type it got.
    """
    dtype = torch.get_default_dtype() if dtype is None else dtype
    if isinstance(value, Tensor):
        if not value.is_floating_point():
            raise _kind_error(what, value.dtype)
        return value if value.dtype == dtype else value.to(dtype)
    if _is_bool(value):
        raise ValueError(f"{what} is the bool {value!r}, expected a number or an array of floats")
    if isinstance(value, (np.ndarray, np.generic)):
        arr = np.asarray(value)
        if arr.dtype.kind != "f":
            raise _kind_error(what, arr.dtype)
        return torch.as_tensor(arr, dtype=dtype)
    if isinstance(value, numbers.Real):
        return torch.tensor(float(value), dtype=dtype)
    if isinstance(value, (list, tuple)):
        try:
            arr = np.asarray(value)
        except (ValueError, TypeError, RuntimeError) as err:
            raise ValueError(f"{what} is not a rectangular array of numbers: {err}") from None
        if arr.dtype.kind in "iu" and arr.size:
            arr = arr.astype(np.float64)  # Python ints in a list are numbers
        if arr.dtype.kind != "f" and arr.size:
            raise ValueError(f"{what} is not numeric: it holds {arr.dtype} entries ({describe(value)})")
        return torch.as_tensor(arr.astype(np.float64), dtype=dtype)
    raise ValueError(
        f"{what} is not numeric: expected a number, an array or a tensor of floats, got {describe(value)}"
    )


def as_float_array(value: Any, what: str) -> np.ndarray:
    """``value`` as a float64 numpy array, by the same rules as :func:`as_float_tensor`."""
    if isinstance(value, Tensor):
        value = value.detach().cpu()
        if not value.is_floating_point():
            raise _kind_error(what, value.dtype)
        return value.double().numpy()
    return as_float_tensor(value, what, torch.float64).numpy()


def check_finite_tensor(what: str, value: Tensor) -> Tensor:
    """Raise if ``value`` holds NaN or inf, saying how many entries and where the first is."""
    bad = ~torch.isfinite(value.detach())
    if bool(bad.any()):
        first = tuple(int(i) for i in torch.nonzero(bad)[0]) if value.ndim else ()
        raise ValueError(
            f"{what} contains {int(bad.sum())} NaN or inf entries"
            + (f" (first at index {first}: {float(value.detach()[first])})" if first else "")
            + "; expected finite values"
        )
    return value
