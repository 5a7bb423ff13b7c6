"""``pal bench perception``: frames per second of the perception pipeline Π at 640x480, one core.

The frames are one scripted tabletop run (default ``box-rotation``, all three objects in view,
sensor noise on) rendered once into memory. Then, alternating inside each repeat
(:func:`pal.experiments.timing.measure_interleaved`):

- ``render``: the baseline — placing the objects and rendering the same frames with the
  MuJoCo camera (RGB, depth and segmentation; EGL or the ray-cast fallback);
- ``no_pose``: Π without pose estimation (segmentation, tracking, EEMS, relations, scene);
- ``with_pose``: Π with pose estimation (the default pipeline).

Each contender processes all frames from a fresh state. Figures: ``fps_no_pose``,
``fps_with_pose``, ``render_fps`` (frames / median seconds), their ratios to ``render_fps``,
and the median per-stage milliseconds Π reports in ``PerceptionState.timings``.

**One core**: while timing, the process is pinned to one CPU (``os.sched_setaffinity``),
OpenCV runs one thread and the BLAS thread pool is limited to one thread (threadpoolctl, when
installed); the numbers are reported with how many of these limits were in force. Targets
(issue 4): ≥ 30 frames/s without pose, ≥ 10 with pose.
"""

from __future__ import annotations

import contextlib
import logging
import os
import statistics
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import cv2

from pal.experiments.timing import markdown_table, measure_interleaved, ratio
from pal.perception import Pipeline, PipelineConfig, RGBDFrame
from pal.sim.motions import script
from pal.sim.recording import RecordConfig, render_run
from pal.sim.tabletop import load_tabletop

__all__ = ["TARGET_FPS_NO_POSE", "TARGET_FPS_WITH_POSE", "Config", "Result", "one_core", "run"]

log = logging.getLogger(__name__)

TARGET_FPS_NO_POSE = 30.0
TARGET_FPS_WITH_POSE = 10.0


@dataclass(frozen=True)
class Config:
    """Benchmark settings.

    Attributes:
        motion: the scripted run whose frames are timed.
        seed: its seed.
        frames: how many of its frames (from the start; the run is at least 3 s at 15 frames/s).
        width, height: image size, pixels.
        repeats: timed repeats (median reported) after one warm-up.
        one_core: pin to one CPU and one thread while timing.
        backend: camera backend.
    """

    motion: str = "box-rotation"
    seed: int = 0
    frames: int = 45
    width: int = 640
    height: int = 480
    repeats: int = 3
    one_core: bool = True
    backend: str = "auto"

    @classmethod
    def quick(cls) -> Config:
        return cls(frames=10, repeats=1)


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


@dataclass(frozen=True)
class Result:
    """Frames per second of each contender (module docstring)."""

    fps_no_pose: float
    fps_with_pose: float
    render_fps: float
    seconds: dict[str, float]
    stage_ms: dict[str, dict[str, float]]
    limits: dict[str, Any]
    backend: str
    frames: int
    config: Config = field(default_factory=Config)

    def to_dict(self) -> dict[str, Any]:
        return {
            "fps_no_pose": self.fps_no_pose,
            "fps_with_pose": self.fps_with_pose,
            "render_fps": self.render_fps,
            "ratio_no_pose": ratio(self.fps_no_pose, self.render_fps),
            "ratio_with_pose": ratio(self.fps_with_pose, self.render_fps),
            "targets": {"fps_no_pose": TARGET_FPS_NO_POSE, "fps_with_pose": TARGET_FPS_WITH_POSE},
            "met": {
                "fps_no_pose": self.fps_no_pose >= TARGET_FPS_NO_POSE,
                "fps_with_pose": self.fps_with_pose >= TARGET_FPS_WITH_POSE,
            },
            "seconds_per_call": dict(self.seconds),
            "stage_ms": {k: dict(v) for k, v in self.stage_ms.items()},
            "limits": dict(self.limits),
            "backend": self.backend,
            "frames": self.frames,
            "width": self.config.width,
            "height": self.config.height,
            "motion": self.config.motion,
        }

    def to_markdown(self) -> str:
        rows = [
            ["render (baseline)", self.seconds["render"], self.render_fps, 1.0, "-"],
            [
                "Π without pose",
                self.seconds["no_pose"],
                self.fps_no_pose,
                ratio(self.fps_no_pose, self.render_fps),
                f">= {TARGET_FPS_NO_POSE:g}: {'met' if self.fps_no_pose >= TARGET_FPS_NO_POSE else 'NOT met'}",
            ],
            [
                "Π with pose",
                self.seconds["with_pose"],
                self.fps_with_pose,
                ratio(self.fps_with_pose, self.render_fps),
                f">= {TARGET_FPS_WITH_POSE:g}: {'met' if self.fps_with_pose >= TARGET_FPS_WITH_POSE else 'NOT met'}",
            ],
        ]
        stages = sorted({s for v in self.stage_ms.values() for s in v})
        c = self.config
        return (
            "\n".join(
                [
                    "## Perception throughput",
                    "",
                    f"{self.frames} frames of `{c.motion}` (seed {c.seed}) at {c.width}x{c.height}, camera backend `{self.backend}`, "
                    f"median of {c.repeats} repeats; limits: {self.limits}.",
                    "",
                    markdown_table(["", "seconds per call", "frames/s", "/ render", "target"], rows),
                    "",
                    "Median milliseconds per frame by stage:",
                    "",
                    markdown_table(
                        ["stage", *self.stage_ms],
                        [[s, *[self.stage_ms[k].get(s) for k in self.stage_ms]] for s in stages],
                    ),
                ]
            )
            + "\n"
        )

    def figures(self) -> dict[str, Any]:
        return {}


def _stage_ms(states: list[Any]) -> dict[str, float]:
    keys = sorted({k for s in states for k in s.timings})
    return {k: 1000.0 * statistics.median(s.timings.get(k, 0.0) for s in states) for k in keys}


def run(config: Config, progress_bar: bool = False) -> Result:
    """Render the frames once, then time rendering and Π with and without pose estimation."""
    if config.frames < 2 or config.repeats < 1:
        raise ValueError(
            f"frames must be >= 2 and repeats >= 1, got frames={config.frames}, repeats={config.repeats}"
        )
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
    seconds = {k: t.median for k, t in timings.items()}
    fps = {k: config.frames / s for k, s in seconds.items()}
    result = Result(
        fps_no_pose=fps["no_pose"],
        fps_with_pose=fps["with_pose"],
        render_fps=fps["render"],
        seconds=seconds,
        stage_ms={
            "no_pose": _stage_ms(timings["no_pose"].result),
            "with_pose": _stage_ms(timings["with_pose"].result),
        },
        limits=limits,
        backend=backend,
        frames=config.frames,
        config=config,
    )
    for name, value, target in (
        ("no pose", result.fps_no_pose, TARGET_FPS_NO_POSE),
        ("with pose", result.fps_with_pose, TARGET_FPS_WITH_POSE),
    ):
        if value < target:
            log.warning("perception %s runs at %.1f frames/s, below the target %g", name, value, target)
    return result
