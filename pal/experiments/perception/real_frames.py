"""Π on the real RGB-D samples: support plane, ids, poses against the inverse camera motion.

The samples (:mod:`pal.perception.samples`) are static scenes seen by a moving camera, so
every object's motion in the camera frame between two frames is the inverse of the camera's
motion: ``camera_from_object(j) = T_ji camera_from_object(i)`` with ``T_ji`` the camera's
``current_from_previous``. That is the ground truth of this evaluation, for every object Π
finds, without labels. Per consecutive frame pair (i, j) of a sample:

- the **reference motion** ``T_ji``: the sample's camera poses where it has them (the room's
  ``pose.txt``: ``inverse(world_from_camera_j) world_from_camera_i``), else the motion Π
  estimates from the background (the desk pair has no ground truth; the estimate is compared
  with the published one, 4.1 degrees and (-0.136, -0.002, 0.065) m). Errors against Π's own
  camera estimate are reported for every pair too;
- an object of frame i is **seen in both frames** when its mask, moved by the reference motion
  (its depth points lifted, moved, projected), and one of frame j's objects are each other's
  best overlap, with an IoU of at least ``seen_iou``; it **keeps its id** when that object has
  its id;
- an object that keeps its id **has a pose** when its poses in both frames are ``estimated``;
  its **error** is the rotation angle and the origin's distance between ``camera_from_object(j)``
  and ``T_ji camera_from_object(i)``; a pose more than 10 degrees or 5 cm wrong is *wrong*; the
  solver of the frame-j pose is counted (``pnp`` from features, ``icp`` the dense fallback,
  which starts at the camera motion's prediction, so its share is reported);
- the **support plane** of every frame is chosen with seeds ``0 .. support_seeds - 1`` and
  compared with the reference plane of the sample's ``support.json`` (a robust fit to a box that
  shows only the desk or the floor): it is that surface when its normal is within 5 degrees and
  its offset within 5 cm;
- the **relations** of every frame are checked without labels
  (:mod:`pal.experiments.perception.relation_checks`): far pairs not near, hidden bottoms not
  resting on the support.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from pal.checks import check_float, check_int
from pal.experiments.perception.evaluation import rotation_angle_deg
from pal.experiments.perception.relation_checks import merge_relation_checks, relation_checks
from pal.experiments.perception.runs import names
from pal.io.sequence_files import SequenceError
from pal.perception import PerceptionState, Pipeline, PipelineConfig
from pal.perception.association import predict_mask, surface_sample
from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import iou
from pal.perception.plane import Plane, fit_plane_ransac
from pal.perception.samples import SAMPLES, open_sample, support_regions
from pal.perception.segmentation import GeometricSegmenter, SegmentationConfig

__all__ = [
    "PUBLISHED_DESK_MOTION",
    "WRONG_DEG",
    "WRONG_M",
    "RealConfig",
    "evaluate_real",
    "pair_rows",
    "reference_plane",
    "summarise",
    "support_check",
]

#: The published ORB + PnP estimate of the desk pair's camera motion: (rotation deg, t (3,) m).
PUBLISHED_DESK_MOTION = (4.1, (-0.136, -0.002, 0.065))
#: An estimated pose further from the reference than this is wrong: degrees and metres.
WRONG_DEG, WRONG_M = 10.0, 0.05


@dataclass(frozen=True)
class RealConfig:
    """What the real-frame evaluation runs.

    Attributes:
        samples: sample sets (keys of :data:`pal.perception.samples.SAMPLES`).
        frames: frames of each sample used (from the first; None: all).
        support_seeds: seeds of the support-plane check (0 .. n - 1).
        seen_iou: IoU of a moved mask with an object of the next frame for "seen in both".
    """

    samples: tuple[str, ...] = SAMPLES
    frames: int | None = None
    support_seeds: int = 10
    seen_iou: float = 0.3

    def __post_init__(self) -> None:
        object.__setattr__(self, "samples", names("samples", self.samples, list(SAMPLES)))
        if self.frames is not None:
            check_int("frames", self.frames, minimum=2)
        check_int("support_seeds", self.support_seeds)
        check_float("seen_iou", self.seen_iou, 0.0, 1.0, open_low=True)


def reference_plane(frame: RGBDFrame, box: tuple[int, int, int, int]) -> Plane:
    """The plane of the surface a pixel box shows: RANSAC (2 cm, seed 0) on its valid depth."""
    x0, y0, x1, y1 = box
    z = frame.depth[y0:y1, x0:x1]
    v, u = np.nonzero(z > 0)
    return fit_plane_ransac(backproject(u + x0, v + y0, z[v, u], frame.K), 0.02, np.random.default_rng(0))


def _same_plane(a: Plane | None, b: Plane) -> tuple[bool, float | None, float | None]:
    if a is None:
        return False, None, None
    angle = float(np.degrees(np.arccos(np.clip(abs(a.normal @ b.normal), -1.0, 1.0))))
    offset = abs(a.offset - b.offset)
    return angle <= 5.0 and offset <= 0.05, angle, offset


def support_check(
    name: str, frames: list[RGBDFrame], stems: list[str], seeds: int, config: SegmentationConfig
) -> dict[str, Any]:
    """The support plane of every frame for seeds ``0 .. seeds - 1`` against the reference plane."""
    surface, regions = support_regions(name)
    rows = []
    for frame, stem in zip(frames, stems, strict=True):
        ref = reference_plane(frame, regions[stem])
        for seed in range(seeds):
            seg = GeometricSegmenter(config, rng=seed)
            ok, angle, offset = _same_plane(seg.fit_plane(frame), ref)
            rows.append({"frame": stem, "seed": seed, "ok": ok, "angle_deg": angle, "offset_m": offset})
    return {
        "surface": surface,
        "checks": len(rows),
        "correct": sum(r["ok"] for r in rows),
        "worst_angle_deg": max((r["angle_deg"] for r in rows if r["angle_deg"] is not None), default=None),
        "worst_offset_m": max((r["offset_m"] for r in rows if r["offset_m"] is not None), default=None),
        "rows": rows,
    }


def _motion(T: np.ndarray) -> tuple[float, list[float]]:
    return rotation_angle_deg(np.eye(3), T[:3, :3]), [float(v) for v in T[:3, 3]]


def _pose_error(Ti: np.ndarray, Tj: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    want = ref @ Ti
    return rotation_angle_deg(Tj[:3, :3], want[:3, :3]), float(np.linalg.norm(Tj[:3, 3] - want[:3, 3]))


def pair_rows(
    fi: RGBDFrame, fj: RGBDFrame, si: PerceptionState, sj: PerceptionState, ref: np.ndarray, seen_iou: float
) -> list[dict[str, Any]]:
    """One row per object of frame i seen in both frames (module docstring)."""
    step = max(2, fi.width // 160)
    later = [o for o in sj.objects if o.visible and o.mask is not None]
    earlier = [o for o in si.objects if o.visible and o.mask is not None]
    camera = sj.camera.current_from_previous if sj.camera is not None else None
    preds = [predict_mask(surface_sample(fi, o.mask, step), ref, fj.K, fj.shape, step) for o in earlier]  # type: ignore[arg-type]
    overlap = np.array(
        [[0.0 if p is None else iou(p, q.mask) for q in later] for p in preds]  # type: ignore[arg-type]
    ).reshape(len(earlier), len(later))
    rows = []
    for a, o in enumerate(earlier):
        if not later:
            break
        best = int(np.argmax(overlap[a]))
        if overlap[a, best] < seen_iou or int(np.argmax(overlap[:, best])) != a:
            continue  # not seen in both: no mutual best overlap under the reference motion
        overlaps = overlap[a]
        match = later[best]
        row: dict[str, Any] = {
            "obj_id": o.obj_id,
            "matched_id": match.obj_id,
            "iou": overlaps[best],
            "kept": match.obj_id == o.obj_id,
            "pose": False,
            "source": None,
            "solver": None,
            "rot_err_deg": None,
            "trans_err_m": None,
            "rot_err_camera_deg": None,
            "trans_err_camera_m": None,
            "rot_err_still_deg": None,
            "trans_err_still_m": None,
            "reason": None,
            "area_px": o.mask.area,
            "area_change": abs(float(np.log(match.mask.area / o.mask.area))),
        }
        if row["kept"]:
            pi, pj = o.pose, match.pose
            row["source"] = None if pj is None else pj.source
            row["solver"] = None if pj is None else pj.diagnostics.solver
            row["reason"] = None if pj is None else pj.diagnostics.reason.split(";")[0]
            if pj is not None and pj.source == "rejected":
                row["reason"] = "; ".join(pj.diagnostics.checks)
            if pi is not None and pj is not None and pi.is_valid and pj.is_valid:
                Ti, Tj = pi.camera_from_object, pj.camera_from_object
                assert Ti is not None and Tj is not None
                row["pose"] = True
                row["rot_err_deg"], row["trans_err_m"] = _pose_error(Ti, Tj, ref)
                row["rot_err_still_deg"], row["trans_err_still_m"] = _pose_error(Ti, Ti, ref)
                if camera is not None:
                    row["rot_err_camera_deg"], row["trans_err_camera_m"] = _pose_error(Ti, Tj, camera)
        rows.append(row)
    return rows


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Totals over pair rows: ids kept, share posed, median errors beside no motion's, wrong, reasons."""
    kept = [r for r in rows if r["kept"]]
    posed = [r for r in kept if r["pose"]]
    wrong = [r for r in posed if r["rot_err_deg"] > WRONG_DEG or r["trans_err_m"] > WRONG_M]
    return {
        "seen_in_both": len(rows),
        "kept_id": len(kept),
        "kept_fraction": len(kept) / len(rows) if rows else None,
        "with_pose": len(posed),
        "pose_fraction": len(posed) / len(kept) if kept else None,
        "rot_err_deg_median": _median([r["rot_err_deg"] for r in posed]),
        "trans_err_m_median": _median([r["trans_err_m"] for r in posed]),
        "rot_err_camera_deg_median": _median(
            [r["rot_err_camera_deg"] for r in posed if r["rot_err_camera_deg"] is not None]
        ),
        "trans_err_camera_m_median": _median(
            [r["trans_err_camera_m"] for r in posed if r["trans_err_camera_m"] is not None]
        ),
        "rot_err_still_deg_median": _median([r["rot_err_still_deg"] for r in posed]),
        "trans_err_still_m_median": _median([r["trans_err_still_m"] for r in posed]),
        "rot_better_than_still": (
            sum(r["rot_err_deg"] < r["rot_err_still_deg"] for r in posed) / len(posed) if posed else None
        ),
        "area_change_median": _median([r["area_change"] for r in kept]),
        "wrong_estimated": len(wrong),
        "rejected": sum(r["source"] == "rejected" for r in kept),
        "without_pose_reasons": dict(Counter(str(r["reason"]) for r in kept if not r["pose"]).most_common(5)),
        "pose_solvers": dict(Counter(str(r["solver"]) for r in posed)),
    }


