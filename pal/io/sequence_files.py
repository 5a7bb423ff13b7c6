"""The ``pal`` RGB-D sequence layout on disk: its writer and the reading helpers all readers share.

A ``pal`` sequence is a directory::

    sequence.json      {"format": "pal.rgbd-sequence/2", "num_frames", "width", "height",
                        "depth_scale" (metres per depth unit), "has_masks", "gt_objects",
                        "label_names", "metadata" (caller's provenance), "versions"}
                       -- written last: a sequence without it is incomplete
    intrinsics.json    {"K": [[fx, s, cx], [0, fy, cy], [0, 0, 1]], "width", "height"}
    timestamps.txt     one line per frame: "<index> <timestamp in s>"
    rgb/000000.png     8-bit RGB (stored BGR, as PNG readers expect)
    depth/000000.png   16-bit; metres = value * depth_scale; 0 = invalid
    gt/masks/000000.png  optional 16-bit instance ids (0 = background), ``RGBDFrame.labels``
    gt/poses.npz       optional, a checked ``.npz`` of :mod:`pal.io.files` (format
                       :data:`POSES_FORMAT`): per object name, "<name>" (N, 4, 4)
                       camera_from_object and "<name>.valid" (N,) bool (poses of frames where
                       the object is unknown are 0)

Every file is written atomically through :mod:`pal.io.files`. :mod:`pal.sim.recording` writes
this layout with :class:`SequenceWriter`; :mod:`pal.perception.sequence` reads it (and
:mod:`pal.perception.tum` the TUM RGB-D layout) as :class:`FrameSequence` s. This module
imports neither :mod:`pal.sim` nor :mod:`pal.perception`.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from pal.frames import EmptyDepthError, RGBDFrame
from pal.io.files import (
    FileFormatError,
    atomic_write_bytes,
    atomic_write_json,
    check_json,
    versions,
    write_npz,
)
from pal.io.image_headers import MAX_IMAGE_PIXELS, ImageHeaderError, check_image_size

__all__ = [
    "FORMAT",
    "MAX_TEXT_BYTES",
    "POSES_FORMAT",
    "CameraPoses",
    "FrameSequence",
    "MissingFramesWarning",
    "SequenceError",
    "SequenceWriter",
    "atomic_write_png",
    "check_timestamps",
    "decode_depth",
    "encode_depth",
    "read_depth",
    "read_image",
    "read_text",
    "read_text_rows",
    "resolve_inside",
]

logger = logging.getLogger(__name__)

FORMAT = "pal.rgbd-sequence/2"
POSES_FORMAT = "pal.rgbd-sequence-poses/2"
_MAX_U16 = 65535
#: Largest list or table file read (``rgb.txt``, ``groundtruth.txt``, ``timestamps.txt``), bytes:
#: TUM's longest lists are a few MB.
MAX_TEXT_BYTES = 64 * 2**20


class SequenceError(FileFormatError):
    """A sequence directory is missing, incomplete, unreadable or inconsistent."""


class CameraPoses(NamedTuple):
    """Camera-to-world poses of a sequence's frames.

    Attributes:
        poses: (N, 4, 4) float64 transforms, metres; rows without a pose are the identity.
        valid: (N,) bool, True where the recording has a pose for the frame.
    """

    poses: np.ndarray
    valid: np.ndarray


class MissingFramesWarning(UserWarning):
    """Frames a sequence's lists name are not on disk and were skipped (``missing="skip"``)."""


def read_text(path: Path, max_bytes: int | None = None) -> str:
    """The UTF-8 text of a list or table file, refused before reading when over ``max_bytes``.

    ``max_bytes`` None: :data:`MAX_TEXT_BYTES`.

    Raises:
        SequenceError: the file does not exist, is larger than ``max_bytes`` or is not UTF-8 text.
    """
    if not path.is_file():
        raise SequenceError(f"{path} does not exist")
    size = path.stat().st_size
    max_bytes = MAX_TEXT_BYTES if max_bytes is None else max_bytes
    if size > max_bytes:
        raise SequenceError(
            f"{path} is {size} bytes, more than the {max_bytes} a frame list or table may hold"
        )
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise SequenceError(f"{path} is not a readable text file ({type(err).__name__}: {err})") from None


def read_text_rows(path: Path) -> list[list[str]]:
    """Whitespace-separated fields of every non-empty line of a text file, ``#`` comments skipped.

    Raises:
        SequenceError: the file does not exist, is too large (:func:`read_text`) or is not UTF-8 text.
    """
    text = read_text(path)
    return [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]


