"""Mask propagation: the previous frame's object masks carried to this frame by the camera's motion.

Between full segmentations (every ``every`` frames), each object seen in the previous frame
gets its mask from the previous one instead of from a new segmentation:

1. **warp**: the mask's pixels with depth, on a ``step``-pixel grid, are lifted to 3-D with the
   previous depth, moved by the camera's motion ``T = current_from_previous`` and projected,
   ``u' = pi(K (R z K^-1 [u, v, 1] + t))``; each lands as a square of side ``2 (step // 2) + 1``
   pixels, so the warped mask covers its object again, and carries its predicted depth ``z'``;
2. **refine**: inside the warped mask grown by ``border`` pixels (at 640 columns), a pixel
   belongs to the object when its live depth ``z`` lies within the predicted depths around it
   (``[min z' - j, max z' + j]`` over a ``2 border + 3`` window, ``j`` the segmentation's depth
   discontinuity threshold at ``z``) and above the support plane like the segmentation's
   foreground (a pixel new to the mask); a warped pixel without live depth stays, and holes
   without depth enclosed by the mask are filled, as the segmentation fills them. The border thus follows the live depth
   edges, and cannot run off onto the support or a surface behind;
3. **occlusion**: objects are drawn far to near (median predicted depth) into one label image,
   so a pixel belongs to one object only; masks below ``min_area`` pixels, or failing the
   segmentation's size rules, are dropped (the object left the view or was covered).

A full segmentation runs on the first frame, every ``every``-th frame after it, and whenever
the camera's motion is unknown (lost, or no camera motion estimated), larger than
``max_rotation_deg`` or ``max_translation_m``, or the frame comes more than ``max_interval_s``
after the previous one: new objects appear
there, at most ``every - 1`` frames late. The support plane is carried by the same motion:
``n' = R n``, ``d' = d - n' . t``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from pal.checks import check_float, check_int
from pal.perception.frames import RGBDFrame
from pal.perception.masks import Mask
from pal.perception.plane import Plane, plane_height
from pal.perception.regions import fill_invalid_holes
from pal.perception.segmentation import Candidate, SegmentationConfig

__all__ = ["PropagationConfig", "carried_plane", "propagate_masks", "warp_mask"]


@dataclass(frozen=True)
class PropagationConfig:
    """When and how masks are propagated instead of segmented (module docstring).

    Attributes:
        every: a full segmentation every this many frames (1: every frame, no propagation).
        border: pixels (at 640 columns) a propagated mask may grow or shrink at its border per frame.
        step: warp grid step, pixels (at 640 columns).
        min_area: a propagated mask below this many pixels (at 640 columns) is dropped.
        max_interval_s: propagate only to a frame at most this many seconds after the previous
            one (farther apart, the warp and a ``border``-pixel refinement fall behind the motion).
        max_rotation_deg, max_translation_m: ... and only when the camera turned and moved at
            most this much since the previous frame (larger motions uncover and hide too much).
    """

    every: int = 3
    border: int = 1
    step: int = 2
    min_area: int = 150
    max_interval_s: float = 0.05
    max_rotation_deg: float = 2.0
    max_translation_m: float = 0.05

    def __post_init__(self) -> None:
        check_int("every", self.every)
        for name in ("max_interval_s", "max_rotation_deg", "max_translation_m"):
            check_float(name, getattr(self, name), 0.0)

    def small(self, T: np.ndarray) -> bool:
        """The camera motion ``T`` (4, 4) is within ``max_rotation_deg`` and ``max_translation_m``."""
        cos = np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        return bool(
            np.degrees(np.arccos(cos)) <= self.max_rotation_deg
            and np.linalg.norm(T[:3, 3]) <= self.max_translation_m
        )
        check_int("border", self.border, minimum=0)
        check_int("step", self.step)
        check_int("min_area", self.min_area)


def carried_plane(plane: Plane | None, T: np.ndarray) -> Plane | None:
    """``plane`` (``n . x + d = 0``, previous camera frame) in the current frame, ``T`` (4, 4) current_from_previous."""
    if plane is None:
        return None
    n = T[:3, :3] @ plane.normal
    return Plane(n, float(plane.offset - n @ T[:3, 3]), plane.inlier_fraction, plane.num_points)


def warp_mask(
    mask: Mask, depth: np.ndarray, K: np.ndarray, T: np.ndarray, step: int
) -> tuple[int, int, np.ndarray] | None:
    """Step 1 of the module docstring: ``(x0, y0, predicted depth crop)``, float32 metres, 0 off the mask.

    Args:
        mask: the mask in the previous frame.
        depth: (H, W) previous depth, metres (0 invalid).
        K: (3, 3) intrinsics (the same camera in both frames).
        T: (4, 4) current_from_previous.
        step: grid step, pixels.

    Returns:
        None when no pixel with depth lands in the image in front of the camera.
    """
    if depth.shape != mask.image_shape:
        raise ValueError(f"depth has shape {depth.shape}, expected the mask's image shape {mask.image_shape}")
    x0, y0, _, _ = mask.bbox
    vs, us = np.nonzero(mask.crop[::step, ::step])
    vs, us = vs * step + y0, us * step + x0
    z = depth[vs, us].astype(np.float64)
    ok = z > 0
    if not ok.any():
        return None
    us, vs, z = us[ok], vs[ok], z[ok]
    ray = np.linalg.solve(K, np.stack([us, vs, np.ones_like(z)]))  # (3, N)
    cam = T[:3, :3] @ (ray * z) + T[:3, 3:4]
    front = cam[2] > 1e-3
    cam = cam[:, front]
    if cam.shape[1] == 0:
        return None
    proj = K @ (cam / cam[2])
    h, w = mask.image_shape
    ui, vi = np.rint(proj[0]).astype(np.int64), np.rint(proj[1]).astype(np.int64)
    inside = (ui >= 0) & (vi >= 0) & (ui < w) & (vi < h)
    if not inside.any():
        return None
    ui, vi, zi = ui[inside], vi[inside], cam[2, inside].astype(np.float32)
    r = step // 2
    bx0, by0 = max(int(ui.min()) - r, 0), max(int(vi.min()) - r, 0)
    bx1, by1 = min(int(ui.max()) + r + 1, w), min(int(vi.max()) + r + 1, h)
    crop = np.zeros((by1 - by0, bx1 - bx0), np.float32)
    crop[vi - by0, ui - bx0] = zi  # one object's own points: any of them may take a pixel
    far = np.where(crop > 0, crop, np.float32(np.inf))
    near = (
        far if r == 0 else cv2.erode(far, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    )  # splat: nearest depth
    return bx0, by0, np.where(np.isfinite(near), near, 0.0).astype(np.float32)


def _jump(z: np.ndarray, fx: float, seg: SegmentationConfig) -> np.ndarray:
    """The segmentation's depth-discontinuity threshold at depth ``z``, metres."""
    return np.maximum(
        np.maximum(np.float32(seg.jump_min), z * np.float32(seg.jump_footprints / fx)),
        np.float32(seg.jump_sigmas) * seg.noise.sigma(z),
    )