def evaluate_sample(
    name: str, config: RealConfig, pipeline: PipelineConfig, seed: int
) -> tuple[dict[str, Any], list[RGBDFrame], list[PerceptionState]]:
    """Run Π over one sample and score it (module docstring); returns (metrics, frames, states)."""
    seq = open_sample(name)
    n = len(seq) if config.frames is None else min(config.frames, len(seq))
    frames = [seq[k] for k in range(n)]
    pipe = Pipeline(PipelineConfig(**{**pipeline.__dict__, "seed": seed}))
    states = [pipe(f) for f in frames]
    try:
        poses = seq.camera_poses()
    except SequenceError:
        poses = None
    world = None if poses is None or not poses.valid[:n].all() else poses.poses[:n]
    pairs, rows = [], []
    for k in range(n - 1):
        cam = states[k + 1].camera
        estimate = None if cam is None else cam.current_from_previous
        ref = estimate if world is None else np.linalg.inv(world[k + 1]) @ world[k]
        if ref is None:
            raise ValueError(
                f"{name}: no reference motion for frames {k}-{k + 1} (camera motion off, no poses)"
            )
        pair_rows_ = pair_rows(frames[k], frames[k + 1], states[k], states[k + 1], ref, config.seen_iou)
        rows += pair_rows_
        entry = {
            "frames": [seq.stems[k], seq.stems[k + 1]],
            "reference": "estimated from the background" if world is None else "camera poses",
            "reference_motion": dict(zip(("rotation_deg", "translation"), _motion(ref), strict=True)),
            "camera": None if cam is None else cam.to_dict(),
            "objects": len([o for o in states[k].objects if o.visible]),
            **summarise(pair_rows_),
        }
        if world is not None and estimate is not None:
            entry["camera_vs_reference"] = {
                "rot_deg": rotation_angle_deg(estimate[:3, :3], ref[:3, :3]),
                "trans_m": float(np.linalg.norm(estimate[:3, 3] - ref[:3, 3])),
            }
        pairs.append(entry)
    metrics = {
        "frames": n,
        "pairs": pairs,
        "objects_per_frame": [sum(o.visible for o in s.objects) for s in states],
        **summarise(rows),
        "rows": rows,
        "support": support_check(name, frames, seq.stems[:n], config.support_seeds, pipeline.segmentation),
        "relations": relation_checks(states),
    }
    return metrics, frames, states


def evaluate_real(
    config: RealConfig, pipeline: PipelineConfig | None = None, seed: int = 0
) -> dict[str, Any]:
    """Every sample of ``config`` scored, and the totals over them (module docstring)."""
    pipeline = pipeline or PipelineConfig()
    per = {name: evaluate_sample(name, config, pipeline, seed)[0] for name in config.samples}
    rows = [r for m in per.values() for r in m["rows"]]
    support = [m["support"] for m in per.values()]
    desk = per.get("tum_desk")
    published = None
    if desk is not None and desk["pairs"] and desk["pairs"][0]["camera"] is not None:
        cam = desk["pairs"][0]["camera"]
        published = {
            "rotation_deg": cam["rotation_deg"],
            "published_rotation_deg": PUBLISHED_DESK_MOTION[0],
            "translation_diff_m": float(
                np.linalg.norm(np.subtract(cam["translation"], PUBLISHED_DESK_MOTION[1]))
            ),
        }
    return {
        "samples": per,
        "total": summarise(rows),
        "support_correct": sum(s["correct"] for s in support),
        "support_checks": sum(s["checks"] for s in support),
        "desk_camera_vs_published": published,
        "relations": merge_relation_checks([m["relations"] for m in per.values()]),
    }
