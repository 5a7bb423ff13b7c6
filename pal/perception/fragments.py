"""Merging fragments that move rigidly together (opt-in: ``PipelineConfig(merge=MergeConfig())``).

A segmentation may cut one object into two pieces (a box's lid and its body, a mug and its
handle), and the tracker then follows two ids. Two tracked objects ``a`` (the older, smaller
id) and ``b`` are merged into ``a`` when, in each of ``window`` consecutive frames:

- both are visible with an *estimated* pose, ``W_i = world_from_camera @ camera_from_object``;
- their masks touch once grown by ``adjacency_px`` pixels (at 640 columns; scaled with the width);

and over those frames:

- their relative pose ``inverse(W_a) @ W_b`` changes by at most ``max_rotation_deg`` and
  ``max_translation_m`` from the window's first frame;
- at least one of them *moves*: its world pose changes by at least ``min_motion_m`` or
  ``min_rotation_deg`` over the window. Static objects all "move rigidly together" in a world
  corrected for the camera's motion, so two static neighbours are never merged.

From the next frame on, ``b``'s observations are reported under ``a``'s id with the union of
the two masks (:meth:`FragmentMerger.apply`); ``b``'s record is dropped and the merge ``(a, b)``
is listed in :attr:`pal.perception.state.PerceptionState.merges` of the frame that decided it.
The tracker keeps following both pieces (each with its own surface sample and prediction); only
what the pipeline reports is merged. Merges are never undone.

Off by default: a merge needs estimated poses of both pieces in every frame of the window, and
the thresholds were checked on synthetic scenes only.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from pal.perception.masks import Mask
from pal.perception.state import ObjectState
from pal.perception.tracking import Observation

__all__ = ["FragmentMerger", "MergeConfig"]


@dataclass(frozen=True)
class MergeConfig:
    """Thresholds of the fragment merge (module docstring).

    Attributes:
        window: consecutive frames with estimated poses of both pieces, >= 2.
        max_rotation_deg: largest change of the relative rotation over the window, degrees.
        max_translation_m: largest change of the relative translation over the window, m.
        min_motion_m: a piece whose world position moves this far over the window is moving, m.
        min_rotation_deg: a piece whose world rotation changes this much over the window is moving, degrees.
        adjacency_px: the masks must touch once grown by this many pixels (at 640 columns).
    """

    window: int = 3
    max_rotation_deg: float = 2.0
    max_translation_m: float = 0.01
    min_motion_m: float = 0.02
    min_rotation_deg: float = 5.0
    adjacency_px: int = 4

    def __post_init__(self) -> None:
        if self.window < 2:
            raise ValueError(f"window is {self.window} frames, expected >= 2")
        for name in ("max_rotation_deg", "max_translation_m", "min_motion_m", "min_rotation_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} is {getattr(self, name)}, expected > 0")
        if self.adjacency_px < 0:
            raise ValueError(f"adjacency_px is {self.adjacency_px}, expected >= 0 pixels")


def _angle_deg(R: np.ndarray) -> float:
    """Rotation angle of a (3, 3) rotation matrix, degrees."""
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _change(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """(rotation degrees, translation m) of ``inverse(A) @ B`` for (4, 4) rigid transforms."""
    D = np.linalg.inv(A) @ B
    return _angle_deg(D[:3, :3]), float(np.linalg.norm(D[:3, 3]))


def touching(a: Mask, b: Mask, grow: int) -> bool:
    """True when mask ``a`` grown by ``grow`` pixels overlaps mask ``b``."""
    x0, y0 = min(a.bbox[0], b.bbox[0]) - grow, min(a.bbox[1], b.bbox[1]) - grow
    x1, y1 = max(a.bbox[2], b.bbox[2]) + grow, max(a.bbox[3], b.bbox[3]) + grow
    ra = a.region(x0, y0, x1, y1).view(np.uint8)
    if grow > 0:
        ra = cv2.dilate(ra, np.ones((2 * grow + 1, 2 * grow + 1), np.uint8))
    return bool((ra.astype(bool) & b.region(x0, y0, x1, y1)).any())


def union(masks: Sequence[Mask]) -> Mask:
    """The union of masks of the same image."""
    full = masks[0].full()
    for m in masks[1:]:
        full |= m.full()
    return Mask.from_full(full)


class FragmentMerger:
    """Decides and applies merges of fragments that move rigidly together (module docstring).

    Attributes:
        aliases: merged id -> the id it is reported under.
    """

    def __init__(self, config: MergeConfig | None = None) -> None:
        self.config = config or MergeConfig()
        self.aliases: dict[int, int] = {}
        self._history: dict[int, deque[tuple[int, np.ndarray]]] = {}

    def target(self, obj_id: int) -> int:
        """The id ``obj_id`` is reported under (itself when never merged)."""
        while obj_id in self.aliases:
            obj_id = self.aliases[obj_id]
        return obj_id

    def apply(self, observations: Sequence[Observation]) -> list[Observation]:
        """The tracker's observations with merged pieces under one id and the union of their masks."""
        groups: dict[int, list[Observation]] = {}
        for o in observations:
            groups.setdefault(self.target(o.track_id), []).append(o)
        out = []
        for tid, group in groups.items():
            main = next((o for o in group if o.track_id == tid), group[0])
            mask = main.mask if len(group) == 1 else union([o.mask for o in group])
            out.append(replace(main, track_id=tid, mask=mask))
        return out

    def update(
        self, frame_index: int, states: Mapping[int, ObjectState], world_from_camera: np.ndarray
    ) -> list[tuple[int, int]]:
        """Record this frame's poses and decide new merges.

        Args:
            frame_index: 0-based index of this frame.
            states: this frame's object states by id.
            world_from_camera: (4, 4) the camera's pose (metres).

        Returns:
            the new merges ``(kept id, merged id)``, also added to :attr:`aliases`.
        """
        cfg = self.config
        full = []
        for i, s in states.items():
            if i in self.aliases or not s.visible or s.pose is None or not s.pose.is_valid:
                self._history.pop(i, None)
                continue
            h = self._history.setdefault(i, deque(maxlen=cfg.window))
            if h and h[-1][0] != frame_index - 1:
                h.clear()
            h.append((frame_index, world_from_camera @ s.pose.camera_from_object))  # type: ignore[operator]
            if len(h) == cfg.window:
                full.append(i)
        merges = []
        for a in sorted(full):
            for b in sorted(full):
                if b <= a or b in self.aliases or a in self.aliases:
                    continue
                ma, mb = states[a].mask, states[b].mask
                grow = round(cfg.adjacency_px * ma.image_shape[1] / 640) if ma is not None else 0
                if ma is None or mb is None or not self._rigid(a, b) or not touching(ma, mb, grow):
                    continue
                self.aliases[b] = a
                self._history.pop(b, None)
                merges.append((a, b))
        return merges

    def _rigid(self, a: int, b: int) -> bool:
        """The relative pose of ``a`` and ``b`` is constant over the window while one of them moves."""
        cfg = self.config
        ha, hb = [W for _, W in self._history[a]], [W for _, W in self._history[b]]
        moving = False
        for h in (ha, hb):
            rot, trans = _change(h[0], h[-1])
            moving |= rot >= cfg.min_rotation_deg or trans >= cfg.min_motion_m
        if not moving:
            return False
        first = np.linalg.inv(ha[0]) @ hb[0]
        for Wa, Wb in zip(ha[1:], hb[1:], strict=True):
            rot, trans = _change(first, np.linalg.inv(Wa) @ Wb)
            if rot > cfg.max_rotation_deg or trans > cfg.max_translation_m:
                return False
        return True
