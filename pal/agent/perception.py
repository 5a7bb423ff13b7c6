"""The agent's visual front end: o(t) -> Π -> object variables in table coordinates (thesis Eq. 4.2).

Four steps, none of which needs the world model:

1. **Self-filter.** The agent removes its own body from the depth image before Π sees it (the
   pixels its self-model renders, :meth:`pal.sim.pushing.PushingEnv.arm_mask`), so the arm is not
   segmented as an object. Depth 0 marks those pixels invalid; RGB is untouched.
2. **Π.** :class:`pal.perception.Pipeline` (geometric segmentation, tracking with stable ids, pose
   with estimated / propagated / lost flags). Its :meth:`~pal.perception.PerceptionState.observations`
   give each object's position (3,) and 1-sigma uncertainty (3,) in the camera frame, derived from
   the pose diagnostics (or the mask's spread when no pose was estimated); objects without
   evidence are absent, never NaN.
3. **Object variable.** Π reports the pose origin (a point fixed on the object where its first view's
   surface was) or the centroid of the visible surface; both sit on the near face and slide over
   the object as it turns. The agent's object variable is instead the centre of the object's top
   surface in the table plane (:func:`top_centre`): Π's mask is lifted to 3-D with the depth, and
   the points within ``band`` (1.2 cm) of the highest one are averaged. For a box standing on the table
   and for a ball this is the centre of the footprint, whatever the yaw. Its 1-sigma uncertainty
   is the larger of Π's (from the pose diagnostics, when the pose was estimated) and the standard
   error of the top points, with a floor. Π's own position is used when the top has too few points.
4. **Slots.** World-model variables are named per object slot (``pos.box``, ...). :class:`ObjectSlots`
   binds track ids to slots: at the first frame that shows as many objects as there are slots, in
   order of decreasing apparent metric size (slot names are given largest object first). Then every
   frame each slot takes the cheapest track within ``gate`` metres of its current estimate (or last
   measurement) whose apparent metric size (mask area x (depth / f)^2) and top height are close to
   the slot's running ones; the cost is distance / 5 cm + |log size ratio| / 0.3 + height change /
   5 mm + 0.5 for a change of track id. So a box is not mistaken for a ball, and a blob of two
   touching objects stands for neither.
   Positions are mapped to the table frame with the calibrated camera pose: ``p = R p_c + t`` and
   ``Sigma = R diag(std_c^2) R^T``; the variables are the (x, y) components.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pal.perception import Mask, PerceptionState, RGBDFrame
from pal.perception.spatial import mask_points

__all__ = ["Measurement", "ObjectSlots", "self_filtered_frame", "to_table", "top_centre"]


def self_filtered_frame(
    rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, timestamp: float, body_mask: np.ndarray
) -> RGBDFrame:
    """An :class:`RGBDFrame` whose depth is 0 (invalid) on the agent's own body.

    Args:
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32, metres.
        K: (3, 3) camera intrinsics, pixels.
        timestamp: frame time, s.
        body_mask: (H, W) bool, True on the agent's body.
    """
    mask = np.asarray(body_mask, dtype=bool)
    if mask.shape != np.asarray(depth).shape:
        raise ValueError(f"body_mask has shape {mask.shape}, expected {np.asarray(depth).shape} like depth")
    return RGBDFrame(rgb, np.where(mask, 0.0, depth).astype(np.float32), K, float(timestamp))


def to_table(
    position: np.ndarray, std: np.ndarray, table_from_camera: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Map a camera-frame position (3,) and per-axis std (3,) to the table frame.

    Returns:
        ``(p (3,), std (3,))``: ``p = R p_c + t`` and the sqrt of the diagonal of ``R diag(std^2) R^T``.
    """
    T = np.asarray(table_from_camera, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(
            f"table_from_camera has shape {T.shape} or non-finite entries; expected a finite (4, 4)"
        )
    R = T[:3, :3]
    p = R @ np.asarray(position, dtype=np.float64) + T[:3, 3]
    cov = R @ np.diag(np.asarray(std, dtype=np.float64) ** 2) @ R.T
    return p, np.sqrt(np.clip(np.diag(cov), 0.0, None))


def top_centre(
    frame: RGBDFrame, mask: Mask, table_from_camera: np.ndarray, band: float = 0.012, min_points: int = 12
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Table-plane centre (2,) of an object's top surface, its standard error (2,) and its height, metres.

    The mask's pixels with depth are lifted to the table frame; the points within ``band`` m of
    the highest are the top; their mean (x, y) is the centre, ``std / sqrt(n)`` its error and
    their median z the height. None with fewer than ``min_points`` top points.
    """
    pts = mask_points(frame, mask)
    if pts.shape[0] < min_points:
        return None
    T = np.asarray(table_from_camera, dtype=np.float64)
    table = pts @ T[:3, :3].T + T[:3, 3]
    top = table[table[:, 2] >= table[:, 2].max() - band]
    if top.shape[0] < min_points:
        return None
    return top[:, :2].mean(0), top[:, :2].std(0) / np.sqrt(top.shape[0]), float(np.median(top[:, 2]))


@dataclass(frozen=True)
class Measurement:
    """One perceived object variable o_obs(t).

    Attributes:
        position: (2,) table-plane (x, y), metres.
        std: (2,) 1-sigma uncertainty, metres (> 0).
        obj_id: the perception track id.
        source: ``"top"`` (top-surface centre), ``"pose"`` (Π's estimated pose) or ``"centroid"``
            (Π's visible-surface centroid).
        size: apparent metric size, m^2: mask area x (depth / f)^2 (0 when unknown).
        height: height of the top surface above the table, m (0 when unknown).
    """

    position: np.ndarray
    std: np.ndarray
    obj_id: int
    source: str
    size: float = 0.0
    height: float = 0.0


class ObjectSlots:
    """Binds perception track ids to the world model's object slots (module docstring).

    Args:
        names: slot names, largest object first (e.g. ``("box", "ball")``).
        gate: largest distance, m, between a slot's current estimate and the track it takes.
        min_std: floor of the reported std, m (a measurement is never certain).
        use_top: read positions as top-surface centres (False: Π's positions as reported).
        max_size_ratio: largest ``|log(size / slot size)|`` a track may have to stand for a slot: a
            blob of two merged objects, or a mostly hidden one, is not taken for either.
        max_height_change: largest change of the top's height (m) a track may have to stand for a
            slot (the top of a 6 cm box and of an 8 cm ball tell them apart when one is half hidden).
    """

    def __init__(
        self,
        names: Sequence[str],
        gate: float = 0.3,
        min_std: float = 0.002,
        use_top: bool = True,
        max_size_ratio: float = 0.7,
        max_height_change: float = 0.012,
    ) -> None:
        names = tuple(names)
        if not names or len(set(names)) != len(names):
            raise ValueError(f"slot names {names!r} must be distinct and non-empty")
        if not (gate > 0 and min_std > 0):
            raise ValueError(f"gate ({gate}) and min_std ({min_std}) must be > 0 metres")
        self.names, self.gate, self.min_std, self.use_top = names, float(gate), float(min_std), bool(use_top)
        self.max_size_ratio, self.max_height_change = float(max_size_ratio), float(max_height_change)
        self.reset()

    def reset(self) -> None:
        """Forget every binding (a new episode)."""
        self.bound: dict[str, int] = {}
        self.last: dict[str, np.ndarray] = {}
        self.size: dict[str, float] = {}
        self.height: dict[str, float] = {}

    @property
    def ready(self) -> bool:
        """True once every slot has been bound at least once."""
        return len(self.bound) == len(self.names)

    def update(
        self,
        state: PerceptionState,
        table_from_camera: np.ndarray,
        reference: dict[str, Any] | None = None,
        focal: float = 1.0,
        frame: RGBDFrame | None = None,
    ) -> dict[str, Measurement | None]:
        """This frame's measurement per slot, None for a slot without evidence (lost or not yet bound).

        Args:
            state: Π's output.
            table_from_camera: (4, 4) camera pose in the table frame.
            reference: optional slot -> (2,) current estimate; a missing slot is re-bound to the
                nearest unbound track around it (default: around its last measurement).
            focal: focal length of the frame, pixels (for the apparent metric size).
            frame: the frame Π saw; with it, positions are top-surface centres (module docstring).
        """
        self.focal = float(focal)
        obs = {}
        for oid, (p, s) in state.observations().items():
            pt, st = to_table(p, s, table_from_camera)
            obj = state.object(oid)
            size = 0.0 if obj.mask is None else obj.mask.area * (float(p[2]) / self.focal) ** 2
            source = obj.position_source or "centroid"
            xy, std, height = pt[:2], np.maximum(st[:2], self.min_std), 0.0
            top = None
            if self.use_top and frame is not None and obj.mask is not None:
                top = top_centre(frame, obj.mask, table_from_camera)
            if top is not None:
                pose_std = st[:2] if source == "pose" else np.zeros(2)
                xy, std, source = top[0], np.maximum(np.maximum(top[1], pose_std), self.min_std), "top"
                height = top[2]
            obs[oid] = Measurement(xy, std, oid, source, size, height)
        if not self.ready:
            if len(obs) < len(self.names):
                return dict.fromkeys(self.names)
            order = sorted(obs, key=lambda oid: (-obs[oid].size, oid))
            self.bound = {name: order[i] for i, name in enumerate(self.names)}
            return self._report(obs, dict(self.bound))
        ref = {
            n: np.asarray(reference[n], float)
            for n in self.names
            if reference and reference.get(n) is not None
        }
        ref = {n: ref.get(n, self.last.get(n)) for n in self.names}
        pairs = []
        for n in self.names:
            for oid, m in obs.items():
                dist = 0.0 if ref[n] is None else float(np.linalg.norm(m.position - ref[n]))
                look = (
                    abs(np.log(max(m.size, 1e-9) / self.size[n])) if self.size.get(n) and m.size > 0 else 0.0
                )
                rise = abs(m.height - self.height[n]) if self.height.get(n) and m.height > 0 else 0.0
                if dist > self.gate or look > self.max_size_ratio or rise > self.max_height_change:
                    continue
                cost = dist / 0.05 + look / 0.3 + rise / 0.005 + (0.0 if self.bound.get(n) == oid else 0.5)
                pairs.append((cost, n, oid))
        matched: dict[str, int] = {}
        for _, name, oid in sorted(pairs):  # greedy: cheapest (distance, apparent size, id change) first
            if name not in matched and oid not in matched.values():
                matched[name] = oid
        self.bound.update(matched)
        return self._report(obs, matched)

    def _report(self, obs: dict[int, Measurement], matched: dict[str, int]) -> dict[str, Measurement | None]:
        out: dict[str, Measurement | None] = {}
        for name in self.names:
            m = obs.get(matched[name]) if name in matched else None
            out[name] = m
            if m is not None:
                self.last[name] = m.position.copy()
                if m.size > 0:
                    old = self.size.get(name)
                    self.size[name] = m.size if old is None else 0.9 * old + 0.1 * m.size
                if m.height > 0:
                    old = self.height.get(name)
                    self.height[name] = m.height if old is None else 0.9 * old + 0.1 * m.height
        return out
