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

import math
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
    resolve_inside,
)
from pal.perception.folder_layouts import LAYOUTS, FolderLayout
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


def _read_intrinsics(path: Path) -> np.ndarray:
    K = _read_json(path).get("K")
    try:
        if K is not None and not isinstance(K, list):
            raise ValueError(f"K is {K!r}, expected a (3, 3) list of numbers")
        return check_intrinsics(None if K is None else np.asarray(K, dtype=np.float64))
    except (TypeError, ValueError) as err:
        raise SequenceError(f"{path}: {err}") from None


#: Optional keys of sequence.json and their defaults.
_DEFAULTS: dict[str, Any] = {"metadata": {}, "label_names": {}, "has_masks": False, "gt_objects": []}


def _field(path: Path, info: dict[str, Any], key: str, kinds: tuple[type, ...], expected: str) -> Any:
    value = info.get(key, _DEFAULTS.get(key))
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        raise SequenceError(f"{path}: {key!r} is {value!r}, expected {expected}")
    return value


def _check_info(path: Path, info: dict[str, Any]) -> dict[str, Any]:
    """The checked fields of ``sequence.json``; SequenceError naming the file, key and value."""
    out: dict[str, Any] = {}
    for key in ("width", "height", "num_frames"):
        out[key] = _field(path, info, key, (int,), "an int >= 1")
        if out[key] < 1:
            raise SequenceError(f"{path}: {key!r} is {out[key]!r}, expected an int >= 1")
    scale = _field(path, info, "depth_scale", (int, float), "a number > 0 (metres per depth unit)")
    if not (math.isfinite(scale) and scale > 0):
        raise SequenceError(
            f"{path}: 'depth_scale' is {scale!r}, expected a number > 0 (metres per depth unit)"
        )
    out["depth_scale"] = float(scale)
    out["has_masks"] = _field(path, info, "has_masks", (bool,), "true or false")
    out["metadata"] = dict(_field(path, info, "metadata", (dict,), "a JSON object"))
    names = _field(path, info, "gt_objects", (list,), "a list of object names")
    if not all(isinstance(n, str) for n in names):
        raise SequenceError(f"{path}: 'gt_objects' is {names!r}, expected a list of object names")
    out["gt_objects"] = names
    labels = _field(path, info, "label_names", (dict,), "an object of id -> name")
    if not all(k.lstrip("-").isdigit() and isinstance(v, str) for k, v in labels.items()):
        raise SequenceError(f"{path}: 'label_names' is {labels!r}, expected an object of integer id -> name")
    out["label_names"] = {int(k): v for k, v in labels.items()}
    return out


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
        self.K = _read_intrinsics(self.path / "intrinsics.json")
        fields = _check_info(self.path / "sequence.json", info)
        self.depth_scale, self.width, self.height = fields["depth_scale"], fields["width"], fields["height"]
        self.timestamps = self._read_timestamps(fields["num_frames"])
        self.metadata: dict[str, Any] = fields["metadata"]
        self.label_names: dict[int, str] = fields["label_names"]
        self.has_masks: bool = fields["has_masks"]
        names = fields["gt_objects"]
        self._gt: dict[str, np.ndarray] = self._read_gt(names) if names else {}
        self.gt_objects: tuple[str, ...] = tuple(names)

    def _read_gt(self, names: list[str]) -> dict[str, np.ndarray]:
        gt_path = self.path / "gt" / "poses.npz"
        if not gt_path.is_file():
            raise SequenceError(f"{gt_path} is missing but sequence.json lists ground-truth objects {names}")
        try:
            gt = read_npz(gt_path, format=POSES_FORMAT).arrays
        except FileFormatError as err:
            raise SequenceError(str(err)) from err
        n = len(self.timestamps)
        for name in names:
            if name not in gt or f"{name}.valid" not in gt:
                raise SequenceError(f"{gt_path} has no poses for object {name!r}")
            shapes = (gt[name].shape, gt[f"{name}.valid"].shape)
            if shapes != ((n, 4, 4), (n,)):
                raise SequenceError(
                    f"{gt_path}: the poses of {name!r} have shapes {shapes}, expected (({n}, 4, 4), ({n},))"
                )
        return gt

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
        name, where = f"{index:06d}.png", str(self.path)
        rgb = read_image(resolve_inside(self.path, f"rgb/{name}", where))
        depth = read_depth(resolve_inside(self.path, f"depth/{name}", where), self.depth_scale)
        labels = None
        if self.has_masks:
            mask = resolve_inside(self.path, f"gt/masks/{name}", where)
            labels = read_image(mask, depth=True).astype(np.int32)
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
    layout: str | FolderLayout | None = None,
    **tum_options: Any,
) -> FrameSequence:
    """Open a recorded sequence: ``pal`` layout, TUM RGB-D lists, or a folder of image files.

    Args:
        path: the directory.
        K: (3, 3) intrinsics for TUM and folder layouts (None: read ``calibration.json``);
            the ``pal`` layout stores its own and refuses another.
        depth_scale: metres per depth unit for TUM and folder layouts (None: read
            ``calibration.json``).
        fps: frame rate of a folder without ``timestamps.txt``, frames/s (None: stills).
        layout: a folder's naming pattern (:class:`pal.perception.folder_layouts.FolderLayout`
            or a built-in name); None: found from the files.
        **tum_options: passed to :class:`pal.perception.tum.TUMSequence` (``max_difference``,
            ``missing``).

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
    if layout is not None or find_folder_layout(p) is not None:
        return FolderSequence(p, K=K, depth_scale=depth_scale, fps=fps, layout=layout)
    if (p / "rgb").is_dir():
        return RecordedSequence(p)  # an incomplete pal sequence: its reader names what is missing
    layouts = "; ".join(f"{x.name!r} ({x.describe()})" for x in LAYOUTS)
    raise SequenceError(
        f"{p} is neither a pal sequence (sequence.json), a TUM RGB-D sequence (rgb.txt + depth.txt), "
        f"nor a folder of frames of a built-in layout: {layouts}"
    )
