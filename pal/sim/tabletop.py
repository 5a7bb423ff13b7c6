"""The tabletop scene (``assets/tabletop.xml``): a table, an oblique overhead camera, a box, a boat, a ball.

With ``occluder=True`` the scene also holds an occluding hand and forearm
(:data:`OCCLUDER`): a free body of capsules and a palm in skin colour, without collisions,
that scripted motions move over the objects (:func:`pal.sim.motions.occluder_path`); its
ground-truth instance id is :data:`OCCLUDER_LABEL`. :meth:`Tabletop.set_lighting` scales the
scene's lights (lighting changes of the harder tabletop, :mod:`pal.sim.recording`).

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
    "OCCLUDER",
    "OCCLUDER_LABEL",
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
#: Body name of the occluding hand and forearm (``occluder=True``).
OCCLUDER = "occluder"
#: Its ground-truth instance id.
OCCLUDER_LABEL = 4
_SKIN = (0.86, 0.66, 0.54, 1.0)


def _add_occluder(spec: mujoco.MjSpec) -> None:
    """A hand and forearm, palm down, fingers towards -x, forearm along +x from the wrist (body frame)."""
    body = spec.worldbody.add_body(name=OCCLUDER, pos=[0.0, 0.0, 1.5])
    body.add_freejoint(name=OCCLUDER)
    geom = {"contype": 0, "conaffinity": 0, "rgba": list(_SKIN), "mass": 0.05}
    cap, box = mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_BOX
    body.add_geom(
        name="occluder_forearm",
        type=cap,
        size=[0.032, 0.13, 0],
        pos=[0.16, 0, 0.01],
        euler=[0, 90, 0],
        **geom,
    )
    body.add_geom(name="occluder_palm", type=box, size=[0.045, 0.042, 0.014], pos=[0.0, 0, 0], **geom)
    for k, dy in enumerate((-0.03, -0.01, 0.01, 0.03)):
        body.add_geom(
            name=f"occluder_finger{k}",
            type=cap,
            size=[0.009, 0.028, 0],
            pos=[-0.07, dy, -0.004],
            euler=[0, 90, 0],
            **geom,
        )
    body.add_geom(
        name="occluder_thumb",
        type=cap,
        size=[0.01, 0, 0],
        fromto=[-0.01, -0.04, -0.006, -0.05, -0.068, -0.006],
        **geom,
    )


def tabletop_path() -> Path:
    """Path of the scene's MJCF file (package data)."""
    return Path(str(resources.files("pal.sim").joinpath("assets", "tabletop.xml")))


def scene_digest(texture_seed: int = 0, occluder: bool = False) -> str:
    """SHA-256 of the scene's MJCF text and generated assets, and the occluder (provenance of recordings)."""
    h = hashlib.sha256(tabletop_path().read_bytes())
    if occluder:
        h.update(b"occluder/2")  # bump when the occluder's geometry changes
    for name, blob in sorted(generate_assets(texture_seed).items()):
        h.update(name.encode())
        h.update(blob)
    return h.hexdigest()


def tabletop_spec(
    objects: Sequence[str] = OBJECTS, texture_seed: int = 0, occluder: bool = False
) -> mujoco.MjSpec:
    """The scene as an uncompiled ``MjSpec`` (see the module docstring).

    Args:
        objects: the objects to keep, a subset of :data:`OBJECTS`.
        texture_seed: seed of the procedural textures.
        occluder: add the occluding hand and forearm (:data:`OCCLUDER`).

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
    if occluder:
        _add_occluder(spec)
    return spec


@dataclass(eq=False)
class Tabletop:
    """A compiled tabletop scene with its simulation data.

    Attributes:
        model, data: the compiled model and its data.
        objects: the objects present.
        world_from_table: (4, 4) pose of the table frame in the world.
        occluder: whether the occluding hand (:data:`OCCLUDER`) is in the scene.
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    objects: tuple[str, ...]
    world_from_table: np.ndarray
    occluder: bool = False

    def __post_init__(self) -> None:
        self._light_base = (
            np.array(self.model.light_diffuse, dtype=np.float64),
            np.array(self.model.vis.headlight.diffuse, dtype=np.float64),
            np.array(self.model.vis.headlight.ambient, dtype=np.float64),
        )

    def _body(self, name: str) -> int:
        if name not in self.objects and not (self.occluder and name == OCCLUDER):
            raise ValueError(f"object {name!r} is not in this scene; it has {list(self.objects)}")
        return int(mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name))

    def set_lighting(self, gain: float) -> None:
        """Scale every light (the sun and the headlight) by ``gain`` (1: as in the MJCF), > 0."""
        if not gain > 0:
            raise ValueError(f"lighting gain is {gain}, expected > 0")
        lights, head_diffuse, head_ambient = self._light_base
        self.model.light_diffuse[:] = np.clip(lights * gain, 0.0, 1.0)
        self.model.vis.headlight.diffuse[:] = np.clip(head_diffuse * gain, 0.0, 1.0)
        self.model.vis.headlight.ambient[:] = np.clip(head_ambient * gain, 0.0, 1.0)

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
        """(H, W) int32 ground-truth instance ids of a view: :data:`OBJECT_LABELS`, the occluder's, 0 elsewhere."""
        lut = np.zeros(self.model.nbody + 1, np.int32)  # index body id + 1; -1 (background) -> 0
        for name in self.objects:
            lut[self._body(name) + 1] = OBJECT_LABELS[name]
        if self.occluder:
            lut[self._body(OCCLUDER) + 1] = OCCLUDER_LABEL
        return lut[frame.body_segmentation + 1]

    def camera_from_objects(self, frame: CameraFrame) -> dict[str, np.ndarray]:
        """Ground-truth ``camera_from_object`` (4, 4) of every object in the OpenCV camera frame of ``frame``."""
        camera_from_world = np.linalg.inv(frame.world_from_camera)
        return {name: camera_from_world @ self.world_from_object(name) for name in self.objects}


def load_tabletop(
    objects: Sequence[str] = OBJECTS, texture_seed: int = 0, occluder: bool = False
) -> Tabletop:
    """Compile the scene (:func:`tabletop_spec`) and place the objects at their XML poses."""
    spec = tabletop_spec(objects, texture_seed, occluder)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    top = int(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table_top"))
    R = data.geom_xmat[top].reshape(3, 3).copy()
    half = float(model.geom_size[top][2])
    world_from_table = np.eye(4)
    world_from_table[:3, :3] = R
    world_from_table[:3, 3] = data.geom_xpos[top] + R[:, 2] * half
    return Tabletop(model, data, tuple(n for n in OBJECTS if n in objects), world_from_table, occluder)
