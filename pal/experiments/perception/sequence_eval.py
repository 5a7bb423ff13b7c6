"""Π over a recorded static-scene sequence with camera truth: coverage, pose errors, ids, speed.

The scene is static, so between two evaluated frames i and j every object's motion in the
camera frame is the inverse camera motion ``T_ji = inverse(world_from_camera_j)
world_from_camera_i`` (the sequence's :meth:`camera_poses`, interpolated). The frames are
``0, s, 2s, ...`` of the sequence (stride ``s``); each consecutive evaluated pair (i, j) is scored
as in :func:`pal.experiments.perception.real_frames.pair_rows`:

- **seen in both** / **kept id**: the object's mask moved by ``T_ji`` and one of frame j's are
  each other's best overlap (IoU ≥ ``seen_iou``); the object keeps its id when that one has it;
- **posed**: both poses of a kept object are ``estimated``; the share of kept objects posed;
- **errors**: rotation angle and origin distance between ``camera_from_object(j)`` and
  ``T_ji camera_from_object(i)``; *wrong* above 10 degrees or 5 cm;
- **no motion**: the predictor ``camera_from_object(j) = camera_from_object(i)`` on the same
  posed pairs, its errors, and the share of pairs where the estimated rotation beats it.

Speed: wall and CPU seconds of the process per frame over the whole run (one pipeline, every
evaluated frame in order) and the median milliseconds of every stage Π reports. Pairs whose
frames lack a camera pose are skipped and counted.
"""

from __future__ import annotations

import os
import statistics
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from pal.checks import check_choice, check_float, check_int
from pal.experiments.perception.evaluation import rotation_angle_deg
from pal.experiments.perception.real_frames import pair_rows, summarise
from pal.perception import Pipeline, PipelineConfig
from pal.perception.tum import (
    FREIBURG1_DISTORTION,
    FREIBURG1_K,
    FREIBURG2_K,
    FREIBURG3_K,
    TUM_DEPTH_SCALE,
    TUMSequence,
)

__all__ = [
    "OFFSET_SCAN_S",
    "TUM_CAMERAS",
    "TUM_DISTORTION",
    "SequenceConfig",
    "evaluate_sequence",
    "excerpt_path",
    "open_sequence",
    "truth_clock_offset",
]

#: The TUM cameras by name: (3, 3) intrinsics, pixels.
TUM_CAMERAS = {"freiburg1": FREIBURG1_K, "freiburg2": FREIBURG2_K, "freiburg3": FREIBURG3_K}
#: Their published lens distortion (OpenCV k1, k2, p1, p2, k3), where it is known here.
TUM_DISTORTION = {"freiburg1": FREIBURG1_DISTORTION}


def excerpt_path() -> Path:
    """The shipped 4-frame excerpt of TUM RGB-D freiburg1_xyz (``sample_data/tum_fr1_xyz``)."""
    path = Path(str(resources.files("pal.perception").joinpath("sample_data", "tum_fr1_xyz")))
    if not (path / "rgb.txt").is_file():
        raise FileNotFoundError(f"{path} is missing: this installation of pal has no sample data")
    return path


