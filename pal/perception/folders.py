"""Folders of RGB-D image files: ``1.png`` + ``1_depth.png``, ``1-color.png`` + ``1-depth.png``, ``color/`` + ``depth/``.

The naming patterns are :class:`pal.perception.folder_layouts.FolderLayout` s; the built-in
ones (``paired``, ``dashed``, ``subfolders``, ``rgb-subfolders``) are tried when none is given,
and a user's own is passed as ``layout=``. Colour and depth stems must pair one to one.

Frames are ordered by stem (numerically when every stem is an integer). Colour files are
8-bit (PNG, JPEG, ...), read as RGB; depth files are 16-bit PNG or binary PGM (0 = invalid),
scaled by ``depth_scale`` metres per unit.

The camera is never assumed: intrinsics and depth scale come from the arguments or from
``calibration.json`` next to the frames (:mod:`pal.perception.calibration`). Timestamps come
from ``timestamps.txt`` (``<stem> <seconds>`` rows) when present, else from ``fps``
(``index / fps``); stills with neither are numbered 0, 1, 2, ... s and marked ``timed=False``.
Camera poses, when the folder has them, are read from ``pose.txt`` (one ``tx ty tz qx qy qz
qw`` row per frame, camera-to-world, the convention of the TUM ground truth) by
:meth:`FolderSequence.camera_poses`.

On opening, the first depth image is checked against the stated scale
(:func:`pal.frames.check_depth_range` warns when the range is implausible and names the fix).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pal.frames import RGBDFrame, check_depth_range
from pal.io.sequence_files import (
    CameraPoses,
    FrameSequence,
    SequenceError,
    check_timestamps,
    read_depth,
    read_image,
    read_text_rows,
    resolve_inside,
)
from pal.perception.calibration import resolve_calibration
from pal.perception.folder_layouts import (
    COLOR_EXTENSIONS,
    DEPTH_EXTENSIONS,
    LAYOUTS,
    FolderLayout,
    find_layout,
    layout_named,
    paired_frames,
)
from pal.perception.undistort import Undistortion

__all__ = [
    "COLOR_EXTENSIONS",
    "DEPTH_EXTENSIONS",
    "FolderLayout",
    "FolderSequence",
    "find_folder_layout",
    "pose_matrices",
]


def find_folder_layout(path: Path) -> tuple[str, list[tuple[str, Path, Path]]] | None:
    """The built-in layout of ``path`` and its ``(stem, colour file, depth file)`` frames, or None.

    Returns:
        ``(layout name, frames)`` in frame order (:mod:`pal.perception.folder_layouts`), or None
        when no built-in layout pairs any file.

    Raises:
        SequenceError: the best layout leaves colour or depth files unpaired.
    """
    layout = find_layout(path)
    return None if layout is None else (layout.name, paired_frames(path, layout))


def pose_matrices(values: np.ndarray, source: str) -> np.ndarray:
    """(N, 4, 4) camera-to-world transforms from (N, 7) ``tx ty tz qx qy qz qw`` rows (metres).

    Raises:
        SequenceError: not (N, 7), a non-finite value or a zero quaternion (the row is named).
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 7:
        raise SequenceError(f"{source}: poses have shape {v.shape}, expected (N, 7) 'tx ty tz qx qy qz qw'")
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1) | (np.linalg.norm(v[:, 3:], axis=1) < 1e-9))
    if bad.size:
        raise SequenceError(f"{source}: pose row {int(bad[0]) + 1} {v[bad[0]].tolist()} is not a valid pose")
    out = np.tile(np.eye(4), (v.shape[0], 1, 1))
    out[:, :3, :3] = Rotation.from_quat(v[:, 3:]).as_matrix()
    out[:, :3, 3] = v[:, :3]
    return out


