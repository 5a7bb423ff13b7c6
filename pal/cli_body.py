"""Body and dataset options of ``pal babble``, ``pal experiment`` and ``pal bench``.

``--body finger|arm | --mjcf PATH``, ``--name NAME``, ``--joint J``, ``--actuator A ...``,
``--frame-skip N``, ``--action-range A=LOW,HIGH ...``, ``--effective-range`` and
``--dataset DIR``: the flags, and their translation into ``--set`` paths of a config's
:class:`~pal.experiments.world_model.body.BodyChoice` and :class:`~pal.experiments.world_model.data.DataConfig`.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

__all__ = [
    "BODY_FLAGS",
    "UsageError",
    "UsageParser",
    "action_ranges",
    "add_body_flags",
    "body_fields",
    "check_data",
]

#: ``pal experiment|bench`` body flags -> field of the config's body choice, in the order they are set.
BODY_FLAGS = {
    "body": "body",
    "mjcf": "mjcf",
    "body_name": "name",
    "frame_skip": "frame_skip",
    "joint": "joint",
    "actuator": "actuator",
    "action_range": "action_range",
    "effective_range": "effective_range",
}


class UsageError(Exception):
    """A command line that cannot be run; printed as one line, exit status 2."""


class UsageParser(argparse.ArgumentParser):
    """argparse with one-line errors."""

    def error(self, message: str) -> NoReturn:
        """Raise the message as one :class:`UsageError` line instead of printing usage."""
        raise UsageError(f"{self.prog}: {message}")


def action_ranges(texts: Sequence[str] | None) -> tuple[tuple[str, float, float], ...]:
    """``--action-range NAME=LOW,HIGH`` texts as ``(name, low, high)`` triples."""
    from pal.sim.ranges import parse_action_range

    try:
        return tuple(parse_action_range(t) for t in texts or ())
    except ValueError as err:
        raise UsageError(f"--action-range: {err}") from None


def body_fields(entry: Any, args: argparse.Namespace) -> dict[str, Any]:
    """The body and dataset flags as ``--set`` paths, applied in this order.

    A new body (``--body``/``--mjcf``) first clears the joint, actuators and action ranges of
    the old one that no flag replaces; the body comes before the joint, actuators and ranges,
    which are checked against it.
    """
    from pal.experiments.world_model.data import BodyChoice, DataConfig
    from pal.lab import configs

    given = {flag: getattr(args, flag, None) for flag in BODY_FLAGS}
    given = {k: (tuple(v) if isinstance(v, list) else v) for k, v in given.items() if v is not None}
    if "body" in given and "mjcf" in given:
        raise UsageError("give either --body or --mjcf, not both")
    if "joint" in given:
        if len(given["joint"]) != 1:
            raise UsageError(
                f"--joint given {len(given['joint'])} times {list(given['joint'])}; name the one joint to analyse"
            )
        given["joint"] = given["joint"][0]
    if "action_range" in given:
        given["action_range"] = action_ranges(given["action_range"])
    if "mjcf" in given:  # stored in the run's config as an absolute, resolved path
        given["mjcf"] = str(Path(given["mjcf"]).expanduser().resolve())
    dataset = getattr(args, "dataset", None)
    if not given and dataset is None:
        return {}
    default = entry.default()
    fields: dict[str, Any] = {}
    if given:
        paths = configs.find(default, BodyChoice)
        if len(paths) != 1:
            flags = ", ".join("--" + BODY_FLAGS[k].replace("_", "-") for k in given)
            found = f" (it has {paths})" if paths else ""
            raise UsageError(f"{flags}: pal {entry.kind} {entry.name} has no body setting{found}")
        prefix = f"{paths[0]}." if paths[0] else ""
        if "body" in given or "mjcf" in given:  # settings of the old body that no flag replaces
            cleared = {"joint": None, "actuator": None, "action_range": ()}
            fields.update({f"{prefix}{k}": v for k, v in cleared.items() if k not in given})
            if "body" in given:
                fields[f"{prefix}mjcf"] = None
        fields.update({f"{prefix}{BODY_FLAGS[k]}": given[k] for k in BODY_FLAGS if k in given})
    if dataset is not None:
        paths = configs.find(default, DataConfig)
        if len(paths) != 1:
            raise UsageError(f"--dataset: pal {entry.kind} {entry.name} has no dataset setting")
        fields[f"{paths[0]}.dataset" if paths[0] else "dataset"] = dataset
    return fields


def check_data(kind: str, name: str, config: Any) -> None:
    """Refuse a dataset choice that cannot be analysed, before the run starts."""
    from pal.experiments.world_model.data import DataConfig
    from pal.lab import configs

    for _, data in configs.walk(config):
        if isinstance(data, DataConfig):
            try:
                data.check()
            except ValueError as err:
                raise UsageError(f"pal {kind} {name}: {err}") from None


def add_body_flags(p: argparse.ArgumentParser, *, babble: bool) -> None:
    """Add the body flags to ``p`` (``babble``: recording defaults, several ``--joint``)."""
    p.add_argument("--body", default=None, help="shipped body: finger (default) or arm")
    p.add_argument("--mjcf", default=None, metavar="PATH", help="any MJCF file instead of a shipped body")
    p.add_argument(
        "--name",
        dest="body_name",
        default=None,
        help="the body's name in reports and caches (default: the model's)",
    )
    if babble:
        p.add_argument(
            "--joint", action="append", metavar="NAME", help="record this joint (repeatable; default all)"
        )
    else:
        p.add_argument("--joint", action="append", metavar="NAME", help="joint to analyse")
    p.add_argument(
        "--actuator",
        action="append",
        metavar="NAME",
        help="babble this actuator (repeatable; default all that drive a recorded joint)",
    )
    p.add_argument(
        "--frame-skip",
        type=int,
        default=50 if babble else None,
        help="MuJoCo steps per transition (default 50)",
    )
    p.add_argument(
        "--action-range",
        action="append",
        metavar="NAME=LOW,HIGH",
        help="babble actuator NAME over [LOW, HIGH] inside its ctrlrange (repeatable)",
    )
    p.add_argument(
        "--effective-range",
        action="store_true",
        default=False if babble else None,
        help="babble over the effective ranges found by a short probe run",
    )
