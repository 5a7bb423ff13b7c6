"""ŝ_vis(t), the output of the perceptual pipeline (:mod:`pal.perception.pipeline`) for one frame.

:class:`PerceptionState` holds the scene descriptor, the relational layer, the camera's motion
and one :class:`ObjectState` per remembered object (Eq. 4.6-4.7).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from pal.perception.egomotion import CameraMotion
from pal.perception.masks import Mask
from pal.perception.memory import AdmissionDecision
from pal.perception.plane import Plane
from pal.perception.relations import SceneRelations
from pal.perception.spatial import SpatialDescriptor
from pal.perception.trajectory import Pose

__all__ = ["ObjectState", "PerceptionState", "require_finite_positions"]


@dataclass(frozen=True, eq=False)
class ObjectState:
    """ŝ_i^obj(t) for one remembered object (Eq. 4.7).

    Attributes:
        obj_id: stable id.
        visible: associated in this frame.
        status: ``"born"``, ``"tracked"``, ``"reidentified"``, or None when not visible.
        label: latest segmenter label (the ground-truth id with the oracle segmenter).
        mask: this frame's mask, or None.
        spatial: egocentric spatial descriptor, or None (not visible / no depth).
        pose: this frame's pose sample (estimated / propagated / lost), or None when pose
            estimation is off.
        position: (3,) metres, camera frame, or None (missing — never NaN).
        position_std: (3,) 1-sigma uncertainty, metres, or None.
        position_source: ``"pose"``, ``"centroid"`` or None.
        num_snapshots: EEMS gallery size.
        admission: this frame's EEMS admission decision, or None.
    """

    obj_id: int
    visible: bool
    status: str | None
    label: int
    mask: Mask | None
    spatial: SpatialDescriptor | None
    pose: Pose | None
    position: np.ndarray | None
    position_std: np.ndarray | None
    position_source: str | None
    num_snapshots: int
    admission: AdmissionDecision | None


@dataclass(frozen=True, eq=False)
class PerceptionState:
    """ŝ_vis(t) = ŝ_scene(t) ∪ [ŝ_i^obj(t)] (Eq. 4.6).

    Attributes:
        timestamp: s. frame_index: 0-based frame counter.
        objects: the objects alive in memory (seen within the re-identification window), by id.
        scene: the Table 5.6 descriptor (JSON-compatible dict).
        relations: the relational layer, or None when disabled.
        timings: seconds spent per stage in this frame.
        camera: the camera's motion since the previous frame (None when the camera is
            configured static).
        support: the support plane of this frame (None with the oracle segmenter or without one).
        merges: fragments merged in this frame, ``(kept id, merged id)``
            (:mod:`pal.perception.fragments`; reported under the kept id from the next frame).
    """

    timestamp: float
    frame_index: int
    objects: tuple[ObjectState, ...]
    scene: dict[str, Any]
    relations: SceneRelations | None
    timings: dict[str, float]
    camera: CameraMotion | None = None
    support: Plane | None = None
    merges: tuple[tuple[int, int], ...] = ()

    def object(self, obj_id: int) -> ObjectState:
        """The state of object ``obj_id``; KeyError if it is not in this frame's state."""
        for o in self.objects:
            if o.obj_id == obj_id:
                return o
        raise KeyError(f"object {obj_id} is not in this state; ids are {[o.obj_id for o in self.objects]}")

    def observations(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """``{obj_id: (position (3,), std (3,))}`` in metres, only for objects with evidence now."""
        return {
            o.obj_id: (o.position, o.position_std)
            for o in self.objects
            if o.position is not None and o.position_std is not None
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible summary: scene descriptor, relations, camera motion and timings."""
        return {
            "scene": self.scene,
            "relations": None if self.relations is None else self.relations.to_dict(),
            "camera": None if self.camera is None else self.camera.to_dict(),
            "timings": dict(self.timings),
        }


def require_finite_positions(objects: tuple[ObjectState, ...]) -> None:
    """Raise ``RuntimeError`` naming the object when a reported position or its std is not finite."""
    for o in objects:
        if o.position is not None and not (
            np.all(np.isfinite(o.position))
            and o.position_std is not None
            and np.all(np.isfinite(o.position_std))
        ):
            raise RuntimeError(
                f"internal error: object {o.obj_id} has a non-finite position {o.position} / std {o.position_std}"
            )
