"""The MuJoCo bodies shipped with pal, and loading of any MJCF file with clear errors.

Bodies are package data (``pal/sim/assets/*.xml``) and load through
:mod:`importlib.resources`, never relative to the working directory:

- ``finger``: a hand with the lumped finger joint of MIMo's left hand (thesis §5.2), one motor.
- ``arm``: shoulder (3), elbow, wrist (3) and finger, 8 motors, gravity on.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import mujoco

__all__ = ["BODIES", "LoadedModel", "MJCFError", "body_path", "load_body", "load_model"]

#: Names of the bodies shipped as package data.
BODIES: tuple[str, ...] = ("finger", "arm")


class MJCFError(ValueError):
    """An MJCF file is missing, unreadable or rejected by MuJoCo's compiler."""


@dataclass(frozen=True)
class LoadedModel:
    """A compiled model with its provenance.

    Attributes:
        model: the compiled ``mujoco.MjModel``.
        name: body name (``"finger"``, ``"arm"``) or the file stem of a custom MJCF file.
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


def load_model(source: str | os.PathLike[str]) -> LoadedModel:
    """Compile a shipped body (by name) or any MJCF file (by path).

    Args:
        source: a name in :data:`BODIES` or a path to an MJCF ``.xml`` file.

    Returns:
        :class:`LoadedModel` with the model, its name, path and file hash.

    Raises:
        MJCFError: the file does not exist, cannot be read, or MuJoCo rejects it; the
            message names the path and carries MuJoCo's own error.
    """
    if _is_body_name(source):
        path, name = body_path(str(source)), str(source)
    else:
        path = Path(source)
        name = path.stem
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
    return LoadedModel(model=model, name=name, path=path, sha256=hashlib.sha256(blob).hexdigest())


def load_body(name: str) -> mujoco.MjModel:
    """Compile a shipped body.

    Args:
        name: one of :data:`BODIES`.

    Returns:
        The compiled ``mujoco.MjModel``.
    """
    return load_model(body_path(name)).model
