"""Camera calibration of recorded frames: intrinsics K and depth scale, given or read from a file.

Readers of recorded RGB-D frames (:mod:`pal.perception.folders`, :mod:`pal.perception.tum`)
never assume a camera. The intrinsics and the depth scale (metres per stored depth unit) are
either passed by the caller or read from ``calibration.json`` next to the frames::

    {"fx": 520.9, "fy": 521.0, "cx": 325.1, "cy": 249.7,   # or "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
     "depth_scale": 0.0002,                                 # metres per unit (TUM: 1/5000, Kinect: 0.001)
     "fps": 30.0,                                           # optional: frame rate when there are no timestamps
     "distortion": [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]}  # optional: OpenCV k1, k2, p1, p2[, k3]

With distortion coefficients (given or in the file), the readers undistort every frame onto the
pinhole image of the same K (:mod:`pal.perception.undistort`).

Arguments given to the reader override the file. Without either, the reader raises
:class:`~pal.io.sequence_files.SequenceError` naming what is missing and how to give it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pal.frames import check_intrinsics
from pal.io.files import FileFormatError, read_json
from pal.io.sequence_files import SequenceError
from pal.perception.undistort import check_distortion

__all__ = ["CALIBRATION_FILE", "Calibration", "intrinsics_matrix", "resolve_calibration"]

#: Name of the calibration file that readers look for next to the frames.
CALIBRATION_FILE = "calibration.json"


@dataclass(frozen=True, eq=False)
class Calibration:
    """A recording's camera.

    Attributes:
        K: (3, 3) float64 intrinsics, pixels.
        depth_scale: metres per stored depth unit (> 0).
        fps: frame rate, frames/s, or None when the recording has its own timestamps.
        source: where the values came from (``"arguments"``, the calibration file, or both).
        distortion: (4,), (5,) or (8,) float64 OpenCV lens coefficients ``k1, k2, p1, p2[, k3]``,
            or None for a pinhole camera (frames are used as recorded).
    """

    K: np.ndarray
    depth_scale: float
    fps: float | None
    source: str
    distortion: np.ndarray | None = None


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The (3, 3) pinhole matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (pixels), checked."""
    return check_intrinsics(np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64))


def _read_file(path: Path) -> dict[str, Any]:
    try:
        data = read_json(path)
    except FileFormatError as err:
        raise SequenceError(f"{path}: {err}") from err
    if not isinstance(data, dict):
        raise SequenceError(f"{path} holds {type(data).__name__}, expected a JSON object")
    return data


def _file_K(path: Path, data: dict[str, Any]) -> np.ndarray | None:
    try:
        if "K" in data:
            return check_intrinsics(np.asarray(data["K"], dtype=np.float64), "K")
        names = ("fx", "fy", "cx", "cy")
        if any(n in data for n in names):
            missing = [n for n in names if n not in data]
            if missing:
                raise ValueError(f"has {sorted(set(names) & set(data))} but lacks {missing}")
            return intrinsics_matrix(*(float(data[n]) for n in names))
    except (TypeError, ValueError) as err:
        raise SequenceError(f"{path}: intrinsics {err}") from None
    return None


def _positive(name: str, value: Any, where: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SequenceError(f"{where}: {name} is {value!r}, expected a number > 0") from None
    if not (math.isfinite(v) and v > 0):
        raise SequenceError(f"{where}: {name} is {value!r}, expected a finite number > 0")
    return v


def resolve_calibration(
    directory: Path,
    K: np.ndarray | None,
    depth_scale: float | None,
    fps: float | None = None,
    *,
    distortion: object = None,
    scale_hint: str = "",
) -> Calibration:
    """The camera of the frames in ``directory``: the arguments, else ``calibration.json``.

    Args:
        directory: the recording's directory.
        K: (3, 3) intrinsics, or None to read them from the file.
        depth_scale: metres per depth unit, or None to read it from the file.
        fps: frame rate, frames/s, or None (read from the file if it has one).
        distortion: OpenCV lens coefficients ``k1, k2, p1, p2[, k3]``, or None to read them from
            the file's ``"distortion"`` (absent: a pinhole camera).
        scale_hint: a sentence added to the error when the depth scale is missing (e.g. the
            format's usual scale).

    Raises:
        SequenceError: intrinsics or depth scale neither given nor in the file, the file is
            malformed, or a value is invalid (depth_scale <= 0, focal lengths <= 0, distortion
            not 4, 5 or 8 finite numbers, ...).
    """
    path = directory / CALIBRATION_FILE
    data = _read_file(path) if path.is_file() else {}
    sources = []
    if K is not None:
        try:
            K = check_intrinsics(K)
        except ValueError as err:
            raise SequenceError(f"{directory}: {err}") from None
        sources.append("arguments")
    else:
        K = _file_K(path, data)
        if K is None:
            raise SequenceError(
                f"{directory}: the camera intrinsics are unknown. Pass K=[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] "
                f'(pixels), or write {CALIBRATION_FILE} next to the frames with {{"fx", "fy", "cx", "cy", '
                '"depth_scale"}; there is no default camera'
            )
        sources.append(CALIBRATION_FILE)
    if depth_scale is not None:
        scale = _positive("depth_scale", depth_scale, str(directory))
        sources.append("arguments")
    elif "depth_scale" in data:
        scale = _positive("depth_scale", data["depth_scale"], str(path))
        sources.append(CALIBRATION_FILE)
    else:
        raise SequenceError(
            f"{directory}: the depth scale is unknown. Pass depth_scale= (metres per stored unit: 0.001 for "
            f'millimetres, 0.0002 for TUM\'s 5000 units per metre), or add "depth_scale" to {CALIBRATION_FILE}. '
            + scale_hint
        )
    if fps is None and "fps" in data:
        fps = _positive("fps", data["fps"], str(path))
    elif fps is not None:
        fps = _positive("fps", fps, str(directory))
    lens = _distortion(distortion, data, directory, path)
    return Calibration(K, scale, fps, " + ".join(dict.fromkeys(sources)), lens)


def _distortion(given: object, data: dict[str, Any], directory: Path, path: Path) -> np.ndarray | None:
    """The lens coefficients given, else the file's ``"distortion"``, else None; checked."""
    value, where = (given, str(directory)) if given is not None else (data.get("distortion"), str(path))
    if value is None:
        return None
    try:
        return check_distortion(value)
    except ValueError as err:
        raise SequenceError(f"{where}: {err}") from None