class FolderSequence(FrameSequence):
    """A folder of colour and depth image files (module docstring).

    Args:
        path: the directory.
        K: (3, 3) intrinsics, pixels; None: read from ``calibration.json``.
        depth_scale: metres per depth unit; None: read from ``calibration.json``.
        fps: frame rate for timestamps ``index / fps`` when there is no ``timestamps.txt``;
            None: stills, numbered 0, 1, 2, ... s (``timed`` is False).
        layout: a :class:`FolderLayout` or a built-in layout's name; None: the built-in layout
            that pairs the most files.

    Attributes:
        layout: the layout's name, e.g. ``"paired"``, ``"dashed"`` or ``"subfolders"``.
        stems: the frames' file stems, in frame order.
        depth_scale: metres per depth unit.
        timed: False when the timestamps are frame numbers (no ``timestamps.txt``, no fps).
        undistortion: the lens correction of ``calibration.json``'s ``"distortion"`` applied to
            every frame, or None.

    Raises:
        SequenceError: not a folder of frames, a layout that matches nothing, colour and depth
            counts that differ, no intrinsics or depth scale, malformed ``timestamps.txt`` or
            non-monotonic timestamps.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        K: np.ndarray | None = None,
        depth_scale: float | None = None,
        fps: float | None = None,
        layout: str | FolderLayout | None = None,
    ) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise SequenceError(f"sequence directory {self.path} does not exist or is not a directory")
        chosen = find_layout(self.path) if layout is None else layout_named(layout)
        if chosen is None:
            patterns = "; ".join(f"{x.name!r} ({x.describe()})" for x in LAYOUTS)
            raise SequenceError(
                f"{self.path} holds no colour/depth image pairs of a built-in layout: expected one of "
                f"{patterns} (or pass layout=FolderLayout(...) for another naming pattern)"
            )
        frames = paired_frames(self.path, chosen)
        self.layout = chosen.name
        calib = resolve_calibration(self.path, K, depth_scale, fps)
        self.K, self.depth_scale, self.calibration_source = calib.K, calib.depth_scale, calib.source
        self.undistortion = None if calib.distortion is None else Undistortion(calib.K, calib.distortion)
        self.stems = [s for s, _, _ in frames]
        where = str(self.path)
        self._files = [
            (resolve_inside(self.path, c, where), resolve_inside(self.path, d, where)) for _, c, d in frames
        ]
        self.timed = True
        self.timestamps = self._timestamps(calib.fps)
        check_depth_range(
            read_image(self._files[0][1], depth=True),
            self.depth_scale,
            source=str(self._files[0][1]),
            stacklevel=3,
        )

    def _timestamps(self, fps: float | None) -> np.ndarray:
        path = self.path / "timestamps.txt"
        if path.is_file():
            rows = read_text_rows(path)
            stamps = {r[0]: r[1] for r in rows if len(r) == 2}
            missing = [s for s in self.stems if s not in stamps]
            if missing or len(stamps) != len(rows):
                raise SequenceError(
                    f"{path}: expected one '<stem> <seconds>' row per frame; no time for {missing[:5]}"
                )
            try:
                ts = np.array([float(stamps[s]) for s in self.stems])
            except ValueError as err:
                raise SequenceError(f"{path}: a timestamp is not a number ({err})") from None
            return check_timestamps(ts, str(path))
        if fps is None:
            self.timed = False
            return np.arange(len(self.stems), dtype=np.float64)
        return np.arange(len(self.stems), dtype=np.float64) / fps

    def frame(self, index: int) -> RGBDFrame:
        """Frame ``index``: the colour file as RGB, the depth file in metres.

        Raises:
            SequenceError: a file is missing or unreadable, or colour and depth differ in size.
            pal.frames.EmptyDepthError: the depth image has no valid pixel.
        """
        color_file, depth_file = self._files[index]
        rgb = read_image(color_file)
        depth = read_depth(depth_file, self.depth_scale)
        if rgb.shape[:2] != depth.shape:
            raise SequenceError(
                f"{color_file.name} is {rgb.shape[1]}x{rgb.shape[0]} but {depth_file.name} is "
                f"{depth.shape[1]}x{depth.shape[0]}; colour and depth must be registered at the same size"
            )
        if self.undistortion is not None:  # calibration.json's lens coefficients
            rgb, depth = self.undistortion(rgb, depth)
        return RGBDFrame(rgb=rgb, depth=depth, K=self.K, timestamp=float(self.timestamps[index]))

    def camera_poses(self) -> CameraPoses:
        """Camera-to-world poses from ``pose.txt``, one row per frame, all valid.

        Raises:
            SequenceError: the folder has no ``pose.txt``, or it has another number of rows.
        """
        path = self.path / "pose.txt"
        if not path.is_file():
            raise SequenceError(f"{self.path} has no camera poses (pose.txt)")
        rows = read_text_rows(path)
        if len(rows) != len(self):
            raise SequenceError(f"{path} has {len(rows)} rows, expected one per frame ({len(self)})")
        try:
            values = np.array(rows, dtype=np.float64)
        except ValueError:
            raise SequenceError(f"{path}: expected rows of 7 numbers 'tx ty tz qx qy qz qw'") from None
        return CameraPoses(pose_matrices(values, str(path)), np.ones(len(self), dtype=bool))
