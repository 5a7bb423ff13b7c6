"""``pal bench perception``: frames per second of the perception pipeline Π at 640x480, one core.

**Real frames.** Π with pose estimation and relations runs over the real RGB-D samples
(:mod:`pal.perception.samples`: the TUM desk pair and three Kinect room frames, 640x480,
a fresh pipeline per sample, every frame a new view of a moving camera): ``fps_real`` is
frames / median seconds, with the median milliseconds of every stage Π reports, and
``fps_real_cpu`` frames / median CPU seconds of the process (the core's time spent on Π, which
other processes sharing the machine do not inflate as they do the wall-clock figure). The same run
is scored by :mod:`pal.experiments.perception.real_frames` (ids kept, poses against the inverse
camera motion, the support plane over seeds), and those scores are the report's quality
targets: a speed figure is only worth what the output is.

**Simulated frames.** The frames are one scripted tabletop run (default ``box-rotation``, all
three objects in view, sensor noise on) rendered once into memory. Then, alternating inside
each repeat (:func:`pal.lab.timing.measure_interleaved`):

- ``render``: the baseline — placing the objects and rendering the same frames with the
  MuJoCo camera (RGB, depth and segmentation; EGL or the ray-cast fallback);
- ``no_pose``: Π without pose estimation (segmentation, tracking, EEMS, relations, scene);
- ``with_pose``: Π with pose estimation (the default pipeline).

Each contender processes all frames from a fresh state. Metrics: ``fps_no_pose``,
``fps_with_pose``, ``render_fps`` (frames / median seconds), their ratios to ``render_fps``
(``ratio_no_pose``, ``ratio_with_pose``), the median seconds per call, and the median
per-stage milliseconds Π reports in ``PerceptionState.timings``.

**One core**: while timing, the process is pinned to one CPU (``os.sched_setaffinity``),
OpenCV runs one thread and the BLAS thread pool is limited to one thread (threadpoolctl, when
installed); the numbers are reported with how many of these limits were in force. Targets:
≥ 30 frames/s without pose, ≥ 10 with pose on the simulated frames; ≥ 15 frames/s with pose and
relations on the real frames; on the real frames ≥ 70 % of the tracked objects with a pose per
frame pair, their median error against the inverse camera motion ≤ 2 degrees and ≤ 2 cm, no
estimated pose more than 10 degrees or 5 cm wrong, ≥ 90 % of the objects seen in both frames
keeping their id, and the support plane the desk (the floor in the room) for every seed.

**A static sequence with camera truth.** The ``sequence`` block runs
:mod:`pal.experiments.perception.sequence` (the ``perception-sequence`` experiment) on one core:
a TUM-layout folder (``--set sequence.path=FOLDER sequence.camera=freiburg1``; by default the
shipped 4-frame excerpt of freiburg1_xyz) at strides 1 and 3, with its targets (≥ 70 % posed,
≤ 1.5 degrees / 1 cm, none wrong, ≥ 90 % ids kept, rotation better than no motion on ≥ 80 % of
the stride-1 pairs, ≥ 15 frames per CPU second).
"""

from __future__ import annotations

import contextlib
import logging
import os
import statistics
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import cv2

from pal.checks import check_choice, check_int
from pal.experiments.perception.real_frames import RealConfig, evaluate_real
from pal.experiments.perception.relation_checks import FAR_GAP
from pal.experiments.perception.sequence import (
    sequence_metrics,
    sequence_results,
    sequence_stage_table,
    sequence_table,
    sequence_targets,
)
from pal.experiments.perception.sequence_eval import SequenceConfig
from pal.frames import RGBDFrame
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target
from pal.lab.timing import Timing, measure_interleaved, ratio
from pal.perception import Pipeline, PipelineConfig
from pal.perception.samples import open_sample
from pal.sim.camera import BACKENDS
from pal.sim.motions import MOTIONS, script
from pal.sim.recording import RecordConfig, render_run
from pal.sim.tabletop import load_tabletop

__all__ = ["QUICK", "TARGET_FPS", "TINY", "Config", "one_core", "run"]

log = logging.getLogger(__name__)

#: Frames/s that Π should reach on one core, without and with pose estimation (simulated), and
#: with pose and relations on the real frames.
TARGET_FPS = {"no_pose": 30.0, "with_pose": 10.0, "real": 15.0}