def _refine(
    frame: RGBDFrame, x0: int, y0: int, pred: np.ndarray, plane: Plane | None, r: int, seg: SegmentationConfig
) -> tuple[int, int, np.ndarray]:
    """Step 2 of the module docstring: ``(x0, y0, bool crop)`` of the refined mask."""
    h, w = frame.shape
    gx0, gy0 = max(x0 - r, 0), max(y0 - r, 0)
    gx1, gy1 = min(x0 + pred.shape[1] + r, w), min(y0 + pred.shape[0] + r, h)
    z_pred = np.zeros((gy1 - gy0, gx1 - gx0), np.float32)
    z_pred[y0 - gy0 : y0 - gy0 + pred.shape[0], x0 - gx0 : x0 - gx0 + pred.shape[1]] = pred
    warped = z_pred > 0
    kernel = np.ones((2 * r + 3, 2 * r + 3), np.uint8)
    hi = cv2.dilate(z_pred, kernel)
    lo = cv2.erode(np.where(warped, z_pred, np.float32(np.inf)), kernel)
    z = frame.depth[gy0:gy1, gx0:gx1]
    j = _jump(z, float(frame.K[0, 0]), seg)
    reach = cv2.dilate(warped.view(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)).view(bool)
    ok = (z > 0) & (z >= lo - j) & (z <= hi + j)
    if plane is not None:  # a new pixel must also be foreground
        K = frame.K.copy()
        K[0, 2] -= gx0
        K[1, 2] -= gy0
        height = plane_height(z, K, plane)
        sigma = seg.noise.sigma(z)
        fg = (height > np.maximum(np.float32(seg.min_height), np.float32(seg.height_sigmas) * sigma)) & (
            height < seg.max_height
        )
        ok &= warped | fg
    return gx0, gy0, fill_invalid_holes(reach & (ok | (warped & (z <= 0))), z <= 0)


def propagate_masks(
    masks: dict[int, Mask],
    previous_depth: np.ndarray,
    frame: RGBDFrame,
    T: np.ndarray,
    plane: Plane | None,
    config: PropagationConfig,
    segmentation: SegmentationConfig,
    keep: Callable[[int, Mask], float | None] | None = None,
) -> list[Candidate]:
    """This frame's candidates from the previous frame's masks (module docstring).

    Args:
        masks: the previous frame's masks by object id.
        previous_depth: (H, W) the previous frame's depth, metres.
        frame: this frame (same shape and intrinsics).
        T: (4, 4) current_from_previous, the camera's motion.
        plane: this frame's support plane (camera frame), or None.
        config: propagation parameters.
        segmentation: the depth-discontinuity and foreground thresholds.
        keep: ``keep(id, mask)``: the mask's metric size, m², or None to drop it (the
            segmentation's size rules); None keeps every mask of ``min_area`` pixels.

    Returns:
        candidates labelled with their object's id, in increasing id order (the masks that
        survive refinement and occlusion).
    """
    if previous_depth.shape != frame.shape:
        raise ValueError(
            f"previous depth has shape {previous_depth.shape}, expected the frame's {frame.shape}"
        )
    scale = frame.width / 640.0
    step, r = max(1, round(config.step * scale)), round(config.border * scale)
    refined = []
    for tid, mask in masks.items():
        warped = warp_mask(mask, previous_depth, frame.K, T, step)
        if warped is None:
            continue
        x0, y0, pred = warped
        gx0, gy0, crop = _refine(frame, x0, y0, pred, plane, r, segmentation)
        if crop.any():
            refined.append((float(np.median(pred[pred > 0])), tid, gx0, gy0, crop))
    labels = np.zeros(frame.shape, np.int32)
    for _, tid, x0, y0, crop in sorted(refined, key=lambda item: -item[0]):  # far to near
        h, w = crop.shape
        labels[y0 : y0 + h, x0 : x0 + w][crop] = tid
    min_area = max(1, round(config.min_area * scale * scale))
    out = []
    for _, tid, x0, y0, crop in sorted(refined, key=lambda item: item[1]):
        h, w = crop.shape
        own = labels[y0 : y0 + h, x0 : x0 + w] == tid
        if int(np.count_nonzero(own)) < min_area:
            continue
        mask = Mask.from_crop(own, x0, y0, frame.shape)
        size = 0.0 if keep is None else keep(tid, mask)
        if size is not None:
            out.append(Candidate(mask, tid, size))
    return out
