"""Recording scripted tabletop runs as RGB-D sequences with ground truth (``pal record``).

:func:`render_run` plays a :class:`~pal.sim.motions.Script` in the tabletop scene and yields
one :class:`~pal.frames.RGBDFrame` per scripted instant, with the ground-truth
instance labels (:data:`~pal.sim.tabletop.OBJECT_LABELS`) and every object's
``camera_from_object``. :func:`record` writes them in the ``pal`` sequence layout
(:mod:`pal.sequence_files`, read by :mod:`pal.perception.sequence`): rgb, 16-bit depth
(1 mm units), ``gt/masks``, ``gt/poses.npz`` and provenance (motion, seed, drawn parameters,
camera, backend, noise). Like all of :mod:`pal.sim`, this module does not import
:mod:`pal.perception`.

Sensor model: rendered depth is exact, so by default a little noise is added, drawn from the
run's seed: depth ``z + N(0, (depth_noise · z²)²)`` (``depth_noise`` metres at 1 m, the
quadratic growth of stereo/structured-light sensors; 2 mm at 1 m is about 0.7 mm at the
table) and RGB ``N(0, rgb_noise²)`` grey levels per channel. Depth is then quantised to 1 mm
by the writer. Set both to 0 for exact frames.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pal.frames import RGBDFrame
from pal.sequence_files import SequenceWriter
from pal.sim.motions import MOTIONS, Script, script
from pal.sim.tabletop import CAMERA, OBJECT_LABELS, load_tabletop, scene_digest

__all__ = ["RecordConfig", "RecordedFrame", "record", "render_run"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordConfig:
    """One recorded run.

    Attributes:
        motion: a key of :data:`pal.sim.motions.MOTIONS`.
        seed: run seed (path, speed, parked objects, sensor noise).
        fps: frames per second.
        width, height: image size, pixels.
        depth_noise: depth noise std at 1 m, metres (grows with z²); 0 for none.
        rgb_noise: colour noise std, grey levels; 0 for none.
        backend: camera backend (:data:`pal.sim.camera.BACKENDS`).
        texture_seed: seed of the procedural textures (the objects' appearance).
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

    def __post_init__(self) -> None:
        if self.motion not in MOTIONS:
            raise ValueError(f"unknown motion {self.motion!r}; expected one of {sorted(MOTIONS)}")
        if self.width < 16 or self.height < 16:
            raise ValueError(
                f"image size width={self.width} x height={self.height} pixels is too small; "
                "expected width and height >= 16"
            )
        if not (self.depth_noise >= 0 and self.rgb_noise >= 0):
            raise ValueError(
                f"depth_noise ({self.depth_noise}) and rgb_noise ({self.rgb_noise}) must be >= 0"
            )


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


def render_run(config: RecordConfig, run: Script | None = None) -> Iterator[RecordedFrame]:
    """Render a scripted run frame by frame (noise included, see the module docstring).

    Args:
        config: the run; its motion, seed and fps draw the script unless ``run`` is given.
        run: an explicit script (its motion must match ``config.motion``).
    """
    run = run or script(config.motion, config.seed, config.fps)
    if run.motion != config.motion:
        raise ValueError(f"script is for {run.motion!r} but the config asks for {config.motion!r}")
    scene = load_tabletop(texture_seed=config.texture_seed)
    noise = np.random.default_rng(np.random.SeedSequence([int(config.seed), 0x5E45]))
    with scene.camera(config.width, config.height, config.backend) as cam:
        for k, t in enumerate(run.timestamps):
            for name in scene.objects:
                scene.set_pose(name, run.poses[name][k])
            scene.forward()
            view = cam.render()
            depth = view.depth
            rgb = view.rgb
            if config.depth_noise > 0:
                unit = noise.normal(0.0, 1.0, depth.shape).astype(np.float32)
                z = depth + unit * np.float32(config.depth_noise) * depth * depth  # std grows with z²
                depth = np.where(depth > 0, np.maximum(z, 0.0), 0.0).astype(np.float32)
            if config.rgb_noise > 0:
                jitter = noise.normal(0.0, config.rgb_noise, rgb.shape)
                rgb = np.clip(rgb + jitter, 0, 255).astype(np.uint8)
            frame = RGBDFrame(rgb=rgb, depth=depth, K=view.K, timestamp=float(t), labels=scene.labels(view))
            yield RecordedFrame(frame, scene.camera_from_objects(view), view.backend)


def record(
    config: RecordConfig, out: str | os.PathLike[str], *, overwrite: bool = False, progress_bar: bool = False
) -> Path:
    """Record one run to the sequence directory ``out`` (module docstring); returns its path.

    Raises:
        pal.sequence_files.SequenceError: ``out`` already holds a sequence and not ``overwrite``.
    """
    run = script(config.motion, config.seed, config.fps)
    metadata = {
        "source": "pal.sim.recording",
        "scene": "tabletop",
        "scene_sha256": scene_digest(config.texture_seed),
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
    with SequenceWriter(out, metadata=metadata, label_names=labels, overwrite=overwrite) as writer:
        for rec in frames:
            writer.append(rec.frame, rec.poses)
            writer.metadata["backend"] = rec.backend
    logger.info("recorded %s (seed %d): %d frames in %s", config.motion, config.seed, len(run), out)
    return Path(out)
