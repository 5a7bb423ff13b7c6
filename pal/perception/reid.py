"""Re-identification of a lost track from its predicted 3-D position and its memory gallery.

The overlap stage of :mod:`pal.perception.tracking` re-identifies a missing track when a
candidate overlaps the track's predicted mask. When that fails (the object came back after a
few frames, moved a little while hidden, or its mask prediction left the image), a candidate
that would be born is compared here with the tracks missing for at most ``max_gap_s`` seconds
(0.5 s: 15 frames at 30 Hz):

- **position**: the world position of the candidate's surface median (its surface sample
  moved by the camera's pose, :class:`pal.perception.egomotion.CameraMotion`) must lie within
  ``max_distance_m + distance_per_s * gap`` of the track's prediction, its last world position
  plus its world velocity times the gap (the gap clipped to ``max_gap_s``);
- **appearance**: the Bhattacharyya distance of the candidate's hue-saturation histogram to
  the *nearest* view of the track's memory gallery (:class:`pal.perception.memory.Gallery`;
  the track's running histogram when its gallery is empty) must be at most ``max_appearance``;
- **size**: the metric sizes must agree within a factor ``size_ratio``.

Among the compatible pairs, a one-to-one assignment minimises
``distance / allowed distance + appearance / max_appearance``. A matched candidate takes the
old id back (status ``"reidentified"``) instead of being born.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from pal.perception.association import appearance, appearance_distances, surface_sample
from pal.perception.frames import RGBDFrame
from pal.perception.masks import Mask

__all__ = ["ReidConfig", "gallery_histograms", "match_lost", "world_medians"]


@dataclass(frozen=True)
class ReidConfig:
    """Thresholds of the re-identification by position and gallery (module docstring).

    Attributes:
        max_gap_s: a track missing for at most this long can be re-identified this way, s.
        max_distance_m: allowed distance to the predicted world position right after the loss, m.
        distance_per_s: the allowed distance grows by this much per second of gap, m/s.
        max_appearance: largest Bhattacharyya distance to the nearest gallery view, in (0, 1].
        size_ratio: metric sizes of candidate and track must agree within this factor, > 1.
    """

    max_gap_s: float = 0.5
    max_distance_m: float = 0.04
    distance_per_s: float = 0.1
    max_appearance: float = 0.35
    size_ratio: float = 2.0

    def __post_init__(self) -> None:
        if not self.max_gap_s > 0 or not self.max_distance_m > 0 or not self.distance_per_s >= 0:
            raise ValueError(
                f"max_gap_s ({self.max_gap_s} s) and max_distance_m ({self.max_distance_m} m) must be > 0 "
                f"and distance_per_s ({self.distance_per_s} m/s) >= 0"
            )
        if not 0 < self.max_appearance <= 1:
            raise ValueError(f"max_appearance is {self.max_appearance}, expected in (0, 1]")
        if not self.size_ratio > 1:
            raise ValueError(f"size_ratio is {self.size_ratio}, expected > 1")


def gallery_histograms(rgbs: Sequence[np.ndarray], masks: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The hue-saturation histogram (:func:`pal.perception.association.appearance`) of each gallery view.

    Args:
        rgbs: (h, w, 3) uint8 crops of the views.
        masks: (h, w) bool object masks of the same crops.
    """
    out = []
    for rgb, m in zip(rgbs, masks, strict=True):
        area = int(m.sum())
        if area == 0:
            continue
        hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
        out.append(appearance(hsv, Mask((0, 0, m.shape[1], m.shape[0]), m, m.shape, area)))
    return out


def world_medians(
    frame: RGBDFrame, masks: Sequence[Mask], world_from_camera: np.ndarray, step: int
) -> np.ndarray:
    """(n, 3) world position of each mask's surface median, m (NaN rows: no depth in the mask).

    Args:
        frame: the frame the masks belong to.
        masks: n masks.
        world_from_camera: (4, 4) the camera's pose (metres).
        step: pixel step of the surface sample.
    """
    W = np.asarray(world_from_camera, dtype=np.float64)
    out = np.full((len(masks), 3), np.nan)
    for r, m in enumerate(masks):
        pts = surface_sample(frame, m, step)
        if pts.shape[0]:
            out[r] = W[:3, :3] @ np.median(pts, axis=0) + W[:3, 3]
    return out


def match_lost(
    positions: np.ndarray,
    hists: Sequence[np.ndarray],
    sizes: Sequence[float],
    predicted: np.ndarray,
    views: Sequence[Sequence[np.ndarray]],
    track_sizes: np.ndarray,
    gaps: np.ndarray,
    config: ReidConfig,
) -> list[tuple[int, int, float, float]]:
    """One-to-one matches of candidates to lost tracks (module docstring).

    Args:
        positions: (n, 3) candidates' world positions, m (NaN rows: no depth, never matched).
        hists: n candidates' (B,) hue-saturation histograms.
        sizes: n candidates' metric sizes, m² (0: unknown, not compared).
        predicted: (m, 3) tracks' predicted world positions, m.
        views: per track, the histograms of its gallery views (at least one each).
        track_sizes: (m,) tracks' metric sizes, m² (0: unknown).
        gaps: (m,) time since each track was last seen, s.
        config: the thresholds.

    Returns:
        (candidate row, track column, distance m, appearance distance) of each match.
    """
    n, m = len(positions), len(predicted)
    if not n or not m:
        return []
    hists, sizes = np.stack(hists), np.asarray(sizes, dtype=np.float64)
    dist = np.linalg.norm(positions[:, None, :] - predicted[None, :, :], axis=2)
    allowed = config.max_distance_m + config.distance_per_s * np.minimum(gaps, config.max_gap_s)
    app = np.stack([appearance_distances(hists, np.stack(v)).min(axis=1) for v in views], axis=1)
    both = (sizes[:, None] > 0) & (track_sizes[None, :] > 0)
    ratio = np.where(
        both, sizes[:, None] / np.where(track_sizes[None, :] > 0, track_sizes[None, :], 1.0), 1.0
    )
    size_ok = ~both | (np.abs(np.log(np.maximum(ratio, 1e-12))) <= np.log(config.size_ratio))
    ok = np.isfinite(dist) & (dist <= allowed[None, :]) & (app <= config.max_appearance) & size_ok
    if not ok.any():
        return []
    cost = np.where(ok, np.nan_to_num(dist) / allowed[None, :] + app / config.max_appearance, 1e3)
    rows, cols = linear_sum_assignment(cost)
    return [
        (int(r), int(c), float(dist[r, c]), float(app[r, c]))
        for r, c in zip(rows, cols, strict=True)
        if ok[r, c]
    ]
