"""Recorded RGB-D sequences on disk: the ``pal`` layout (read and written) and a common reader API.

A ``pal`` sequence is a directory::

    sequence.json      {"format": "pal.rgbd-sequence/1", "num_frames", "width", "height",
                        "depth_scale" (metres per depth unit), "has_masks", "gt_objects",
                        "label_names", "metadata" (caller's provenance), "versions"}
                       -- written last: a sequence without it is incomplete
    intrinsics.json    {"K": [[fx, s, cx], [0, fy, cy], [0, 0, 1]], "width", "height"}
    timestamps.txt     one line per frame: "<index> <timestamp in s>"
    rgb/000000.png     8-bit RGB (stored BGR, as PNG readers expect)
    depth/000000.png   16-bit; metres = value * depth_scale; 0 = invalid
    gt/masks/000000.png  optional 16-bit instance ids (0 = background), ``RGBDFrame.labels``
    gt/poses.npz       optional: per object name, "<name>" (N, 4, 4) camera_from_object and
                       "<name>.valid" (N,) bool (poses of frames where the object is unknown are 0)

Every file is written atomically. The TUM RGB-D layout is read by :mod:`pal.perception.tum`;
:func:`open_sequence` picks the reader from the directory's contents.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pal.perception.atomic import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_npz,
    atomic_write_png,
    versions,
)
from pal.perception.frames import RGBDFrame, check_intrinsics

__all__ = [
    "FORMAT",
    "FrameSequence",
    "RecordedSequence",
    "SequenceError",
    "SequenceWriter",
    "decode_depth",
    "encode_depth",
    "open_sequence",
    "read_image",
]

logger = logging.getLogger(__name__)

FORMAT = "pal.rgbd-sequence/1"
_MAX_U16 = 65535


class SequenceError(ValueError):
    """A sequence directory is missing, incomplete, unreadable or inconsistent."""


def read_text_rows(path: Path) -> list[list[str]]:
    """Whitespace-separated fields of every non-empty line of a text file, ``#`` comments skipped.

    Raises:
        SequenceError: the file does not exist.
    """
    if not path.is_file():
        raise SequenceError(f"{path} does not exist")
    return [
        line.split()
        for line in path.read_text(encoding="utf-8").splitlines()
        if line.strip() and not line.startswith("#")
    ]


def encode_depth(depth: np.ndarray, scale: float) -> np.ndarray:
    """Metres -> uint16 units of ``scale`` metres; 0 stays 0 (invalid).

    Depths beyond ``65535 * scale`` cannot be stored; they become 0 (invalid) and a warning
    is logged with their count.
    """
    if not scale > 0:
        raise ValueError(f"depth_scale is {scale}, expected > 0 metres per unit")
    units = np.rint(np.asarray(depth, dtype=np.float64) / scale)
    over = units > _MAX_U16
    if over.any():
        logger.warning(
            "%d depth pixels beyond %.3f m cannot be stored at scale %g; marked invalid (0)",
            int(over.sum()),
            _MAX_U16 * scale,
            scale,
        )
        units[over] = 0
    return units.astype(np.uint16)


def decode_depth(units: np.ndarray, scale: float) -> np.ndarray:
    """uint16 depth units -> (H, W) float32 metres (0 = invalid)."""
    return (units.astype(np.float32) * np.float32(scale)).astype(np.float32)


def read_image(path: Path, *, depth: bool = False) -> np.ndarray:
    """Read a PNG: (H, W, 3) uint8 RGB, or with ``depth=True`` (H, W) uint16.

    Raises:
        SequenceError: the file is missing, unreadable or has the wrong type.
    """
    if not path.is_file():
        raise SequenceError(f"{path} does not exist")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SequenceError(f"{path} is not a readable image")
    if depth:
        if image.ndim != 2 or image.dtype != np.uint16:
            raise SequenceError(
                f"{path} has shape {image.shape} dtype {image.dtype}; expected a 16-bit single-channel depth PNG"
            )
        return image
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    elif image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    else:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if image.dtype != np.uint8:
        raise SequenceError(f"{path} has dtype {image.dtype}; expected an 8-bit colour PNG")
    return image


class FrameSequence:
    """Common API of recorded sequences: ``len``, indexing and iteration yield :class:`RGBDFrame`.

    Attributes:
        path: the directory.
        K: (3, 3) intrinsics of every frame.
        timestamps: (N,) float64 seconds.
    """

    path: Path
    K: np.ndarray
    timestamps: np.ndarray

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def frame(self, index: int) -> RGBDFrame:  # pragma: no cover - abstract
        raise NotImplementedError

    def __getitem__(self, index: int) -> RGBDFrame:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"frame {index} out of range for a sequence of {n} frames")
        return self.frame(index % n)

    def __iter__(self) -> Iterator[RGBDFrame]:
        for i in range(len(self)):
            yield self.frame(i)


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise SequenceError(f"{path} does not exist; {path.parent} is not a complete pal sequence")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise SequenceError(f"{path} is not readable JSON ({type(err).__name__}: {err})") from None
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
            with np.load(gt_path, allow_pickle=False) as npz:
                self._gt = {k: npz[k] for k in npz.files}
            for name in names:
                if name not in self._gt or f"{name}.valid" not in self._gt:
                    raise SequenceError(f"{gt_path} has no poses for object {name!r}")
        self.gt_objects: tuple[str, ...] = tuple(names)

    def _read_timestamps(self, n: int) -> np.ndarray:
        path = self.path / "timestamps.txt"
        rows = read_text_rows(path)
        if len(rows) != n or any(len(r) != 2 for r in rows):
            raise SequenceError(f"{path} has {len(rows)} '<index> <time>' rows, expected {n}")
        ts = np.array([float(r[1]) for r in rows], dtype=np.float64)
        if not np.all(np.isfinite(ts)):
            raise SequenceError(f"{path} has non-finite timestamps")
        return ts

    def frame(self, index: int) -> RGBDFrame:
        name = f"{index:06d}.png"
        rgb = read_image(self.path / "rgb" / name)
        depth = decode_depth(read_image(self.path / "depth" / name, depth=True), self.depth_scale)
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


class SequenceWriter:
    """Writes frames (and optional ground truth) in the ``pal`` layout; a context manager.

    Args:
        path: the directory to create (must not hold a sequence unless ``overwrite``).
        depth_scale: metres per stored depth unit (default 1 mm: up to 65.535 m).
        metadata: JSON-compatible provenance (seed, motion, config, ...).
        label_names: optional names of the instance ids in ``frame.labels``.
        overwrite: allow writing into a directory that already has ``sequence.json``.

    The first frame fixes the image size and the intrinsics; later frames must agree.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        depth_scale: float = 0.001,
        metadata: Mapping[str, Any] | None = None,
        label_names: Mapping[int, str] | None = None,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        if (self.path / "sequence.json").exists() and not overwrite:
            raise SequenceError(f"{self.path} already holds a sequence; pass overwrite=True to replace it")
        if not depth_scale > 0:
            raise ValueError(f"depth_scale is {depth_scale}, expected > 0 metres per unit")
        self.depth_scale = float(depth_scale)
        self.metadata = json.loads(json.dumps(dict(metadata or {}), allow_nan=False))
        self.label_names = {int(k): str(v) for k, v in (label_names or {}).items()}
        self._timestamps: list[float] = []
        self._K: np.ndarray | None = None
        self._shape: tuple[int, int] | None = None
        self._has_masks: bool | None = None
        self._gt: dict[str, list[np.ndarray | None]] = {}
        self._closed = False
        self.path.mkdir(parents=True, exist_ok=True)
        (self.path / "sequence.json").unlink(missing_ok=True)

    def append(self, frame: RGBDFrame, gt_poses: Mapping[str, np.ndarray] | None = None) -> int:
        """Write one frame; returns its index.

        Args:
            frame: the frame; its ``labels`` (if any) are written as ground-truth masks.
            gt_poses: optional ``{object name: (4, 4) camera_from_object}`` for this frame.
        """
        if self._closed:
            raise SequenceError(f"writer for {self.path} is closed")
        if self._K is None:
            self._K, self._shape, self._has_masks = np.array(frame.K), frame.shape, frame.labels is not None
        if frame.shape != self._shape:
            raise ValueError(f"frame has size {frame.shape}, expected {self._shape} like the first frame")
        if not np.allclose(frame.K, self._K):
            raise ValueError(
                f"frame intrinsics {frame.K.tolist()} differ from the first frame's {self._K.tolist()}"
            )
        if (frame.labels is not None) != self._has_masks:
            raise ValueError("either every frame carries ground-truth labels or none does")
        index = len(self._timestamps)
        name = f"{index:06d}.png"
        atomic_write_png(
            self.path / "rgb" / name, cv2.cvtColor(np.ascontiguousarray(frame.rgb), cv2.COLOR_RGB2BGR)
        )
        atomic_write_png(self.path / "depth" / name, encode_depth(frame.depth, self.depth_scale))
        if frame.labels is not None:
            if frame.labels.min() < 0 or frame.labels.max() > _MAX_U16:
                raise ValueError(
                    f"labels span [{frame.labels.min()}, {frame.labels.max()}]; expected ids in [0, 65535]"
                )
            atomic_write_png(self.path / "gt" / "masks" / name, frame.labels.astype(np.uint16))
        for key in self._gt:
            self._gt[key].append(None)
        for key, pose in (gt_poses or {}).items():
            pose = np.asarray(pose, dtype=np.float64)
            if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
                raise ValueError(
                    f"ground-truth pose of {key!r} has shape {pose.shape} or non-finite entries; expected finite (4, 4)"
                )
            self._gt.setdefault(str(key), [None] * (index + 1))[index] = pose
        self._timestamps.append(frame.timestamp)
        return index

    def close(self) -> Path:
        """Write the timestamps, intrinsics, ground truth and finally ``sequence.json``."""
        if self._closed:
            return self.path
        if self._K is None or self._shape is None:
            raise SequenceError(f"no frame was written to {self.path}; an empty sequence is not valid")
        lines = ["# index timestamp_s"] + [f"{i} {t:.9f}" for i, t in enumerate(self._timestamps)]
        atomic_write_bytes(self.path / "timestamps.txt", ("\n".join(lines) + "\n").encode())
        atomic_write_json(
            self.path / "intrinsics.json",
            {"K": self._K.tolist(), "width": self._shape[1], "height": self._shape[0]},
        )
        if self._gt:
            arrays: dict[str, np.ndarray] = {}
            for key, poses in self._gt.items():
                arrays[key] = np.stack([np.zeros((4, 4)) if p is None else p for p in poses])
                arrays[f"{key}.valid"] = np.array([p is not None for p in poses])
            atomic_write_npz(self.path / "gt" / "poses.npz", arrays)
        atomic_write_json(
            self.path / "sequence.json",
            {
                "format": FORMAT,
                "num_frames": len(self._timestamps),
                "width": self._shape[1],
                "height": self._shape[0],
                "depth_scale": self.depth_scale,
                "has_masks": bool(self._has_masks),
                "gt_objects": sorted(self._gt),
                "label_names": {str(k): v for k, v in self.label_names.items()},
                "metadata": self.metadata,
                "versions": versions(),
            },
        )
        self._closed = True
        return self.path

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.close()


def open_sequence(path: str | os.PathLike[str], **tum_options: Any) -> FrameSequence:
    """Open a recorded sequence, ``pal`` layout or TUM RGB-D layout.

    Args:
        path: the directory.
        **tum_options: passed to :class:`pal.perception.tum.TUMSequence` for TUM directories.

    Raises:
        SequenceError: the directory does not exist or matches neither layout.
    """
    from pal.perception.tum import TUMSequence

    p = Path(path)
    if not p.is_dir():
        raise SequenceError(f"sequence directory {p} does not exist or is not a directory")
    if (p / "sequence.json").is_file() or ((p / "rgb").is_dir() and not (p / "rgb.txt").is_file()):
        return RecordedSequence(p)
    if (p / "rgb.txt").is_file() and (p / "depth.txt").is_file():
        return TUMSequence(p, **tum_options)
    raise SequenceError(
        f"{p} is neither a pal sequence (sequence.json) nor a TUM RGB-D sequence (rgb.txt + depth.txt)"
    )
