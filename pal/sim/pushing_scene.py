"""The pushing world's scene: the arm at the tabletop with a box and a ball, as a ``mujoco.MjSpec``.

The scene is composed from the shipped tabletop (:func:`pal.sim.tabletop.tabletop_spec`) and the
shipped arm (``assets/arm.xml``); neither file is changed. :class:`pal.sim.pushing.PushingEnv`
runs it:

- **Arm.** Only ``shoulder_horizontal`` and ``elbow`` stay joints (both hinge about the vertical),
  so the arm moves in a horizontal plane 3.5 cm above the table top and its hand sweeps the table;
  the other joints are removed (rigid). The torque motors are replaced by position servos
  (``kp``, ``kv``, torque limit ``max_torque``): the action is the target angle of each joint, rad,
  within the joint's range. The torso sits behind the far edge of the table, facing the camera.
- **Objects.** The tabletop's ball (radius 4 cm) and its printed box, resized to a toy carton of
  9 x 7 x 6 cm, 0.12 kg (:data:`BOX_HALF`), in proportion to the infant arm's 25 cm reach.
- **Contacts.** The arm's limb and hand geoms collide with the objects only (contype 2); the
  objects collide with the table, each other, the arm and an invisible fence (geom group 3, never
  rendered, contype 4) that runs along the table's edges so nothing falls off. The ball gets
  rolling friction (condim 6), so it stops within a few centimetres instead of rolling forever.
- **Camera.** The tabletop's oblique RGB-D camera, moved (same tilt, 44 deg from the vertical) so
  that it looks at the arm's workspace from ``camera_distance``.

Frames: the *table frame* of :mod:`pal.sim.tabletop` (origin at the centre of the table top, z up,
+y away from the camera).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from pal.sim.bodies import body_path
from pal.sim.tabletop import CAMERA, RESTING_HEIGHT, tabletop_spec

__all__ = [
    "BOX_HALF",
    "BOX_MASS",
    "JOINTS",
    "OBJECT_RADIUS",
    "RESTING",
    "PushingLayout",
    "pushing_spec",
    "quat_z",
]

#: Short joint name (world-model variables) -> joint name in the compiled model.
JOINTS: dict[str, str] = {"shoulder": "arm/shoulder_horizontal", "elbow": "arm/elbow"}
#: Half extents (x, y, z) of the box in this world, m: a toy carton an infant's hand can push
#: (the tabletop's 14 x 10 x 8 cm carton is large for a 25 cm reach); same texture, 0.12 kg.
BOX_HALF: tuple[float, float, float] = (0.045, 0.035, 0.03)
BOX_MASS = 0.12
#: Radius of each object's footprint (circumscribed circle), metres: spacing at placement.
OBJECT_RADIUS: dict[str, float] = {"box": math.hypot(BOX_HALF[0], BOX_HALF[1]), "ball": 0.04, "boat": 0.12}
#: Height of each object's body origin above the table top at rest, m.
RESTING: dict[str, float] = {**RESTING_HEIGHT, "box": BOX_HALF[2]}
_ARM_CONTACT_GEOMS = (
    "upper_arm",
    "forearm",
    "palm",
    "thumb",
    "finger_index",
    "finger_middle",
    "finger_ring",
    "finger_little",
)
_FENCE_GROUP = 3


@dataclass(frozen=True)
class PushingLayout:
    """Where things are, table frame (metres, degrees).

    Attributes:
        shoulder: (x, y, z) of the shoulder joint; z is the arm's height above the table top.
        yaw_deg: heading of the arm at q = 0 (degrees about z; 180 points at the camera).
        kp, kv: servo stiffness (N m / rad) and damping (N m s / rad).
        max_torque: servo torque limit, N m.
        home: (shoulder, elbow) angles at reset, rad (the hand tucked in near the torso).
        spawn_radius: objects are placed at this range of distances from the shoulder, m.
        spawn_angle_deg: ... and within this range of bearings from the workspace's central bearing
            (the hand's bearing with the shoulder at mid-range, at the middle spawn radius).
        camera_target: (x, y) on the table the camera looks at.
        camera_distance: camera distance from that point, m.
        fence_inset: distance of the invisible fence from the table's edges, m.
        ball_rolling_friction: rolling friction of the ball, m.
    """

    shoulder: tuple[float, float, float] = (0.0, 0.36, 0.035)
    yaw_deg: float = 240.0
    kp: float = 3.0
    kv: float = 1.0
    max_torque: float = 1.5
    home: tuple[float, float] = (math.radians(-25.0), math.radians(-140.0))
    spawn_radius: tuple[float, float] = (0.19, 0.26)
    spawn_angle_deg: tuple[float, float] = (-40.0, 40.0)
    camera_target: tuple[float, float] = (0.03, 0.15)
    camera_distance: float = 0.6
    fence_inset: float = 0.01
    ball_rolling_friction: float = 0.03

    def __post_init__(self) -> None:
        lo, hi = self.spawn_radius
        if not 0 < lo < hi:
            raise ValueError(f"spawn_radius {self.spawn_radius} must satisfy 0 < low < high (metres)")
        if not self.spawn_angle_deg[0] < self.spawn_angle_deg[1]:
            raise ValueError(f"spawn_angle_deg {self.spawn_angle_deg} must satisfy low < high")
        if not (self.kp > 0 and self.kv >= 0 and self.max_torque > 0 and self.camera_distance > 0):
            raise ValueError(f"kp, max_torque and camera_distance must be > 0 and kv >= 0, got {self}")


def quat_z(deg: float) -> np.ndarray:
    """(4,) unit quaternion (w, x, y, z) of a rotation by ``deg`` degrees about z."""
    q = np.zeros(4)
    mujoco.mju_euler2Quat(q, np.array([0.0, 0.0, math.radians(deg)]), "xyz")
    return q


def pushing_spec(
    objects: tuple[str, ...] = ("box", "ball"), layout: PushingLayout | None = None, texture_seed: int = 0
) -> mujoco.MjSpec:
    """The uncompiled pushing world (module docstring).

    Args:
        objects: objects on the table, a subset of :data:`pal.sim.tabletop.OBJECTS`.
        layout: placement and servo parameters.
        texture_seed: seed of the procedural textures.
    """
    layout = layout or PushingLayout()
    spec = tabletop_spec(objects, texture_seed)
    table_z = 0.3  # the "table" frame of tabletop.xml: the table top's surface
    arm = mujoco.MjSpec.from_file(str(body_path("arm")))
    arm.option.timestep, arm.option.iterations = spec.option.timestep, spec.option.iterations
    keep = {j.split("/", 1)[1] for j in JOINTS.values()}
    for joint in list(arm.joints):
        if joint.name not in keep:
            arm.delete(joint)
    for actuator in list(arm.actuators):
        arm.delete(actuator)
    for geom in arm.geoms:
        if geom.name in _ARM_CONTACT_GEOMS:
            geom.contype, geom.conaffinity = 2, 0
    # the torso body sits 0.4 m above its frame and the shoulder 0.1 m along the arm's +y
    yaw = math.radians(layout.yaw_deg)
    sx, sy, sz = layout.shoulder
    base = np.array([sx + 0.1 * math.sin(yaw), sy - 0.1 * math.cos(yaw), table_z + sz - 0.4])
    spec.worldbody.add_frame(pos=base, quat=quat_z(layout.yaw_deg)).attach_body(arm.body("torso"), "arm/", "")
    for short, joint in JOINTS.items():
        act = spec.add_actuator(name=short, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=layout.kp, kv=layout.kv)
        rng = np.radians(spec.joint(joint).range)
        act.ctrllimited, act.ctrlrange = True, rng
        act.forcelimited, act.forcerange = True, [-layout.max_torque, layout.max_torque]
    for name in objects:
        for geom in spec.body(name).geoms:
            geom.conaffinity = 1 | 2 | 4
    if "box" in objects:
        box = spec.geom("box")
        box.size, box.mass = list(BOX_HALF), BOX_MASS
        spec.body("box").pos = [spec.body("box").pos[0], spec.body("box").pos[1], BOX_HALF[2]]
    if "ball" in objects:
        ball = spec.geom("ball")
        ball.condim = 6
        ball.friction = [ball.friction[0], ball.friction[1], layout.ball_rolling_friction]
    # invisible fence along the table edges (table top: 0.9 x 0.7 m)
    hx, hy, h = 0.45 - layout.fence_inset, 0.35 - layout.fence_inset, 0.1
    for name, pos, size in (
        ("fence_left", (-hx - 0.01, 0, h / 2), (0.01, hy, h / 2)),
        ("fence_right", (hx + 0.01, 0, h / 2), (0.01, hy, h / 2)),
        ("fence_near", (0, -hy - 0.01, h / 2), (hx, 0.01, h / 2)),
        ("fence_far", (0, hy + 0.01, h / 2), (hx, 0.01, h / 2)),
    ):
        spec.worldbody.add_geom(
            name=name,
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=[pos[0], pos[1], table_z + pos[2]],
            size=list(size),
            group=_FENCE_GROUP,
            contype=4,
            conaffinity=4,
            rgba=[0, 0, 0, 0],
        )
    # the camera: same orientation as in tabletop.xml, looking at the workspace
    cam = spec.camera(CAMERA)
    tilt = math.atan2(0.6897, 0.7241)  # angle of the optical axis from the vertical
    tx, ty = layout.camera_target
    d = layout.camera_distance
    cam.pos = [tx, ty - d * math.sin(tilt), d * math.cos(tilt)]
    return spec
