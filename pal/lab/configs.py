"""Experiment configurations: nested frozen dataclasses, overridden by dotted paths.

Every registered experiment has a frozen ``Config`` whose fields are plain values or nested
frozen sub-configs (protocol, fitting, action inference, ...). ``pal experiment NAME --set
protocol.fit.schedule.epochs=40`` reaches a nested field through :func:`override`, which parses
the value as JSON (a bare word stays a string), checks it against the field's annotation and
rebuilds every config on the path, so their ``__post_init__`` checks run again. A bare word
given to a tuple of strings is a one-entry tuple (``--set protocol.graphs=state``), and a path
through an option group that is None starts from that group's defaults
(``--set action.options.sampling.population=64`` turns the sampling stage on).

One declaration per setting, one vocabulary:

- **Options and configs.** ``*Options`` (and :class:`inference.FitSchedule`) are the frozen
  knobs of one algorithm, passed to one function of :mod:`inference` (``options=``,
  ``schedule=``, ``sampling=``); :class:`inference.SamplingConfig` keeps its older name.
  ``*Config`` are the trees of the agent and of the experiments. A config NESTS the option
  object it passes on (``PlanConfig(action=ActionOptions(sampling=SamplingConfig(...)))``,
  ``ModelConfig(schedule=FitSchedule(...))``, ``EstimateConfig(svi=SVIOptions(...))``) and
  passes it straight through; it never copies the option's fields one by one, and declares
  beside it only settings of its own. ``tests/pal/lab/test_config_settings.py`` holds this.
- **Counts** follow :mod:`inference`: ``num_steps`` (optimiser iterations), ``num_samples``
  (draws), ``num_particles``; a fit's passes stay ``epochs`` as in :class:`inference.FitSchedule`.
- **As a dict** is ``to_dict()`` (a method) or :func:`to_dict` (a config tree), never ``as_dict``.
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from collections.abc import Iterator
from typing import Any

from pal.checks import MAX_SEED

__all__ = [
    "MAX_INT",
    "MAX_VALUE_CHARS",
    "MAX_VALUE_DEPTH",
    "ConfigError",
    "apply_set",
    "find",
    "override",
    "parse_value",
    "to_dict",
    "walk",
]

#: Longest ``--set`` value text, characters.
MAX_VALUE_CHARS = 10_000
#: Deepest nesting of lists and objects in a ``--set`` value.
MAX_VALUE_DEPTH = 32
#: Largest magnitude of an int setting (a 64-bit integer: what numpy, torch and MuJoCo take).
MAX_INT = 2**63 - 1


class ConfigError(ValueError):
    """A configuration path or value that does not fit the experiment's config."""


def _is_config(obj: Any) -> bool:
    return dataclasses.is_dataclass(obj) and not isinstance(obj, type)