@dataclass(frozen=True)
class SequenceConfig:
    """What the sequence evaluation runs.

    Attributes:
        path: a TUM-layout folder (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, and
            ``calibration.json`` with the intrinsics and depth scale); ``""``: the shipped
            4-frame excerpt of freiburg1_xyz. Partial downloads are opened with ``missing="skip"``.
        camera: ``"file"``: intrinsics and depth scale from the folder's ``calibration.json``;
            ``"freiburg1"``, ``"freiburg2"``, ``"freiburg3"``: that TUM camera's intrinsics and
            TUM's depth scale (1/5000 m per unit).
        undistort: undistort the frames with the camera's lens coefficients (``"freiburg1"``'s
            published ones, or ``calibration.json``'s ``"distortion"``); False: use the
            recorded images as pinhole images.
        truth_offset_s: clock offset of the camera truth, s: frame k is scored against the
            motion-capture pose at its timestamp plus this (``TUMSequence.camera_poses``);
            0 reads the truth at the image timestamps.
        strides: frame strides evaluated, each over its own fresh pipeline.
        frames: sequence frames used, from the first, before striding (None: all).
        seen_iou: IoU of a moved mask with an object of the next frame for "seen in both".
    """

    path: str = ""
    camera: str = "file"
    undistort: bool = True
    truth_offset_s: float = 0.0
    strides: tuple[int, ...] = (1, 3)
    frames: int | None = None
    seen_iou: float = 0.3

    def __post_init__(self) -> None:
        if not isinstance(self.path, str):
            raise TypeError(f"path is {type(self.path).__name__}; expected a folder name (str)")
        if not isinstance(self.strides, tuple) or not self.strides:
            raise ValueError(f"strides is {self.strides!r}; expected a non-empty tuple of ints >= 1")
        check_choice("camera", self.camera, ("file", *TUM_CAMERAS))
        if not isinstance(self.undistort, bool):
            raise TypeError(f"undistort is {self.undistort!r}; expected True or False")
        for s in self.strides:
            check_int("strides", s, minimum=1)
        if self.frames is not None:
            check_int("frames", self.frames, minimum=2)
        check_float("seen_iou", self.seen_iou, 0.0, 1.0, open_low=True)
        check_float("truth_offset_s", self.truth_offset_s, -0.1, 0.1)


def open_sequence(path: str | os.PathLike[str], camera: str = "file", undistort: bool = True) -> TUMSequence:
    """The TUM-layout folder ``path`` (``""``: the shipped excerpt), camera and lens as in :class:`SequenceConfig`."""
    folder = excerpt_path() if str(path) == "" else Path(path)
    if camera == "file":
        seq = TUMSequence(folder, missing="skip")
    elif camera in TUM_CAMERAS:
        lens = TUM_DISTORTION.get(camera) if undistort else None
        seq = TUMSequence(
            folder, K=TUM_CAMERAS[camera], depth_scale=TUM_DEPTH_SCALE, missing="skip", distortion=lens
        )
    else:
        raise ValueError(f"camera {camera!r} unknown; expected 'file' or one of {list(TUM_CAMERAS)}")
    if not undistort:
        seq.undistortion = None
    return seq


#: Clock offsets of the camera truth that :func:`truth_clock_offset` tries, s (-40 to +40 ms).
OFFSET_SCAN_S = tuple(round(-0.04 + 0.005 * k, 3) for k in range(17))


def truth_clock_offset(
    seq: TUMSequence, motions: list[tuple[int, int, np.ndarray]], offsets: tuple[float, ...] = OFFSET_SCAN_S
) -> tuple[float | None, float | None]:
    """The clock offset of the camera truth that Π's own camera motions agree with best.

    For each offset (s), the median rotation angle between Π's ``current_from_previous`` of each
    pair and the truth's motion read at the frame times plus that offset
    (``seq.camera_poses(offset=...)``); pairs without truth at an offset are left out there.

    Args:
        seq: the sequence with its camera truth.
        motions: ``(i, j, current_from_previous (4, 4))`` of the pairs Π measured.
        offsets: the offsets tried, s.

    Returns:
        (the offset with the smallest median error, s; that median, degrees), or (None, None)
        without motions.
    """
    best: tuple[float | None, float | None] = (None, None)
    for offset in offsets:
        poses = seq.camera_poses(offset=offset)
        errs = [
            rotation_angle_deg(est[:3, :3], (np.linalg.inv(poses.poses[j]) @ poses.poses[i])[:3, :3])
            for i, j, est in motions
            if poses.valid[i] and poses.valid[j]
        ]
        if errs and (best[1] is None or float(np.median(errs)) < best[1]):
            best = (float(offset), float(np.median(errs)))
    return best


def _run(pipe: Pipeline, frames: list[Any]) -> tuple[list[Any], float, float]:
    """Π over ``frames`` in order: (states, wall seconds, CPU seconds of the process)."""
    wall, cpu = time.perf_counter(), time.process_time()
    states = [pipe(f) for f in frames]
    return states, time.perf_counter() - wall, time.process_time() - cpu


def _stage_ms(states: list[Any]) -> dict[str, float]:
    keys = sorted({k for s in states for k in s.timings})
    return {k: 1000.0 * statistics.median(s.timings.get(k, 0.0) for s in states) for k in keys}


