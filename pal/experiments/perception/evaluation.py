"""Evaluation of the perception pipeline Π on one recorded sequence against its ground truth.

Used by experiments A1-A3 (:mod:`pal.experiments.perception.a1_kinematic` and siblings). The pipeline
sees only the frames; the ground truth (instance masks ``frame.labels`` and
``camera_from_object`` poses) is read beside it for scoring:

- **object identity**: every pipeline record is assigned the ground-truth object under most of
  its masks; the *main* record of the moved object is the one with the most such frames.
  ``tracks`` counts the records of the moved object seen in at least 5 % of the frames (1 = a
  stable id) and ``fragments`` the others (pieces split off for a frame or two, e.g. at a
  depth discontinuity inside the object).
- **pose error**: the canonical object frame is defined by the pipeline at its first good view
  (``solver == "canonical"``), so ``X = inv(T_gt(t_def)) @ T_est(t_def)`` maps the body frame
  to it; every later estimate is compared with ``T_gt(t) @ X``: translation error (cm) of the
  canonical origin and rotation error (deg) of its axes. Drift since the definition is thus
  counted in full; nothing is re-fitted per frame.
- **estimated fraction**: estimated poses / frames in which the object is in view. Propagated
  poses never count.
- **centroid error**: the reported depth centroid of the object's mask against the same
  centroid computed under the true mask (cm); meaningful for the ball, which has no pose.
- **segmentation IoU**: the main record's mask against the ground-truth mask in each frame
  with the object in view (0 when the record has no mask that frame), and the best IoU of any
  candidate for every object in view.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pal.perception import KinematicConfig, Pipeline, PipelineConfig, RecordedSequence, trajectory_descriptor
from pal.perception.masks import Mask, iou
from pal.perception.spatial import spatial_descriptor

__all__ = ["RunResult", "evaluate_sequence", "rotation_angle_deg"]

#: Estimated fraction needed for a trajectory to count as usable in the motion space (the
#: thesis's footnote 17: most of the motion supported by geometric estimates).
USABLE_FRACTION = 0.8


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle of the rotation ``Ra^T Rb``, degrees."""
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _stat(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


@dataclass(frozen=True, eq=False)
class RunResult:
    """Scores and descriptors of one run (module docstring for the definitions).

    Attributes:
        motion, object, kind, run, seed: what was recorded.
        frames: frames in the sequence; in_view: frames with the object's mask >= min area.
        duration_s: recording length, s.
        snapshots: EEMS gallery size of the main record at the end.
        valid, total, propagated: estimated poses, pose entries, propagated entries (main record).
        attempts: frames in which the main record was seen (the pose estimator ran on it).
        matches_mean: mean matches inside both masks per attempt.
        estimated_fraction: valid / in_view.
        trans_err_cm, rot_err_deg: per estimated pose (after the definition frame).
        centroid_err_cm: per frame with a reported centroid and the object in view.
        seg_iou: main record vs ground truth, per frame in view; seg_iou_all: best candidate IoU
            for every object in view, every frame.
        tracks: records of the moved object seen in >= 5 % of the frames; fragments: the others.
        kinematic: (90,) motion descriptor of the main record, or None (< 2 estimated poses).
        kinematic_reliable: the descriptor's own reliability flag (no long gaps).
        visual: (54,) gallery-mean appearance descriptor, or None.
        fps: pipeline frames per second on this run (wall clock, includes reading the frames);
            None when the clock did not advance.
        failures: most common reasons of non-estimated poses, with counts.
        t_est, p_est: (M,) s and (M, 3) camera-frame positions of the estimated poses, metres.
        t_gt, p_gt: (N,) s and (N, 3) true positions of the canonical origin (after alignment),
            or the body origin without an alignment.
    """

    motion: str
    object: str
    kind: str
    run: int
    seed: int
    frames: int
    in_view: int
    duration_s: float
    snapshots: int
    valid: int
    total: int
    propagated: int
    attempts: int
    matches_mean: float | None
    estimated_fraction: float
    trans_err_cm: list[float]
    rot_err_deg: list[float]
    centroid_err_cm: list[float]
    seg_iou: list[float]
    seg_iou_all: list[float]
    tracks: int
    fragments: int
    kinematic: np.ndarray | None
    kinematic_reliable: bool
    visual: np.ndarray | None
    fps: float | None
    failures: dict[str, int] = field(default_factory=dict)
    t_est: np.ndarray = field(default_factory=lambda: np.zeros(0))
    p_est: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    t_gt: np.ndarray = field(default_factory=lambda: np.zeros(0))
    p_gt: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def name(self) -> str:
        """The run's label, ``"motion/run"``."""
        return f"{self.motion}/{self.run}"

    @property
    def usable(self) -> bool:
        """A usable motion exemplar: mostly estimated poses and a reliable descriptor."""
        return (
            self.kinematic is not None
            and self.kinematic_reliable
            and self.estimated_fraction >= USABLE_FRACTION
        )

    def summary(self) -> dict[str, Any]:
        """JSON-compatible per-run figures (``metrics.runs`` of ``pal experiment a1 --json``)."""
        return {
            "motion": self.motion,
            "object": self.object,
            "kind": self.kind,
            "run": self.run,
            "seed": self.seed,
            "frames": self.frames,
            "duration_s": self.duration_s,
            "snapshots": self.snapshots,
            "valid_total": [self.valid, self.total],
            "estimated_attempts": [self.valid, self.attempts],
            "propagated": self.propagated,
            "matches_mean": self.matches_mean,
            "estimated_fraction": self.estimated_fraction,
            "trans_err_cm_median": _stat(self.trans_err_cm, 50),
            "trans_err_cm_p90": _stat(self.trans_err_cm, 90),
            "rot_err_deg_median": _stat(self.rot_err_deg, 50),
            "rot_err_deg_p90": _stat(self.rot_err_deg, 90),
            "centroid_err_cm_median": _stat(self.centroid_err_cm, 50),
            "seg_iou_median": _stat(self.seg_iou, 50),
            "seg_iou_mean": float(np.mean(self.seg_iou)) if self.seg_iou else None,
            "seg_iou_all_mean": float(np.mean(self.seg_iou_all)) if self.seg_iou_all else None,
            "tracks": self.tracks,
            "fragments": self.fragments,
            "usable_trajectory": self.usable,
            "kinematic_reliable": self.kinematic_reliable,
            "has_visual": self.visual is not None,
            "fps": self.fps,
            "failures": dict(self.failures),
        }


def _gt_label(labels: np.ndarray, mask: Mask) -> int:
    x0, y0, x1, y1 = mask.bbox
    return int(np.bincount(labels[y0:y1, x0:x1][mask.crop]).argmax())


@dataclass
class _Perceived:
    """What Π saw in every frame of a sequence, next to the ground truth of the moved object."""

    votes: dict[int, Counter[int]]  # track id -> ground-truth label -> frames
    visible: Counter[int]  # track id -> frames in which it was visible
    masks: list[dict[int, Mask]]  # per frame: track id -> mask
    centroids: list[dict[int, np.ndarray]]  # per frame: track id -> centroid
    true_centroids: list[np.ndarray | None]  # per frame: the moved object's true centroid
    seg_all: list[float]  # best IoU of every ground-truth object mask in every frame
    in_view: np.ndarray  # (T,) bool: the moved object is in view
    gt_masks: list[Mask | None]  # per frame: the moved object's true mask
    seconds: float  # wall-clock time of Π over the sequence


def _perceive(seq: RecordedSequence, pipe: Pipeline, label: int, min_area: int) -> _Perceived:
    """Run ``pipe`` over ``seq``, collecting tracks, masks and centroids against the ground truth."""
    pose_cfg = pipe.config.pose
    seen = _Perceived({}, Counter(), [], [], [], [], np.zeros(len(seq), dtype=bool), [], 0.0)
    start = time.perf_counter()
    for k, frame in enumerate(seq):
        state = pipe(frame)
        labels = frame.labels
        if labels is None:
            raise ValueError(
                f"{seq.path}: frame {k} has no ground-truth mask although the sequence declares masks"
            )
        frame_masks, frame_cents = {}, {}
        for o in state.objects:
            if o.visible and o.mask is not None:
                seen.visible[o.obj_id] += 1
                seen.votes.setdefault(o.obj_id, Counter())[_gt_label(labels, o.mask)] += 1
                frame_masks[o.obj_id] = o.mask
                if o.spatial is not None:
                    frame_cents[o.obj_id] = o.spatial.centroid
        seen.masks.append(frame_masks)
        seen.centroids.append(frame_cents)
        own = labels == label
        gt_mask = Mask.from_full(own) if own.sum() >= min_area else None
        seen.in_view[k] = gt_mask is not None
        seen.gt_masks.append(gt_mask)
        true = (
            None
            if gt_mask is None
            else spatial_descriptor(
                frame, gt_mask, min_depth=pose_cfg.min_depth, max_depth=pose_cfg.max_depth
            )
        )
        seen.true_centroids.append(None if true is None else true.centroid)
        for lab in np.unique(labels):
            m = labels == lab
            if lab == 0 or m.sum() < min_area:
                continue
            g = Mask.from_full(m)
            seen.seg_all.append(max((iou(g, mm) for mm in frame_masks.values()), default=0.0))
    seen.seconds = time.perf_counter() - start
    return seen


def _empty_result(ts: np.ndarray, gt: np.ndarray) -> dict[str, Any]:
    """The pose scores of a sequence in which no track is the moved object."""
    return {
        "trans_err_cm": [],
        "rot_err_deg": [],
        "centroid_err_cm": [],
        "valid": 0,
        "total": 0,
        "propagated": 0,
        "attempts": 0,
        "matches_mean": None,
        "snapshots": 0,
        "kinematic": None,
        "kinematic_reliable": False,
        "visual": None,
        "failures": {},
        "t_est": np.zeros(0),
        "p_est": np.zeros((0, 3)),
        "t_gt": ts.copy(),
        "p_gt": gt[:, :3, 3].copy(),
    }


def _score_track(
    result: dict[str, Any],
    rec: Any,
    seen: _Perceived,
    main: int,
    ts: np.ndarray,
    gt: tuple[np.ndarray, np.ndarray],
    kinematic: KinematicConfig | None,
) -> None:
    """Fill ``result`` with the poses, descriptors and centroid errors of track ``main`` (record ``rec``).

    ``gt``: the true poses (T, 4, 4) and their validity (T,).
    """
    gt_poses, gt_valid = gt
    poses = rec.trajectory.poses
    index = {round(float(t), 6): k for k, t in enumerate(ts)}
    est = [p for p in poses if p.is_valid]
    tried = [p for p in poses if p.diagnostics.attempts > 0]
    result.update(
        valid=len(est),
        total=len(poses),
        propagated=sum(p.source == "propagated" for p in poses),
        attempts=seen.visible[main],
        snapshots=len(rec.gallery),
        visual=rec.gallery.visual_descriptor(),
        matches_mean=float(np.mean([p.diagnostics.matches for p in tried])) if tried else None,
        failures=dict(
            Counter(p.diagnostics.reason.split(";")[0] for p in poses if not p.is_valid).most_common(4)
        ),
    )
    canon = next((p for p in est if p.diagnostics.solver == "canonical"), None)
    if canon is not None and canon.camera_from_object is not None:
        X = np.linalg.inv(gt_poses[index[round(canon.timestamp, 6)]]) @ canon.camera_from_object
        aligned = gt_poses @ X
        result["p_gt"] = aligned[:, :3, 3].copy()
        for p in est:
            k = index[round(p.timestamp, 6)]
            T = p.camera_from_object
            if p is canon or T is None or not gt_valid[k]:
                continue
            result["trans_err_cm"].append(100.0 * float(np.linalg.norm(T[:3, 3] - aligned[k, :3, 3])))
            result["rot_err_deg"].append(rotation_angle_deg(T[:3, :3], aligned[k, :3, :3]))
        result["t_est"] = np.array([p.timestamp for p in est])
        result["p_est"] = np.array(
            [p.camera_from_object[:3, 3] for p in est if p.camera_from_object is not None]
        )
    if len(est) >= 2:
        desc = trajectory_descriptor(rec.trajectory, kinematic)
        result["kinematic"], result["kinematic_reliable"] = desc.vector, desc.reliable
    for k in range(len(seen.centroids)):  # every frame
        c, true_c = seen.centroids[k].get(main), seen.true_centroids[k]
        if c is not None and true_c is not None:
            result["centroid_err_cm"].append(100.0 * float(np.linalg.norm(c - true_c)))


def evaluate_sequence(
    seq: RecordedSequence,
    config: PipelineConfig,
    *,
    run: int = 0,
    min_area: int = 150,
    kinematic: KinematicConfig | None = None,
) -> RunResult:
    """Run Π over ``seq`` (recorded by :func:`pal.sim.recording.record`) and score it.

    Args:
        seq: the sequence; its metadata names the moved object and its ground truth is used.
        config: the pipeline configuration.
        run: index of the run within its motion (for naming only).
        min_area: the object counts as in view when its true mask has this many pixels.
        kinematic: motion-descriptor settings.

    Raises:
        ValueError: the sequence lacks ground-truth masks or poses of the moved object.
    """
    meta = seq.metadata
    obj = meta.get("object")
    names = {v: k for k, v in seq.label_names.items()}
    if not seq.has_masks or obj not in names or obj not in seq.gt_objects:
        raise ValueError(
            f"{seq.path}: needs ground-truth masks and poses of the moved object (metadata object {obj!r})"
        )
    label = names[obj]
    gt, gt_valid = seq.gt_poses(obj)
    pipe = Pipeline(config)
    seen = _perceive(seq, pipe, label, min_area)
    masks, gt_masks, seconds = seen.masks, seen.gt_masks, seen.seconds
    mine = sorted((c[label], -oid, oid) for oid, c in seen.votes.items() if c.most_common(1)[0][0] == label)
    long = max(1, round(0.05 * len(seq)))
    main = mine[-1][2] if mine else None
    seg = [
        0.0 if main not in masks[k] else iou(gt_masks[k], masks[k][main])
        for k in range(len(seq))
        if gt_masks[k] is not None
    ]  # type: ignore[arg-type]
    ts = seq.timestamps
    result = _empty_result(ts, gt)
    if main is not None:
        _score_track(result, pipe.records[main], seen, main, ts, (gt, gt_valid), kinematic)
    n_view = int(seen.in_view.sum())
    return RunResult(
        motion=str(meta.get("motion")),
        object=str(obj),
        kind=str(meta.get("kind")),
        run=int(run),
        seed=int(meta.get("seed", 0)),
        frames=len(seq),
        in_view=n_view,
        duration_s=float(ts[-1] - ts[0]) if len(ts) else 0.0,
        estimated_fraction=result["valid"] / n_view if n_view else 0.0,
        seg_iou=seg,
        seg_iou_all=seen.seg_all,
        tracks=sum(n >= long for n, _, _ in mine),
        fragments=sum(n < long for n, _, _ in mine),
        fps=len(seq) / seconds if seconds > 0 else None,
        **result,
    )
