"""Recording scripted tabletop runs as RGB-D sequences with ground truth (``pal record``).

:func:`render_run` plays a :class:`~pal.sim.motions.Script` in the tabletop scene and yields
one :class:`~pal.frames.RGBDFrame` per scripted instant, with the ground-truth
instance labels (:data:`~pal.sim.tabletop.OBJECT_LABELS`) and every object's
``camera_from_object``. :func:`record` writes them in the ``pal`` sequence layout
(:mod:`pal.io.sequence_files`, read by :mod:`pal.perception.sequence`): rgb, 16-bit depth
(1 mm units), ``gt/masks``, ``gt/poses.npz`` and provenance (motion, seed, drawn parameters,
camera, backend, noise). Like all of :mod:`pal.sim`, this module does not import
:mod:`pal.perception`.

Sensor model: rendered depth is exact, so by default a little noise is added, drawn from the
run's seed: depth ``z + N(0, (depth_noise · z²)²)`` (``depth_noise`` metres at 1 m, the
quadratic growth of stereo/structured-light sensors; 2 mm at 1 m is about 0.7 mm at the
table) and RGB ``N(0, rgb_noise²)`` grey levels per channel. Depth is then quantised to 1 mm
by the writer. Set both to 0 for exact frames.

**The harder tabletop** (``RecordConfig(realism=Realism())``) is what a real sensor in a real
room sees, so that simulated results stop being an upper bound:

- an **occluding hand and forearm** reaches over the moved object and withdraws
  (:func:`pal.sim.motions.occluder_path`; ground-truth id 4, ``"occluder"``);
- a **real sensor's depth**: disparity quantised to ``disparity_step`` (structured light, so
  depth steps grow with z²), **holes** where the projector is shadowed (a band of
  ``shadow_px`` pixels beside every occluding edge, on the side away from the projector) and at
  depth edges (each pixel next to a jump of more than 2 cm lost with probability
  ``edge_dropout``), and random dropouts (``dropout``);
- **motion blur**: each frame's colour is the mean of ``blur_subframes`` renders over the
  exposure (``exposure`` of the frame interval, the objects moved along their script);
- **lighting changes**: every light is scaled by ``1 + lighting * sin(2 pi t / 2.5 s + phase)``
  plus a step of ``lighting / 2`` half-way through the run (a lamp switched on).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from pal.checks import check_float, check_seed
from pal.frames import RGBDFrame
from pal.io.sequence_files import SequenceWriter
from pal.sim.motions import MOTIONS, Script, occluder_path, script
from pal.sim.tabletop import (
    CAMERA,
    OBJECT_LABELS,
    OCCLUDER,
    OCCLUDER_LABEL,
    Tabletop,
    load_tabletop,
    scene_digest,
)

__all__ = ["MAX_FPS", "Realism", "RecordConfig", "RecordedFrame", "record", "render_run", "sensor_depth"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Realism:
    """What makes the harder tabletop hard (module docstring).

    Attributes:
        occluder: the hand and forearm reach over the moved object.
        disparity_step: depth is quantised in disparity ``1 / z`` to steps of this size, 1/m
            (0.0029 is a Kinect's 1/8 pixel; 0: no quantisation).
        shadow_px: width of the projector's shadow beside occluding edges, pixels at 640
            columns (0: none).
        edge_dropout: probability that a pixel next to a depth jump > 2 cm has no reading.
        dropout: probability that any pixel has no reading.
        blur_subframes: renders averaged per frame (1: no motion blur).
        exposure: exposure time as a fraction of the frame interval.
        lighting: amplitude of the lighting changes (0: constant lighting).
    """

    occluder: bool = True
    disparity_step: float = 0.0029
    shadow_px: int = 4
    edge_dropout: float = 0.5
    dropout: float = 0.003
    blur_subframes: int = 3
    exposure: float = 0.5
    lighting: float = 0.25

    def __post_init__(self) -> None:
        for name in ("edge_dropout", "dropout", "exposure"):
            v = getattr(self, name)
            if not 0 <= v <= 1:
                raise ValueError(f"{name} is {v}, expected in [0, 1]")
        if (
            self.disparity_step < 0
            or self.shadow_px < 0
            or self.blur_subframes < 1
            or not 0 <= self.lighting < 1
        ):
            raise ValueError(
                f"need disparity_step >= 0, shadow_px >= 0, blur_subframes >= 1 and lighting in [0, 1); got {self}"
            )


#: The highest frame rate a recording may ask for, frames per second.
MAX_FPS = 1000.0


@dataclass(frozen=True)
class RecordConfig:
    """One recorded run.

    Attributes:
        motion: a key of :data:`pal.sim.motions.MOTIONS`.
        seed: run seed (path, speed, parked objects, sensor noise).
        fps: frames per second, in ``(0, MAX_FPS]``.
        width, height: image size, pixels.
        depth_noise: depth noise std at 1 m, metres (grows with z²); 0 for none.
        rgb_noise: colour noise std, grey levels; 0 for none.
        backend: camera backend (:data:`pal.sim.camera.BACKENDS`).
        texture_seed: seed of the procedural textures (the objects' appearance).
        realism: the harder tabletop's occluder, sensor holes, blur and lighting, or None for
            the clean scene.
    """

    motion: str
    seed: int = 0
    fps: float = 15.0
    width: int = 640
    height: int = 480
    depth_noise: float = 0.002
    rgb_noise: float = 2.0
    backend: str = "auto"
    texture_seed: int = 0
    realism: Realism | None = None

    def __post_init__(self) -> None:
        if self.motion not in MOTIONS:
            raise ValueError(f"unknown motion {self.motion!r}; expected one of {sorted(MOTIONS)}")
        check_seed("seed", self.seed)
        check_seed("texture_seed", self.texture_seed)
        check_float("fps", self.fps, 0.0, MAX_FPS, open_low=True)
        if self.width < 16 or self.height < 16:
            raise ValueError(
                f"image size width={self.width} x height={self.height} pixels is too small; "
                "expected width and height >= 16"
            )
        check_float("depth_noise", self.depth_noise, 0.0)
        check_float("rgb_noise", self.rgb_noise, 0.0)


@dataclass(frozen=True, eq=False)
class RecordedFrame:
    """A rendered frame with its ground truth.

    Attributes:
        frame: the rendered RGB-D frame.
        poses: object -> (4, 4) camera_from_object, metres.
        backend: the camera backend that rendered it.
    """

    frame: RGBDFrame
    poses: dict[str, np.ndarray]
    backend: str


def _blend(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    """The pose a fraction ``s`` of the way from ``a`` to ``b`` ((4, 4); rotation by slerp)."""
    T = np.eye(4)
    T[:3, 3] = (1 - s) * a[:3, 3] + s * b[:3, 3]
    T[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]])))([s]).as_matrix()[0]
    return T


def sensor_depth(depth: np.ndarray, realism: Realism, rng: np.random.Generator) -> np.ndarray:
    """Quantisation, projector shadows, edge and random dropouts (module docstring)."""
    out = depth.copy()
    valid = out > 0
    if realism.disparity_step > 0:
        q = realism.disparity_step
        out[valid] = (1.0 / (np.rint((1.0 / out[valid]) / q) * q)).astype(np.float32)
    jump = np.zeros(out.shape, bool)
    dx = np.diff(out, axis=1)
    big = np.abs(dx) > 0.02
    jump[:, 1:] |= big
    jump[:, :-1] |= big
    dy = np.diff(out, axis=0)
    big = np.abs(dy) > 0.02
    jump[1:, :] |= big
    jump[:-1, :] |= big
    holes = jump & (rng.random(out.shape) < realism.edge_dropout)
    width = round(realism.shadow_px * out.shape[1] / 640)
    if width > 0:
        # the projector sits to the camera's right: the far side of an edge whose near side is on
        # its right lies in the near object's shadow
        near_right = np.zeros(out.shape, bool)
        near_right[:, :-1] = dx < -0.02
        kernel = np.zeros((1, 2 * width + 1), np.uint8)
        kernel[0, : width + 1] = 1
        holes |= cv2.dilate(near_right.view(np.uint8), kernel, anchor=(width, 0)).view(bool) & valid
    holes |= rng.random(out.shape) < realism.dropout
    out[holes] = 0.0
    return out


def render_run(config: RecordConfig, run: Script | None = None) -> Iterator[RecordedFrame]:
    """Render a scripted run frame by frame (noise and realism included, see the module docstring).

    Args:
        config: the run; its motion, seed and fps draw the script unless ``run`` is given.
        run: an explicit script (its motion must match ``config.motion``).
    """
    run = run or script(config.motion, config.seed, config.fps)
    if run.motion != config.motion:
        raise ValueError(f"script is for {run.motion!r} but the config asks for {config.motion!r}")
    real = config.realism
    scene = load_tabletop(texture_seed=config.texture_seed, occluder=real is not None and real.occluder)
    poses = dict(run.poses)
    if scene.occluder:
        poses[OCCLUDER] = occluder_path(run, config.seed)[0]
    noise = np.random.default_rng(np.random.SeedSequence([int(config.seed), 0x5E45]))
    phase = float(noise.uniform(0, 2 * np.pi))
    with scene.camera(config.width, config.height, config.backend) as cam:
        for k, t in enumerate(run.timestamps):
            if real is not None and real.lighting > 0:
                step = real.lighting / 2 if t > run.timestamps[-1] / 2 else 0.0
                scene.set_lighting(1.0 + real.lighting * np.sin(2 * np.pi * t / 2.5 + phase) + step)
            subframes = 1 if real is None or k == 0 else real.blur_subframes
            rgb_sum = None
            for j in range(subframes):
                # sub-frame j of n ends the exposure at j = n - 1, at the frame's own poses
                s = 1.0 - real.exposure * (subframes - 1 - j) / max(subframes - 1, 1) if real else 1.0
                _place(scene, poses, k, s)
                view = cam.render()
                rgb_sum = view.rgb.astype(np.float32) if rgb_sum is None else rgb_sum + view.rgb
            assert rgb_sum is not None
            depth = view.depth
            rgb = (rgb_sum / subframes).astype(np.float32)
            if config.depth_noise > 0:
                unit = noise.normal(0.0, 1.0, depth.shape).astype(np.float32)
                z = depth + unit * np.float32(config.depth_noise) * depth * depth  # std grows with z²
                depth = np.where(depth > 0, np.maximum(z, 0.0), 0.0).astype(np.float32)
            if real is not None:
                depth = sensor_depth(depth, real, noise)
            if config.rgb_noise > 0:
                rgb = rgb + noise.normal(0.0, config.rgb_noise, rgb.shape)
            rgb = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
            frame = RGBDFrame(rgb=rgb, depth=depth, K=view.K, timestamp=float(t), labels=scene.labels(view))
            yield RecordedFrame(frame, scene.camera_from_objects(view), view.backend)


def _place(scene: Tabletop, poses: dict[str, np.ndarray], k: int, s: float) -> None:
    """Put every body at its pose a fraction ``s`` of the way from frame k-1 to frame k."""
    for name, P in poses.items():
        scene.set_pose(name, P[k] if s >= 1.0 or k == 0 else _blend(P[k - 1], P[k], s))
    scene.forward()


def record(
    config: RecordConfig, out: str | os.PathLike[str], *, overwrite: bool = False, progress_bar: bool = False
) -> Path:
    """Record one run to the sequence directory ``out`` (module docstring); returns its path.

    Raises:
        pal.io.sequence_files.SequenceError: ``out`` already holds a sequence and not ``overwrite``.
    """
    run = script(config.motion, config.seed, config.fps)
    metadata = {
        "source": "pal.sim.recording",
        "scene": "tabletop",
        "scene_sha256": scene_digest(
            config.texture_seed, config.realism is not None and config.realism.occluder
        ),
        "camera": CAMERA,
        "motion": config.motion,
        "object": run.object,
        "kind": MOTIONS[config.motion].kind,
        "seed": int(config.seed),
        "config": asdict(config),
        "script": run.params,
    }
    frames = render_run(config, run)
    if progress_bar:
        from tqdm import tqdm

        frames = iter(tqdm(frames, total=len(run), desc=f"record {config.motion}", unit="frame"))
    labels = {v: k for k, v in OBJECT_LABELS.items()}
    if config.realism is not None and config.realism.occluder:
        labels[OCCLUDER_LABEL] = OCCLUDER
    with SequenceWriter(out, metadata=metadata, label_names=labels, overwrite=overwrite) as writer:
        for rec in frames:
            writer.append(rec.frame, rec.poses)
            writer.metadata["backend"] = rec.backend
    logger.info("recorded %s (seed %d): %d frames in %s", config.motion, config.seed, len(run), out)
    return Path(out)