def evaluate_sequence(
    seq: TUMSequence,
    stride: int,
    config: SequenceConfig,
    pipeline: PipelineConfig | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Run Π over frames ``0, stride, 2 stride, ...`` of ``seq`` and score it (module docstring).

    Returns:
        the totals of :func:`~pal.experiments.perception.real_frames.summarise` plus ``frames``,
        ``pairs`` (scored), ``pairs_without_truth``, ``camera_rot_err_deg_median`` and
        ``camera_trans_err_m_median`` (Π's camera motion against the truth, pairs where it was measured),
        ``truth_offset_best_s`` and ``camera_rot_err_deg_at_best`` (:func:`truth_clock_offset`), ``ids`` (distinct ids created),
        ``objects_per_frame`` (median visible), ``fps_wall``, ``fps_cpu``, ``stage_ms``,
        ``per_pair`` (pose share and kept share per pair), ``pose_fraction_halves`` (the
        share posed over the first and the second half of the pairs) and ``rows``.
    """
    check_int("stride", stride, minimum=1)
    n = len(seq) if config.frames is None else min(config.frames, len(seq))
    index = list(range(0, n, stride))
    if len(index) < 2:
        raise ValueError(f"{seq.path}: stride {stride} over {n} frames leaves {len(index)} frame; need 2")
    frames = [seq[k] for k in index]
    poses = seq.camera_poses(offset=config.truth_offset_s)
    pipe = Pipeline(PipelineConfig(**{**(pipeline or PipelineConfig()).__dict__, "seed": seed}))
    states, wall, cpu = _run(pipe, frames)
    rows: list[dict[str, Any]] = []
    per_pair, missing = [], 0
    camera_err: list[tuple[float, float]] = []
    motions: list[tuple[int, int, np.ndarray]] = []
    for a in range(len(index) - 1):
        i, j = index[a], index[a + 1]
        if not (poses.valid[i] and poses.valid[j]):
            missing += 1
            continue
        ref = np.linalg.inv(poses.poses[j]) @ poses.poses[i]
        cam = states[a + 1].camera
        if cam is not None and cam.known:
            est = cam.current_from_previous
            motions.append((i, j, est))
            camera_err.append(
                (rotation_angle_deg(est[:3, :3], ref[:3, :3]), float(np.linalg.norm(est[:3, 3] - ref[:3, 3])))
            )
        got = [
            {**r, "pair": a}
            for r in pair_rows(frames[a], frames[a + 1], states[a], states[a + 1], ref, config.seen_iou)
        ]
        s = summarise(got)
        per_pair.append(
            {"frames": [i, j], "kept_fraction": s["kept_fraction"], "pose_fraction": s["pose_fraction"]}
        )
        rows += got
    if not per_pair:
        raise ValueError(f"{seq.path}: no pair of evaluated frames has camera poses for both frames")
    half = (len(index) - 1) / 2
    offset = truth_clock_offset(seq, motions)
    return {
        **summarise(rows),
        "pose_fraction_halves": [
            summarise([r for r in rows if (r["pair"] < half) == first])["pose_fraction"]
            for first in (True, False)
        ],
        "stride": stride,
        "frames": len(frames),
        "pairs": len(per_pair),
        "pairs_without_truth": missing,
        "camera_rot_err_deg_median": float(np.median([e[0] for e in camera_err])) if camera_err else None,
        "camera_trans_err_m_median": float(np.median([e[1] for e in camera_err])) if camera_err else None,
        **dict(zip(("truth_offset_best_s", "camera_rot_err_deg_at_best"), offset, strict=True)),
        "ids": len({o.obj_id for s in states for o in s.objects}),
        "objects_per_frame": float(np.median([sum(o.visible for o in s.objects) for s in states])),
        "seconds_wall": wall,
        "seconds_cpu": cpu,
        "fps_wall": len(frames) / wall if wall > 0 else None,
        "fps_cpu": len(frames) / cpu if cpu > 0 else None,
        "stage_ms": _stage_ms(states),
        "per_pair": per_pair,
        "rows": rows,
    }