@dataclass(frozen=True)
class Config:
    """Benchmark settings.

    Attributes:
        seed: seed of the scripted run.
        motion: the scripted run whose frames are timed (a key of :data:`pal.sim.motions.MOTIONS`).
        frames: how many of its frames (from the start; the run is at least 3 s at 15 frames/s).
        width, height: image size, pixels.
        repeats: timed repeats (median reported) after one warm-up.
        one_core: pin to one CPU and one thread while timing.
        backend: camera backend (:data:`pal.sim.camera.BACKENDS`).
        real: the real samples timed and scored.
        sequence: the static sequence scored and timed (:mod:`pal.experiments.perception.sequence`).
    """

    seed: int = 0
    motion: str = "box-rotation"
    frames: int = 45
    width: int = 640
    height: int = 480
    repeats: int = 3
    one_core: bool = True
    backend: str = "auto"
    real: RealConfig = RealConfig()
    sequence: SequenceConfig = SequenceConfig()

    def __post_init__(self) -> None:
        check_choice("motion", self.motion, tuple(MOTIONS))
        check_int("frames", self.frames, minimum=2)
        check_int("width", self.width, minimum=16)
        check_int("height", self.height, minimum=16)
        check_int("repeats", self.repeats)
        check_choice("backend", self.backend, BACKENDS)


@contextlib.contextmanager
def one_core(enabled: bool = True) -> Iterator[dict[str, Any]]:
    """Pin the process to one CPU, one OpenCV thread and one BLAS thread; restore them afterwards.

    Yields:
        the limits actually in force: ``{"cpus": int | None, "opencv_threads": int, "blas_threads": int | None}``.
    """
    if not enabled:
        yield {"cpus": None, "opencv_threads": cv2.getNumThreads(), "blas_threads": None}
        return
    stack = contextlib.ExitStack()
    limits: dict[str, Any] = {"cpus": None, "opencv_threads": 1, "blas_threads": None}
    affinity = getattr(os, "sched_getaffinity", None)
    before = affinity(0) if affinity is not None else None
    threads = cv2.getNumThreads()
    try:
        if before:
            os.sched_setaffinity(0, {min(before)})
            limits["cpus"] = 1
        cv2.setNumThreads(1)
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:
            log.warning("threadpoolctl is not installed: the BLAS thread pool is not limited to one thread")
        else:
            stack.enter_context(threadpool_limits(limits=1))
            limits["blas_threads"] = 1
        yield limits
    finally:
        stack.close()
        cv2.setNumThreads(threads)
        if before:
            os.sched_setaffinity(0, before)


def _stage_ms(states: list[Any]) -> dict[str, float]:
    keys = sorted({k for s in states for k in s.timings})
    return {k: 1000.0 * statistics.median(s.timings.get(k, 0.0) for s in states) for k in keys}


def _time_real(config: Config) -> tuple[Timing, int, list[Any], float]:
    """Time Π (with pose and relations) over the real samples.

    Returns:
        (wall-clock timing, frames, the last call's states, median CPU seconds of the process
        per timed call): the CPU time does not count the time other processes held the core.
    """
    samples = []
    for name in config.real.samples:
        seq = open_sample(name)
        n = len(seq) if config.real.frames is None else min(config.real.frames, len(seq))
        samples.append([seq[k] for k in range(n)])

    cpu: list[float] = []

    def perceive() -> list[Any]:
        start = time.process_time()
        states = []
        for frames in samples:
            states += Pipeline(PipelineConfig(seed=config.seed)).run(frames)
        cpu.append(time.process_time() - start)
        return states

    with one_core(config.one_core):
        timing = measure_interleaved({"real": perceive}, repeats=config.repeats, warmup=1)["real"]
    timed = cpu[-len(timing.seconds) :]  # the warm-up call is not timed
    return timing, sum(len(f) for f in samples), timing.result, statistics.median(timed)


def _real_targets(q: dict[str, Any], fps: float | None) -> list[Target]:
    t = q["total"]
    return [
        Target(
            "fps_real",
            fps,
            TARGET_FPS["real"],
            ">=",
            "frames/s of Pi with pose and relations on the real 640x480 samples, one core",
        ),
        Target(
            "real_pose_fraction",
            t["pose_fraction"],
            0.7,
            ">=",
            "real frames: tracked objects with an estimated pose in both frames of a pair, per object and pair",
        ),
        Target(
            "real_rot_err_deg",
            t["rot_err_deg_median"],
            2.0,
            "<=",
            "real frames: median rotation error of those poses against the inverse camera motion, deg",
        ),
        Target(
            "real_trans_err_m",
            t["trans_err_m_median"],
            0.02,
            "<=",
            "real frames: median translation error of those poses against the inverse camera motion, m",
        ),
        Target(
            "real_wrong_estimated",
            t["wrong_estimated"],
            0,
            "<=",
            "real frames: estimated poses more than 10 deg or 5 cm from the inverse camera motion",
        ),
        Target(
            "real_ids_kept",
            t["kept_fraction"],
            0.9,
            ">=",
            "real frames: objects seen in both frames of a pair that keep their id",
        ),
        Target(
            "real_support_plane",
            q["support_correct"] / q["support_checks"] if q["support_checks"] else None,
            1.0,
            ">=",
            "real frames: fraction of (frame, seed) with the desk or the floor as support plane, seeds 0 to n-1",
        ),
    ]


