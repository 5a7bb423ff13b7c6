"""The tabletop scene (``assets/tabletop.xml``): a table, an oblique overhead camera, a box, a boat, a ball.

The scene is built as a ``mujoco.MjSpec`` so that it can be composed: :func:`tabletop_spec`
returns the uncompiled spec (with the procedural textures and hull mesh of
:mod:`pal.sim.tabletop_assets` attached as in-memory files), optionally without some of the
objects; another body can be attached to it before compiling, e.g.::

    spec = tabletop_spec(objects=("box", "ball"))
    arm = mujoco.MjSpec.from_file(str(body_path("arm")))
    spec.worldbody.add_frame(pos=[0, -0.45, 0.0]).attach_body(arm.body("torso"), "arm/", "")
    model = spec.compile()

:func:`load_tabletop` compiles it and returns a :class:`Tabletop` with helpers to place the
objects (in table coordinates) and to read their ground-truth poses and instance labels.

Frames: the *table frame* has its origin at the centre of the table top, z up, +y away from
the camera. Object poses are ``table_from_object`` (4, 4) transforms of the objects' body
frames (box: its centre; boat: the middle of the keel line; ball: its centre).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

from pal.sim.camera import Camera, CameraFrame
from pal.sim.tabletop_assets import generate_assets

__all__ = [
    "CAMERA",
    "OBJECTS",
    "OBJECT_LABELS",
    "RESTING_HEIGHT",
    "Tabletop",
    "load_tabletop",
    "scene_digest",
    "tabletop_path",
    "tabletop_spec",
]

#: The objects of the scene, in label order.
OBJECTS: tuple[str, ...] = ("box", "boat", "ball")
#: Ground-truth instance ids written with recordings (0 = background: table, floor).
OBJECT_LABELS: dict[str, int] = {"box": 1, "boat": 2, "ball": 3}
#: Height of each object's body origin above the table top when it rests upright, metres.
RESTING_HEIGHT: dict[str, float] = {"box": 0.04, "boat": 0.0, "ball": 0.04}
#: Ball radius, metres (rolling without slipping turns it by distance / radius).
BALL_RADIUS = 0.04
#: The camera of the scene.
CAMERA = "overhead"


def tabletop_path() -> Path:
    """Path of the scene's MJCF file (package data)."""
    return Path(str(resources.files("pal.sim").joinpath("assets", "tabletop.xml")))


def scene_digest(texture_seed: int = 0) -> str:
    """SHA-256 of the scene's MJCF text and generated assets (provenance of recordings)."""
    h = hashlib.sha256(tabletop_path().read_bytes())
    for name, blob in sorted(generate_assets(texture_seed).items()):
        h.update(name.encode())
        h.update(blob)
    return h.hexdigest()


def tabletop_spec(objects: Sequence[str] = OBJECTS, texture_seed: int = 0) -> mujoco.MjSpec:
    """The scene as an uncompiled ``MjSpec`` (see the module docstring).

    Args:
        objects: the objects to keep, a subset of :data:`OBJECTS`.
        texture_seed: seed of the procedural textures.

    Raises:
        ValueError: an unknown or repeated object name.
    """
    names = tuple(objects)
    unknown = [n for n in names if n not in OBJECTS]
    if unknown or len(set(names)) != len(names):
        raise ValueError(f"objects {list(names)} must be distinct names from {list(OBJECTS)}")
    xml = tabletop_path().read_text(encoding="utf-8")
    spec = mujoco.MjSpec.from_string(xml, assets=generate_assets(texture_seed))
    for name in OBJECTS:
        if name not in names:
            spec.delete(spec.body(name))
    return spec


@dataclass(eq=False)
class Tabletop:
    """A compiled tabletop scene with its simulation data.

    Attributes:
        model, data: the compiled model and its data.
        objects: the objects present.
        world_from_table: (4, 4) pose of the table frame in the world.
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    objects: tuple[str, ...]
    world_from_table: np.ndarray

    def _body(self, name: str) -> int:
        if name not in self.objects:
            raise ValueError(f"object {name!r} is not in this scene; it has {list(self.objects)}")
        return int(mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name))

    def set_pose(self, name: str, table_from_object: np.ndarray) -> None:
        """Place an object: writes its free joint's ``qpos`` (call :meth:`forward` or render after).

        Args:
            name: the object's body name.
            table_from_object: (4, 4) pose in table coordinates, metres.
        """
        T = np.asarray(table_from_object, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(
                f"pose of {name!r} has shape {T.shape} or non-finite entries; expected a finite (4, 4)"
            )
        W = self.world_from_table @ T
        jnt = int(self.model.body_jntadr[self._body(name)])
        adr = int(self.model.jnt_qposadr[jnt])
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(W[:3, :3]).ravel())
        self.data.qpos[adr : adr + 3] = W[:3, 3]
        self.data.qpos[adr + 3 : adr + 7] = quat
        self.data.qvel[int(self.model.jnt_dofadr[jnt]) : int(self.model.jnt_dofadr[jnt]) + 6] = 0.0

    def forward(self) -> None:
        """Recompute positions from ``qpos`` (``mj_kinematics``)."""
        mujoco.mj_kinematics(self.model, self.data)

    def world_from_object(self, name: str) -> np.ndarray:
        """(4, 4) current pose of an object's body in the world (after :meth:`forward`)."""
        b = self._body(name)
        T = np.eye(4)
        T[:3, :3] = self.data.xmat[b].reshape(3, 3)
        T[:3, 3] = self.data.xpos[b]
        return T

    def camera(self, width: int = 640, height: int = 480, backend: str = "auto") -> Camera:
        """The overhead camera (close it when done, or use it as a context manager)."""
        return Camera(self.model, self.data, CAMERA, width=width, height=height, backend=backend)

    def labels(self, frame: CameraFrame) -> np.ndarray:
        """(H, W) int32 ground-truth instance ids of a rendered view: :data:`OBJECT_LABELS`, 0 elsewhere."""
        lut = np.zeros(self.model.nbody + 1, np.int32)  # index body id + 1; -1 (background) -> 0
        for name in self.objects:
            lut[self._body(name) + 1] = OBJECT_LABELS[name]
        return lut[frame.body_segmentation + 1]

    def camera_from_objects(self, frame: CameraFrame) -> dict[str, np.ndarray]:
        """Ground-truth ``camera_from_object`` (4, 4) of every object in the OpenCV camera frame of ``frame``."""
        camera_from_world = np.linalg.inv(frame.world_from_camera)
        return {name: camera_from_world @ self.world_from_object(name) for name in self.objects}


def load_tabletop(objects: Sequence[str] = OBJECTS, texture_seed: int = 0) -> Tabletop:
    """Compile the scene (:func:`tabletop_spec`) and place the objects at their XML poses."""
    spec = tabletop_spec(objects, texture_seed)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    top = int(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table_top"))
    R = data.geom_xmat[top].reshape(3, 3).copy()
    half = float(model.geom_size[top][2])
    world_from_table = np.eye(4)
    world_from_table[:3, :3] = R
    world_from_table[:3, 3] = data.geom_xpos[top] + R[:, 2] * half
    return Tabletop(model, data, tuple(n for n in OBJECTS if n in objects), world_from_table)