def to_dict(config: Any) -> dict[str, Any]:
    """The config as nested JSON-compatible dicts (tuples become lists)."""
    if not _is_config(config):
        raise ConfigError(f"expected a dataclass config, got {type(config).__name__}")

    def plain(v: Any) -> Any:
        if _is_config(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {str(k): plain(x) for k, x in v.items()}
        return v

    return plain(config)


def walk(config: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """Every ``(dotted path, value)`` of the config tree, sub-configs included."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        path = f"{prefix}{f.name}"
        yield path, value
        if _is_config(value):
            yield from walk(value, f"{path}.")


def find(config: Any, cls: type) -> list[str]:
    """Dotted paths of every field holding an instance of ``cls`` (the root is ``""``)."""
    paths = [""] if isinstance(config, cls) else []
    return paths + [p for p, v in walk(config) if isinstance(v, cls)]


def parse_value(raw: str) -> Any:
    """``--set`` value text: JSON (``3``, ``0.5``, ``[1, 2]``, ``null``, ``true``) or else the bare string.

    The text may hold at most :data:`MAX_VALUE_CHARS` characters and nest lists and objects
    at most :data:`MAX_VALUE_DEPTH` deep.

    Raises:
        ConfigError: a longer or deeper value, or a number of more than 4300 digits.
    """
    if len(raw) > MAX_VALUE_CHARS:
        raise ConfigError(f"value {raw[:20]!r}... has {len(raw)} characters; the limit is {MAX_VALUE_CHARS}")
    depth = _nesting(raw)
    if depth > MAX_VALUE_DEPTH:
        raise ConfigError(f"value {raw[:20]!r}... nests {depth} levels deep; the limit is {MAX_VALUE_DEPTH}")
    try:
        return json.loads(raw)
    except json.JSONDecodeError:
        return raw
    except ValueError as err:  # an int past Python's digit limit
        raise ConfigError(f"value {raw[:20]!r}...: {err}") from None


def _nesting(raw: str) -> int:
    """The deepest nesting of ``[`` and ``{`` in ``raw``, outside JSON strings."""
    deepest = depth = 0
    in_string = escaped = False
    for ch in raw:
        if in_string:
            escaped, in_string = (False, True) if escaped else (ch == "\\", ch != '"')
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, where: str) -> Any:
    """``value`` checked against annotation ``tp`` (int -> float and list -> tuple allowed)."""
    origin = typing.get_origin(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        for option in typing.get_args(tp):
            try:
                return _coerce(value, option, where)
            except ConfigError:
                continue  # try the next member of the union
        raise ConfigError(f"{where}: {value!r} is not a {_type_name(tp)}")
    if tp is type(None):
        if value is None:
            return None
        raise ConfigError(f"{where}: {value!r} is not None")
    if origin is typing.Literal:
        if value in typing.get_args(tp):
            return value
        raise ConfigError(f"{where}: {value!r} is not one of {list(typing.get_args(tp))}")
    if origin is tuple:
        args = typing.get_args(tp)
        if isinstance(value, str) and len(args) == 2 and args[1] is Ellipsis and args[0] is str:
            return (value,)  # a bare word for a tuple of strings: one entry
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: {value!r} is not a list; write it as JSON, e.g. [1, 2]")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise ConfigError(f"{where}: {value!r} has {len(value)} entries, expected {len(args)}")
        return tuple(_coerce(v, a, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True)))
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: {value!r} is not true or false")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            if not -MAX_INT <= value <= MAX_INT:
                raise ConfigError(f"{where}: {value} is out of range; an int setting is within ±(2**63 - 1)")
            return value
        raise ConfigError(f"{where}: {value!r} is not an int")
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise ConfigError(f"{where}: {value!r} is not a number")
    if tp is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"{where}: {value!r} is not a string")
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        raise ConfigError(
            f"{where} is a group of settings; set one of its fields, e.g. {where}.<field>=VALUE"
        )
    return value


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _default_group(tp: Any) -> Any:
    """The default instance of the dataclass in an optional annotation (``X | None``), else None."""
    options = typing.get_args(tp) if typing.get_origin(tp) in (typing.Union, types.UnionType) else (tp,)
    groups = [t for t in options if isinstance(t, type) and dataclasses.is_dataclass(t)]
    return groups[0]() if len(groups) == 1 else None


def override(config: Any, path: str, value: Any) -> Any:
    """A copy of ``config`` with the field at dotted ``path`` set to ``value``.

    Args:
        config: a frozen dataclass config.
        path: e.g. ``"seed"`` or ``"protocol.fit.schedule.epochs"``.
        value: the new value (already parsed, see :func:`parse_value`).

    Raises:
        ConfigError: an unknown path, a value that does not fit the field's type, or a
            ``seed`` outside ``[0, MAX_SEED]`` (``pal.checks.MAX_SEED``); the message names
            the path, the value and the choices.
        ValueError: the config's own checks refuse the new value.
    """
    if not _is_config(config):
        raise ConfigError(f"expected a dataclass config, got {type(config).__name__}")
    head, _, rest = path.partition(".")
    names = [f.name for f in dataclasses.fields(config)]
    if head not in names:
        raise ConfigError(f"unknown setting {path!r}; {type(config).__qualname__} has {names}")
    current = getattr(config, head)
    if rest and current is None:
        current = _default_group(_hints(type(config))[head])
    if rest:
        if not _is_config(current):
            raise ConfigError(f"{head!r} is a value, not a group of settings; cannot set {path!r}")
        new = override(current, rest, value)
    else:
        new = _coerce(value, _hints(type(config))[head], head)
        if head == "seed" and isinstance(new, int) and not 0 <= new <= MAX_SEED:
            raise ConfigError(f"seed must be an int in [0, {MAX_SEED}], got {new}")
    return dataclasses.replace(config, **{head: new})


def apply_set(config: Any, item: str) -> Any:
    """``config`` with one ``--set KEY=VALUE`` item applied (:func:`parse_value`, :func:`override`).

    Raises:
        ConfigError: a malformed item, or a value refused by :func:`parse_value` or
            :func:`override`; the message starts with the item.
        ValueError: the config's own checks refuse the value; the message starts with the item.
    """
    key, sep, raw = item.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"--set {item!r}: expected KEY=VALUE, e.g. --set seed=1")
    shown = item if len(item) <= 60 else f"{item[:60]}..."
    try:
        return override(config, key.strip(), parse_value(raw))
    except ConfigError as err:
        raise ConfigError(f"--set {shown!r}: {err}") from None
    except ValueError as err:
        if type(err) is not ValueError:
            raise
        raise ValueError(f"--set {shown!r}: {err}") from None
