"""A video of the loop: each camera frame with Π's detections, track ids, slots, estimates and targets.

:func:`overlay` draws one frame (pure OpenCV on a copy of the RGB image):

- each detected object: its mask outline and ``#id`` (green), with the slot it is bound to;
- each slot's state estimate: a filled dot (yellow), projected from the table plane;
- each target of the current decision: a cross (red) and the model's predicted outcome: a ring (cyan);
- a status line (step, episode, mode).

:class:`VideoRecorder` writes frames with ``cv2.VideoWriter`` (fourcc ``mp4v``) to a temporary
file next to the target and renames it on :meth:`VideoRecorder.close`, so a reader never sees a
half-written video.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pal.checks import check_float
from pal.perception import PerceptionState, project

__all__ = ["VideoRecorder", "overlay", "table_to_pixel"]

_GREEN, _YELLOW, _RED, _CYAN, _WHITE = (
    (40, 220, 40),
    (250, 220, 40),
    (230, 40, 40),
    (40, 220, 230),
    (255, 255, 255),
)


def table_to_pixel(
    point: Any, table_from_camera: np.ndarray, K: np.ndarray, height: float = 0.04
) -> tuple[int, int] | None:
    """Pixel (u, v) of the table point (x, y) lifted to ``height`` m, or None behind the camera."""
    p = np.array([float(point[0]), float(point[1]), height, 1.0])
    c = np.linalg.inv(table_from_camera) @ p
    if c[2] <= 1e-6:
        return None
    u, v = project(c[:3], K)
    return round(float(u)), round(float(v))


def overlay(
    rgb: np.ndarray,
    perception: PerceptionState,
    K: np.ndarray,
    table_from_camera: np.ndarray,
    *,
    slots: Mapping[str, int] | None = None,
    estimates: Mapping[str, Any] | None = None,
    targets: Mapping[str, Any] | None = None,
    predicted: Mapping[str, Any] | None = None,
    status: str = "",
) -> np.ndarray:
    """The annotated (H, W, 3) uint8 RGB frame (module docstring); ``rgb`` is not changed."""
    img = np.ascontiguousarray(np.asarray(rgb, dtype=np.uint8).copy())
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"rgb has shape {img.shape}, expected (H, W, 3)")
    names = {oid: name for name, oid in (slots or {}).items()}
    scale = max(img.shape[0] / 480.0, 0.35)
    for obj in perception.objects:
        if obj.mask is None:
            continue
        full = obj.mask.full().astype(np.uint8)
        contours, _ = cv2.findContours(full, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, contours, -1, _GREEN, 1, cv2.LINE_AA)
        x0, y0, _, _ = obj.mask.bbox
        label = f"#{obj.obj_id}" + (f" {names[obj.obj_id]}" if obj.obj_id in names else "")
        cv2.putText(
            img, label, (x0, max(y0 - 3, 10)), cv2.FONT_HERSHEY_SIMPLEX, 0.9 * scale, _GREEN, 1, cv2.LINE_AA
        )
    for e in (estimates or {}).values():
        px = None if e is None else table_to_pixel(e, table_from_camera, K)
        if px is not None:
            cv2.circle(img, px, max(2, int(4 * scale)), _YELLOW, -1, cv2.LINE_AA)
    for name, t in (targets or {}).items():
        px = table_to_pixel(t, table_from_camera, K)
        if px is not None:
            cv2.drawMarker(img, px, _RED, cv2.MARKER_CROSS, max(6, int(16 * scale)), 2, cv2.LINE_AA)
            cv2.putText(
                img,
                f"target {name}",
                (px[0] + 5, px[1] - 5),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.8 * scale,
                _RED,
                1,
                cv2.LINE_AA,
            )
    for p in (predicted or {}).values():
        px = table_to_pixel(p, table_from_camera, K)
        if px is not None:
            cv2.circle(img, px, max(4, int(8 * scale)), _CYAN, 1, cv2.LINE_AA)
    if status:
        cv2.putText(
            img, status, (5, img.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.9 * scale, _WHITE, 1, cv2.LINE_AA
        )
    return img


class VideoRecorder:
    """Writes RGB frames to an mp4 (``mp4v``) atomically (module docstring).

    Args:
        path: the video file to create.
        fps: frames per second.
    """

    def __init__(self, path: str | os.PathLike[str], fps: float = 5.0) -> None:
        check_float("fps", fps, 0.0, open_low=True)
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".mp4", dir=self.path.parent)
        os.close(fd)
        self._tmp = Path(tmp)
        self.fps = float(fps)
        self._writer: cv2.VideoWriter | None = None
        self._size: tuple[int, int] | None = None
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 RGB frame; every frame must have the first frame's size."""
        img = np.asarray(rgb)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise ValueError(f"frame has shape {img.shape} and dtype {img.dtype}, expected (H, W, 3) uint8")
        size = (img.shape[1], img.shape[0])
        if self._writer is None:
            self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, size)
            if not self._writer.isOpened():
                raise RuntimeError(f"OpenCV cannot open an mp4v video writer for {self._tmp}")
            self._size = size
        elif size != self._size:
            raise ValueError(f"frame size {size} differs from the first frame's {self._size}")
        self._writer.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        self.frames += 1

    def close(self) -> Path:
        """Finish the file and move it into place; returns the path. Without frames, nothing is written."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None
            os.chmod(self._tmp, 0o644)  # mkstemp creates 0600
            os.replace(self._tmp, self.path)
        else:
            self._tmp.unlink(missing_ok=True)
        return self.path

    def __enter__(self) -> VideoRecorder:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is not None and self._writer is not None:
            self._writer.release()
            self._writer = None
            self._tmp.unlink(missing_ok=True)
            return
        self.close()
