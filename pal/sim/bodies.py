"""The MuJoCo bodies shipped with pal, and loading of any MJCF file with clear errors.

Bodies are package data (``pal/sim/assets/*.xml``) and load through
:mod:`importlib.resources`, never relative to the working directory:

- ``finger``: a hand with the lumped finger joint of MIMo's left hand (thesis §5.2), one motor.
- ``arm``: shoulder (3), elbow, wrist (3) and finger, 8 motors, gravity on.

A body's name is the model's own (``<mujoco model="...">``) unless the caller gives one;
only a file whose model has no name falls back to its file stem. Names of bodies, joints and
actuators follow :func:`check_name`, the rule of the world model's variable names.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import mujoco

__all__ = ["BODIES", "LoadedModel", "MJCFError", "body_path", "check_name", "load_body", "load_model"]

#: Names of the bodies shipped as package data.
BODIES: tuple[str, ...] = ("finger", "arm")

#: The name MuJoCo gives a model without a ``model`` attribute.
_UNNAMED_MODEL = "MuJoCo Model"


class MJCFError(ValueError):
    """An MJCF file is missing, unreadable or rejected by MuJoCo's compiler."""


def check_name(what: str, name: Any) -> str:
    """``name`` if it is a usable name of a body, joint or actuator, else ``ValueError``.

    The rule is that of :class:`models.variables.Variable` names: a non-empty string of
    printable characters without leading or trailing whitespace. ``:``, ``/``, ``-``, dots
    and inner spaces are allowed (``robot:left_fingers``, ``arm/elbow``, ``joint 1``).
    """
    if not isinstance(name, str):
        raise ValueError(f"{what} must be a string, got {name!r} ({type(name).__name__})")
    if not name or not name.isprintable() or name != name.strip():
        raise ValueError(
            f"{what} {name!r} is not a usable name; expected a non-empty string of printable "
            "characters without leading or trailing whitespace (e.g. 'arm/elbow')"
        )
    return name


@dataclass(frozen=True)
class LoadedModel:
    """A compiled model with its provenance.

    Attributes:
        model: the compiled ``mujoco.MjModel``.
        name: body name: the caller's, else the model's ``<mujoco model="...">``, else the
            file stem (only for a model without a name).
        path: the MJCF file it was compiled from.
        sha256: SHA-256 hex digest of the MJCF file's bytes.
    """

    model: mujoco.MjModel
    name: str
    path: Path
    sha256: str


def body_path(name: str) -> Path:
    """Path of a shipped body's MJCF file.

    Args:
        name: one of :data:`BODIES`.

    Raises:
        ValueError: unknown body name.
    """
    if name not in BODIES:
        raise ValueError(f"unknown body {name!r}; available bodies: {list(BODIES)}")
    ref = resources.files("pal.sim").joinpath("assets", f"{name}.xml")
    path = Path(str(ref))
    if not path.is_file():  # pragma: no cover - only for a broken installation
        raise MJCFError(f"body {name!r} is missing from the installed package: {path} does not exist")
    return path


def _is_body_name(source: str | os.PathLike[str]) -> bool:
    return isinstance(source, str) and source in BODIES and not source.endswith(".xml")


def source_path(source: str | os.PathLike[str]) -> Path:
    """The MJCF file of a shipped body name or a path (not checked for existence)."""
    return body_path(str(source)) if _is_body_name(source) else Path(source)


def model_name(model: mujoco.MjModel) -> str | None:
    """The model's own name (``<mujoco model="...">``), or None when it has none."""
    raw = bytes(model.names).split(b"\0", 1)[0].decode("utf-8", errors="replace")
    return None if raw in ("", _UNNAMED_MODEL) else raw


def load_model(source: str | os.PathLike[str], *, name: str | None = None) -> LoadedModel:
    """Compile a shipped body (by name) or any MJCF file (by path).

    Args:
        source: a name in :data:`BODIES` or a path to an MJCF ``.xml`` file.
        name: the body's name in reports, caches and dataset metadata (default: the
            model's own name, see :class:`LoadedModel`).

    Returns:
        :class:`LoadedModel` with the model, its name, path and file hash.

    Raises:
        MJCFError: the file does not exist, cannot be read, or MuJoCo rejects it; the
            message names the path and carries MuJoCo's own error.
        ValueError: ``name`` (or the model's name) breaks :func:`check_name`.
    """
    if name is not None:
        check_name("body name", name)
    path = source_path(source)
    if not path.is_file():
        hint = f" (or a body name from {list(BODIES)})" if isinstance(source, str) else ""
        raise MJCFError(f"MJCF file {str(path)!r} does not exist; pass an existing .xml path{hint}")
    try:
        blob = path.read_bytes()
    except OSError as err:
        raise MJCFError(f"cannot read MJCF file {str(path)!r}: {err}") from None
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:  # MuJoCo's parser and compiler errors
        message = str(err).strip().replace("\n", " ")
        raise MJCFError(f"MuJoCo cannot load MJCF file {str(path)!r}: {message}") from None
    if name is None:
        own = model_name(model)
        name = check_name(f"the model name of {str(path)!r} (override it with --name)", own or path.stem)
    # the absolute, resolved path: dataset metadata and reports name the file wherever they are read
    return LoadedModel(model=model, name=name, path=path.resolve(), sha256=hashlib.sha256(blob).hexdigest())


def load_body(name: str) -> mujoco.MjModel:
    """Compile a shipped body.

    Args:
        name: one of :data:`BODIES`.

    Returns:
        The compiled ``mujoco.MjModel``.
    """
    return load_model(body_path(name)).model
