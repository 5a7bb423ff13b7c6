"""Reading recorded RGB-D sequences: the ``pal`` layout and :func:`open_sequence` for any layout.

The ``pal`` layout and its writer are defined in :mod:`pal.io.sequence_files` (shared with
:mod:`pal.sim.recording`); this module reads it as :class:`RecordedSequence`. The TUM RGB-D
layout is read by :mod:`pal.perception.tum`, folders of image files (``1.png`` +
``1_depth.png``, or ``color/`` + ``depth/``) by :mod:`pal.perception.folders`;
:func:`open_sequence` picks the reader from the directory's contents. The layout's names are
re-exported here.

Every reader returns RGB frames (channel order red, green, blue) with depth in metres, and
none assumes a camera: the ``pal`` layout stores its intrinsics and depth scale, the others
take them as arguments or from ``calibration.json`` (:mod:`pal.perception.calibration`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from pal.frames import RGBDFrame, check_intrinsics
from pal.io.files import FileFormatError, read_json, read_npz
from pal.io.sequence_files import (
    FORMAT,
    POSES_FORMAT,
    FrameSequence,
    SequenceError,
    SequenceWriter,
    check_timestamps,
    decode_depth,
    encode_depth,
    read_depth,
    read_image,
    read_text_rows,
)
from pal.perception.folders import FolderSequence, find_folder_layout
from pal.perception.tum import TUMSequence

__all__ = [
    "FORMAT",
    "FolderSequence",
    "FrameSequence",
    "RecordedSequence",
    "SequenceError",
    "SequenceWriter",
    "decode_depth",
    "encode_depth",
    "open_sequence",
    "read_image",
]

_OLD_FORMATS = ("pal.rgbd-sequence/1",)


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise SequenceError(f"{path} does not exist; {path.parent} is not a complete pal sequence")
    try:
        data = read_json(path)
    except FileFormatError as err:
        raise SequenceError(str(err)) from err
    if not isinstance(data, dict):
        raise SequenceError(f"{path} holds {type(data).__name__}, expected a JSON object")
    return data


class RecordedSequence(FrameSequence):
    """Reader of the ``pal`` layout (module docstring).

    Args:
        path: the sequence directory.

    Raises:
        SequenceError: the directory is missing or incomplete, a file is unreadable, or the
            metadata disagree (frame count, intrinsics, depth scale).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise SequenceError(f"sequence directory {self.path} does not exist or is not a directory")
        info = _read_json(self.path / "sequence.json")
        if info.get("format") in _OLD_FORMATS:
            raise SequenceError(
                f"{self.path / 'sequence.json'}: format {info.get('format')!r} is an older layout; "
                f"record the sequence again (this version reads {FORMAT!r})"
            )
        if info.get("format") != FORMAT:
            raise SequenceError(
                f"{self.path / 'sequence.json'}: format {info.get('format')!r}, expected {FORMAT!r}"
            )
        intr = _read_json(self.path / "intrinsics.json")
        try:
            self.K = check_intrinsics(
                np.asarray(intr.get("K"), dtype=np.float64) if intr.get("K") is not None else None
            )
        except ValueError as err:
            raise SequenceError(f"{self.path / 'intrinsics.json'}: {err}") from None
        self.depth_scale = float(info.get("depth_scale", 0))
        if not self.depth_scale > 0:
            raise SequenceError(
                f"{self.path / 'sequence.json'}: depth_scale {info.get('depth_scale')!r}, expected > 0"
            )
        try:
            self.width, self.height, n = int(info["width"]), int(info["height"]), int(info["num_frames"])
        except (KeyError, TypeError, ValueError) as err:
            raise SequenceError(
                f"{self.path / 'sequence.json'} lacks a valid width/height/num_frames ({err!r})"
            ) from None
        self.timestamps = self._read_timestamps(n)
        self.metadata: dict[str, Any] = dict(info.get("metadata", {}))
        self.label_names: dict[int, str] = {int(k): str(v) for k, v in info.get("label_names", {}).items()}
        self.has_masks = bool(info.get("has_masks", False))
        self._gt: dict[str, np.ndarray] = {}
        names = list(info.get("gt_objects", []))
        if names:
            gt_path = self.path / "gt" / "poses.npz"
            if not gt_path.is_file():
                raise SequenceError(
                    f"{gt_path} is missing but sequence.json lists ground-truth objects {names}"
                )
            try:
                self._gt = read_npz(gt_path, format=POSES_FORMAT).arrays
            except FileFormatError as err:
                raise SequenceError(str(err)) from err
            for name in names:
                if name not in self._gt or f"{name}.valid" not in self._gt:
                    raise SequenceError(f"{gt_path} has no poses for object {name!r}")
        self.gt_objects: tuple[str, ...] = tuple(names)

    def _read_timestamps(self, n: int) -> np.ndarray:
        path = self.path / "timestamps.txt"
        rows = read_text_rows(path)
        if len(rows) != n or any(len(r) != 2 for r in rows):
            raise SequenceError(f"{path} has {len(rows)} '<index> <time>' rows, expected {n}")
        try:
            ts = np.array([float(r[1]) for r in rows], dtype=np.float64)
        except ValueError as err:
            raise SequenceError(f"{path}: a timestamp is not a number ({err})") from None
        return check_timestamps(ts, str(path))

    def frame(self, index: int) -> RGBDFrame:
        """Frame ``index`` read from disk (with ground-truth labels if recorded); SequenceError if bad."""
        name = f"{index:06d}.png"
        rgb = read_image(self.path / "rgb" / name)
        depth = read_depth(self.path / "depth" / name, self.depth_scale)
        labels = None
        if self.has_masks:
            labels = read_image(self.path / "gt" / "masks" / name, depth=True).astype(np.int32)
        if rgb.shape[:2] != (self.height, self.width) or depth.shape != (self.height, self.width):
            raise SequenceError(
                f"frame {index} has rgb {rgb.shape} and depth {depth.shape}; sequence.json says {self.height}x{self.width}"
            )
        return RGBDFrame(
            rgb=rgb, depth=depth, K=self.K, timestamp=float(self.timestamps[index]), labels=labels
        )

    def gt_poses(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth ``camera_from_object`` poses of ``name``: ((N, 4, 4) float64, (N,) bool valid)."""
        if name not in self.gt_objects:
            raise KeyError(f"no ground-truth poses for {name!r}; the sequence has {list(self.gt_objects)}")
        return self._gt[name], self._gt[f"{name}.valid"].astype(bool)


def open_sequence(
    path: str | os.PathLike[str],
    *,
    K: np.ndarray | None = None,
    depth_scale: float | None = None,
    fps: float | None = None,
    **tum_options: Any,
) -> FrameSequence:
    """Open a recorded sequence: ``pal`` layout, TUM RGB-D lists, or a folder of image files.

    Args:
        path: the directory.
        K: (3, 3) intrinsics for TUM and folder layouts (None: read ``calibration.json``);
            the ``pal`` layout stores its own and refuses another.
        depth_scale: metres per depth unit for TUM and folder layouts (None: read
            ``calibration.json``).
        fps: frame rate of a folder without ``timestamps.txt``, frames/s.
        **tum_options: passed to :class:`pal.perception.tum.TUMSequence` (``max_difference``).

    Raises:
        SequenceError: the directory does not exist, matches no layout, or lacks its camera.
    """
    p = Path(path)
    if not p.is_dir():
        raise SequenceError(f"sequence directory {p} does not exist or is not a directory")
    if (p / "sequence.json").is_file():
        if K is not None or depth_scale is not None:
            raise SequenceError(
                f"{p} is a pal sequence with its own intrinsics.json and depth scale; do not pass K or depth_scale"
            )
        return RecordedSequence(p)
    if (p / "rgb.txt").is_file() and (p / "depth.txt").is_file():
        return TUMSequence(p, K=K, depth_scale=depth_scale, **tum_options)
    if find_folder_layout(p) is not None:
        return FolderSequence(p, K=K, depth_scale=depth_scale, fps=fps)
    if (p / "rgb").is_dir():
        return RecordedSequence(p)  # an incomplete pal sequence: its reader names what is missing
    raise SequenceError(
        f"{p} is neither a pal sequence (sequence.json), a TUM RGB-D sequence (rgb.txt + depth.txt), "
        "nor a folder of frames (<stem>.png + <stem>_depth.png, or color/ + depth/)"
    )