def _time(config: Config) -> tuple[dict[str, Timing], dict[str, Any], str]:
    """Render the frames once, then time rendering and Π without and with pose estimation.

    Returns:
        (contender -> timing, the one-core limits in force, the camera backend used).
    """
    rc = RecordConfig(
        config.motion, seed=config.seed, width=config.width, height=config.height, backend=config.backend
    )
    run_script = script(rc.motion, rc.seed, rc.fps)
    if len(run_script) < config.frames:
        raise ValueError(
            f"{config.motion} (seed {config.seed}) has {len(run_script)} frames, fewer than frames={config.frames}"
        )
    frames: list[RGBDFrame] = []
    backend = ""
    for rec in render_run(rc, run_script):
        frames.append(rec.frame)
        backend = rec.backend
        if len(frames) == config.frames:
            break
    scene = load_tabletop()
    cam = scene.camera(config.width, config.height, config.backend)
    poses = [{n: run_script.poses[n][k] for n in scene.objects} for k in range(config.frames)]

    def render() -> None:
        for pose in poses:
            for name, T in pose.items():
                scene.set_pose(name, T)
            cam.render()

    def perceive(estimate_pose: bool) -> list[Any]:
        return Pipeline(PipelineConfig(estimate_pose=estimate_pose)).run(frames)

    try:
        with one_core(config.one_core) as limits:
            log.info(
                "timing %d frames at %dx%d, %d repeats, limits %s",
                config.frames,
                config.width,
                config.height,
                config.repeats,
                limits,
            )
            timings = measure_interleaved(
                {"render": render, "no_pose": lambda: perceive(False), "with_pose": lambda: perceive(True)},
                repeats=config.repeats,
                warmup=1,
            )
    finally:
        cam.close()
    return timings, limits, backend


def _tables(
    config: Config, m: dict[str, Any], quality: dict[str, Any], fps: dict[str, float | None], real_cpu: float
) -> list[Table]:
    """Throughput against rendering, milliseconds by stage, and the real frame pairs' ids and poses."""
    seconds, stage_ms, real_frames = m["seconds_per_call"], m["stage_ms"], m["real_frames"]
    ratios = {"no_pose": m["ratio_no_pose"], "with_pose": m["ratio_with_pose"]}
    stages = sorted({s for v in stage_ms.values() for s in v})
    pair_rows = [
        [
            name,
            "-".join(p["frames"]),
            p["objects"],
            p["seen_in_both"],
            p["kept_id"],
            p["with_pose"],
            p["rot_err_deg_median"],
            p["trans_err_m_median"],
            p["wrong_estimated"],
            p["rejected"],
            p["reference"],
        ]
        for name, q in quality["samples"].items()
        for p in q["pairs"]
    ]
    return [
        Table(
            "Perception throughput",
            ["contender", "seconds per call", "frames/s", "/ render"],
            [
                ["render (baseline)", seconds["render"], fps["render"], 1.0],
                ["Pi without pose", seconds["no_pose"], fps["no_pose"], ratios["no_pose"]],
                ["Pi with pose", seconds["with_pose"], fps["with_pose"], ratios["with_pose"]],
                ["Pi with pose and relations, real frames", seconds["real"], fps["real"], None],
                ["the same, CPU time of the process", real_cpu, m["fps_real_cpu"], None],
            ],
            f"A simulated call processes all {config.frames} frames from a fresh state, a real call the "
            f"{real_frames} real frames (a fresh pipeline per sample); median of {config.repeats} repeats.",
        ),
        Table(
            "Median milliseconds per frame by stage",
            ["stage", "without pose", "with pose", "real frames"],
            [
                [s, stage_ms["no_pose"].get(s), stage_ms["with_pose"].get(s), stage_ms["real"].get(s)]
                for s in stages
            ],
        ),
        Table(
            "Real frame pairs: ids and poses against the inverse camera motion",
            [
                "sample",
                "frames",
                "objects",
                "seen in both",
                "kept id",
                "with pose",
                "rot. err. median [deg]",
                "trans. err. median [m]",
                "wrong",
                "rejected",
                "reference motion",
            ],
            pair_rows,
            "Seen in both: moved by the reference motion, the object's mask and one of the next frame's are "
            "each other's best overlap. Wrong: more than 10 deg or 5 cm from the inverse camera motion.",
        ),
    ]


