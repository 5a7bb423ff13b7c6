"""What the tracker compares: masks predicted under the camera's motion, appearance, metric size.

- :func:`surface_sample`: a sparse sample of a mask's pixels lifted to 3-D (camera frame),
  what a track remembers of its object's shape;
- :func:`predict_mask`: that sample moved by a rigid transform (the camera's motion since the
  track was last seen), projected and splatted into a mask in the current image;
- :func:`appearance`: a hue-saturation histogram of the mask (48 bins, L1-normalised), and
  :func:`appearance_distance` (Bhattacharyya, in [0, 1]) between two of them.

A static object seen from a moving camera is where its predicted mask says, whatever the
camera did, so association compares candidates with predictions instead of with last masks.
"""

from __future__ import annotations

import cv2
import numpy as np

from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask

__all__ = [
    "APPEARANCE_BINS",
    "appearance",
    "appearance_distance",
    "appearance_distances",
    "predict_mask",
    "surface_sample",
]

#: Hue and saturation bins of :func:`appearance`.
APPEARANCE_BINS = (12, 4)


def surface_sample(frame: RGBDFrame, mask: Mask, step: int) -> np.ndarray:
    """(M, 3) camera-frame points of the mask pixels on a ``step``-pixel grid with depth, metres."""
    x0, y0, _, _ = mask.bbox
    crop = mask.crop[::step, ::step]
    vs, us = np.nonzero(crop)
    vs, us = vs * step + y0, us * step + x0
    z = frame.depth[vs, us]
    ok = z > 0
    return backproject(us[ok], vs[ok], z[ok], frame.K)


def predict_mask(
    points: np.ndarray, T: np.ndarray, K: np.ndarray, image_shape: tuple[int, int], step: int
) -> Mask | None:
    """The mask where ``points`` (M, 3) appear after the rigid motion ``T`` (4, 4).

    Each projected point is splatted as a ``step + 1``-pixel square, so a sample taken every
    ``step`` pixels covers its object again. None when no point lands in the image in front of
    the camera.
    """
    if points.shape[0] == 0:
        return None
    cam = points @ T[:3, :3].T + T[:3, 3]
    cam = cam[cam[:, 2] > 1e-3]
    if cam.shape[0] == 0:
        return None
    u = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 1] * cam[:, 1] / cam[:, 2] + K[0, 2]
    v = K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
    h, w = image_shape
    ui, vi = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    ok = (ui >= 0) & (vi >= 0) & (ui < w) & (vi < h)
    if not ok.any():
        return None
    ui, vi = ui[ok], vi[ok]
    r = max(1, (step + 1) // 2)
    x0, y0 = max(int(ui.min()) - r, 0), max(int(vi.min()) - r, 0)
    x1, y1 = min(int(ui.max()) + r + 1, w), min(int(vi.max()) + r + 1, h)
    crop = np.zeros((y1 - y0, x1 - x0), np.uint8)
    crop[vi - y0, ui - x0] = 1
    crop = cv2.dilate(crop, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    return Mask.from_crop(crop.view(bool), x0, y0, image_shape)


def appearance(hsv: np.ndarray, mask: Mask) -> np.ndarray:
    """(48,) float32 L1-normalised hue-saturation histogram of the mask's pixels.

    Args:
        hsv: (H, W, 3) uint8 image in OpenCV's HSV (hue 0-179).
        mask: the object's mask.
    """
    x0, y0, x1, y1 = mask.bbox
    hist = cv2.calcHist(
        [np.ascontiguousarray(hsv[y0:y1, x0:x1])],
        [0, 1],
        mask.crop.view(np.uint8),
        list(APPEARANCE_BINS),
        [0, 180, 0, 256],
    ).ravel()
    total = float(hist.sum())
    return (hist / total if total > 0 else hist).astype(np.float32)


def appearance_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Bhattacharyya distance of two :func:`appearance` histograms, in [0, 1] (0: identical)."""
    return float(cv2.compareHist(a, b, cv2.HISTCMP_BHATTACHARYYA))


def appearance_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`appearance_distance` of every pair of rows: (n, m) from (n, B) and (m, B) histograms.

    OpenCV's Bhattacharyya distance, ``sqrt(1 - sum(sqrt(h_a h_b)) / sqrt(sum(h_a) sum(h_b)))``,
    in one matrix product.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(f"histograms of shapes {a.shape} and {b.shape}; expected (n, B) and (m, B)")
    norm = np.sqrt(np.outer(a.sum(axis=1), b.sum(axis=1)))
    sim = (np.sqrt(a) @ np.sqrt(b).T) / np.where(norm > 0, norm, np.inf)
    return np.sqrt(np.clip(1.0 - sim, 0.0, None))