def resolve_inside(root: Path, name: str | os.PathLike[str], where: str) -> Path:
    """``root / name`` resolved; it must stay inside ``root`` (no ``..``, absolute path or symlink out).

    Raises:
        SequenceError: the file resolves outside ``root``; names ``where``, the name and its target.
    """
    target = (root / name).resolve()
    if not target.is_relative_to(root.resolve()):
        raise SequenceError(
            f"{where}: the file {str(name)!r} resolves to {target}, outside the sequence folder {root}; "
            "a sequence may only read files inside its folder"
        )
    return target


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


def check_timestamps(timestamps: np.ndarray, source: str) -> np.ndarray:
    """Check that frame times are finite and never decrease; returns them as (N,) float64 s.

    Raises:
        SequenceError: a non-finite timestamp, or one earlier than its predecessor (both named).
    """
    ts = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    bad = np.flatnonzero(~np.isfinite(ts))
    if bad.size:
        raise SequenceError(f"{source}: timestamp {ts[bad[0]]} of frame {int(bad[0])} is not finite")
    back = np.flatnonzero(np.diff(ts) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise SequenceError(
            f"{source}: timestamps are not monotonic: frame {k} at {ts[k]:.6f} s comes after frame {k - 1} "
            f"at {ts[k - 1]:.6f} s; sort the frames by time"
        )
    return ts


def read_image(path: Path, *, depth: bool = False, max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """Read an image file: (H, W, 3) uint8 RGB, or with ``depth=True`` (H, W) uint16.

    Colour files (PNG, JPEG, BMP, PNM, TIFF) are converted from OpenCV's BGR to RGB; grey
    ones are replicated to three channels. Depth files are 16-bit single-channel PNG or PGM.
    The width and height are read from the file's header and checked against ``max_pixels``
    (:data:`pal.io.image_headers.MAX_IMAGE_PIXELS`, 50 megapixels) before it is decoded.

    Raises:
        SequenceError: the file is missing, unreadable, over ``max_pixels``, of another
            format, or has the wrong type; names the file.
    """
    if not path.is_file():
        raise SequenceError(f"{path} does not exist")
    try:
        width, height = check_image_size(path, max_pixels)
    except ImageHeaderError as err:
        raise SequenceError(str(err)) from err
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SequenceError(f"{path} is not a readable image")
    if image.shape[:2] != (height, width):
        raise SequenceError(f"{path} decodes to {image.shape[:2]} but its header says {height}x{width}")
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


def read_depth(path: Path, scale: float) -> np.ndarray:
    """Read a 16-bit depth image (PNG or PGM) as (H, W) float32 metres, 0 = invalid.

    Args:
        path: the file.
        scale: metres per stored unit (> 0).

    Raises:
        SequenceError: the file is missing, unreadable or not 16-bit single-channel.
        EmptyDepthError: no pixel has a reading (all 0).
    """
    units = read_image(path, depth=True)
    if not units.any():
        raise EmptyDepthError(
            f"{path} has no valid depth pixel (all {units.shape[0]}x{units.shape[1]} are 0); it is not a "
            "depth image of this recording, or the sensor failed on this frame"
        )
    with np.errstate(over="ignore"):  # an absurd scale overflows float32; refused below
        depth = decode_depth(units, scale)
    if not np.isfinite(depth).all():
        raise SequenceError(
            f"{path}: depth_scale {scale} turns its units into non-finite metres; expected metres per unit"
        )
    return depth


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
        """Frame ``index`` in [0, len); subclasses read it."""
        raise NotImplementedError

    def __getitem__(self, index: int) -> RGBDFrame:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"frame {index} out of range for a sequence of {n} frames")
        return self.frame(index % n)

    def __iter__(self) -> Iterator[RGBDFrame]:
        for i in range(len(self)):
            yield self.frame(i)

    def camera_poses(self) -> CameraPoses:
        """Camera-to-world poses of the frames with their validity mask, when the recording has them.

        Raises:
            SequenceError: this recording has no camera poses.
        """
        raise SequenceError(f"{self.path} has no camera poses")


def atomic_write_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """Encode ``image`` as PNG and write it atomically.

    Args:
        path: destination ``.png``.
        image: (H, W) uint8/uint16 or (H, W, 3) uint8 in OpenCV's BGR channel order.
    """
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(
            f"OpenCV could not encode an image of shape {image.shape} and dtype {image.dtype} as PNG"
        )
    return atomic_write_bytes(path, buf.tobytes())


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
        check_json(dict(metadata or {}), "sequence metadata")
        self.metadata = json.loads(json.dumps(dict(metadata or {})))
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
            write_npz(
                self.path / "gt" / "poses.npz", arrays, {"objects": sorted(self._gt)}, format=POSES_FORMAT
            )
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
            name="sequence.json",
        )
        self._closed = True
        return self.path

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.close()
