"""The structured scene descriptor of thesis Table 5.6: a JSON-serialisable snapshot of memory.

Keys (exactly these; ``null`` where evidence is missing)::

    timestamp            s, the current frame's
    frame_count          frames processed
    num_objects          object records in memory (alive or not)
    num_visible_objects  records seen within ``visible_window_s`` (2.0 s)
    objects: [           sorted by obj_id
      obj_id             stable id
      visible            seen within ``visible_window_s``
      age_s              now - first seen, s
      last_updated       timestamp of the last association, s
      is_busy            always false (pose estimation runs synchronously here)
      bbox               {xyxy [x0, y0, x1, y1] (x1, y1 exclusive), xywh, centroid [u, v] (mask
                          centroid, float pixels), area (mask pixels)} of the last mask
      num_snapshots      EEMS gallery size
      num_poses          pose samples (all sources)
      num_valid_poses    estimated pose samples
      has_pose           num_valid_poses > 0
      pose               {position [m], orientation (rotation vector, rad), timestamp} of the last
                          *estimated* pose, or null
      velocity           {linear [m/s], dt_s} from the last two estimated poses, or null
      last_pose_diagnostics  the latest pose attempt's diagnostics (dict) or null
    ]

The relational layer (pairwise relations, scene graph, vector) is exported separately by
:mod:`pal.perception.relations`, so this schema stays exactly the thesis's.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pal.perception.memory import ObjectRecord

__all__ = ["OBJECT_KEYS", "SCENE_KEYS", "object_descriptor", "scene_descriptor"]

SCENE_KEYS: tuple[str, ...] = ("timestamp", "frame_count", "num_objects", "num_visible_objects", "objects")
OBJECT_KEYS: tuple[str, ...] = (
    "obj_id",
    "visible",
    "age_s",
    "last_updated",
    "is_busy",
    "bbox",
    "num_snapshots",
    "num_poses",
    "num_valid_poses",
    "has_pose",
    "pose",
    "velocity",
    "last_pose_diagnostics",
)


def _floats(x: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(x, dtype=np.float64).ravel()]


def object_descriptor(
    record: ObjectRecord, timestamp: float, visible_window_s: float = 2.0
) -> dict[str, Any]:
    """The per-object entry of the scene descriptor (module docstring)."""
    mask = record.last_mask
    x0, y0, x1, y1 = mask.bbox
    cu, cv = mask.centroid()
    valid = record.trajectory.last_valid(2)
    pose = velocity = None
    if valid:
        last = valid[-1]
        pose = {
            "position": _floats(last.position),
            "orientation": _floats(last.rotvec),
            "timestamp": last.timestamp,
        }  # type: ignore[arg-type]
        if len(valid) == 2:
            dt = last.timestamp - valid[0].timestamp
            if dt > 0:
                v = (last.position - valid[0].position) / dt  # type: ignore[operator]
                velocity = {"linear": _floats(v), "dt_s": float(dt)}
    diag = record.last_pose_diagnostics
    n_valid = record.trajectory.num_valid
    return {
        "obj_id": int(record.obj_id),
        "visible": bool(timestamp - record.last_updated <= visible_window_s),
        "age_s": float(timestamp - record.first_seen),
        "last_updated": float(record.last_updated),
        "is_busy": False,
        "bbox": {
            "xyxy": [x0, y0, x1, y1],
            "xywh": [x0, y0, x1 - x0, y1 - y0],
            "centroid": [cu, cv],
            "area": int(mask.area),
        },
        "num_snapshots": len(record.gallery),
        "num_poses": len(record.trajectory),
        "num_valid_poses": int(n_valid),
        "has_pose": n_valid > 0,
        "pose": pose,
        "velocity": velocity,
        "last_pose_diagnostics": None if diag is None else diag.to_dict(),
    }


def scene_descriptor(
    records: Sequence[ObjectRecord], timestamp: float, frame_count: int, visible_window_s: float = 2.0
) -> dict[str, Any]:
    """The scene descriptor (Table 5.6) of the records in memory at ``timestamp``."""
    objects = [
        object_descriptor(r, timestamp, visible_window_s) for r in sorted(records, key=lambda r: r.obj_id)
    ]
    return {
        "timestamp": float(timestamp),
        "frame_count": int(frame_count),
        "num_objects": len(objects),
        "num_visible_objects": sum(o["visible"] for o in objects),
        "objects": objects,
    }