#: ``--quick``: 10 simulated frames, every real frame, the support plane over 3 seeds.
QUICK = Config(frames=10, repeats=1, real=RealConfig(support_seeds=3))
#: The contract test's run: 3 small simulated frames, the first 2 frames of each real sample.
TINY = Config(
    frames=3,
    width=160,
    height=120,
    repeats=1,
    real=RealConfig(frames=2, support_seeds=1),
    sequence=SequenceConfig(strides=(3,)),
)


@register("perception", kind="bench", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Frames per second of the perception pipeline on real and simulated frames, and its quality on the real ones."""
    timings, limits, backend = _time(config)
    real_timing, real_frames, real_states, real_cpu = _time_real(config)
    quality = evaluate_real(config.real, PipelineConfig(), config.seed)
    with one_core(config.one_core):
        seq = sequence_results(config.sequence, config.seed)
    seconds = {k: t.median for k, t in timings.items()}
    fps = {k: config.frames / s if s > 0 else None for k, s in seconds.items()}
    fps["real"] = real_frames / real_timing.median if real_timing.median > 0 else None
    stage_ms = {k: _stage_ms(timings[k].result) for k in ("no_pose", "with_pose")}
    stage_ms["real"] = _stage_ms(real_states)
    ratios = {k: ratio(fps[k], fps["render"]) for k in ("no_pose", "with_pose")}
    total = quality["total"]
    m = {
        "fps_no_pose": fps["no_pose"],
        "fps_with_pose": fps["with_pose"],
        "fps_real": fps["real"],
        "fps_real_cpu": real_frames / real_cpu if real_cpu > 0 else None,
        "render_fps": fps["render"],
        "ratio_no_pose": ratios["no_pose"],
        "ratio_with_pose": ratios["with_pose"],
        "seconds_per_call": {**seconds, "real": real_timing.median},
        "stage_ms": stage_ms,
        "limits": dict(limits),
        "backend": backend,
        "frames": config.frames,
        "real_frames": real_frames,
        "width": config.width,
        "height": config.height,
        "motion": config.motion,
        "real": {k: v for k, v in quality.items() if k != "samples"},
        "sequence": sequence_metrics(seq),
        "real_samples": {
            name: {k: v for k, v in q.items() if k not in ("rows",)} for name, q in quality["samples"].items()
        },
    }
    size = f"{config.width}x{config.height}"
    return Report(
        title="Perception throughput (frames/s of Pi on real and simulated frames) and quality on the real ones",
        metrics=m,
        tables=[*_tables(config, m, quality, fps, real_cpu), sequence_table(seq), sequence_stage_table(seq)],
        targets=[
            *[
                Target(
                    f"fps_{k}",
                    fps[k],
                    TARGET_FPS[k],
                    ">=",
                    f"frames/s of Pi {how} pose estimation at {size} on one core, simulated frames",
                )
                for k, how in (("no_pose", "without"), ("with_pose", "with"))
            ],
            *_real_targets(quality, fps["real"]),
            *sequence_targets(seq),
        ],
        notes=[
            f"{config.frames} frames of {config.motion} (seed {config.seed}) at {size}, camera backend {backend}, "
            f"median of {config.repeats} repeats after one warm-up.",
            f"{real_frames} real frames of {', '.join(config.real.samples)} at 640x480; {total['seen_in_both']} objects "
            f"seen in both frames of a pair, {total['kept_id']} kept their id, {total['with_pose']} had an estimated pose "
            f"(by solver: {total['pose_solvers']}).",
            _relations_note(quality["relations"]),
            "Limits in force while timing: "
            + ", ".join(f"{k} {'not limited' if v is None else v}" for k, v in limits.items())
            + ".",
        ],
    )


def _relations_note(checks: dict[str, Any]) -> str:
    """The label-free relation checks of the real frames in words."""
    on = checks["on_max"]
    return (
        f"Relations on the real frames: largest near over {checks['far_pairs']} pairs more than "
        f"{FAR_GAP:g} m apart {_fmt(checks['near_far_max'])}; largest on_support over {checks['hidden_bottoms']} "
        f"objects with a hidden bottom {_fmt(checks['on_support_hidden_max'])}; largest on "
        + (
            "none"
            if on is None
            else f"{on['grade']:.2f} (frame {on['frame']}, ids {on['pair'][0]} on {on['pair'][1]})"
        )
        + "."
    )


def _fmt(value: float | None) -> str:
    return "none" if value is None else f"{value:.3f}"
