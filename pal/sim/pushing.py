"""The pushing world as a gymnasium environment: the arm at the tabletop, pushing a box and a ball.

The scene (the arm's two horizontal joints and position servos, the objects, contacts, fence
and camera) is built by :func:`pal.sim.pushing_scene.pushing_spec` (:mod:`pal.sim.pushing_scene`).

Senses: the gymnasium observation is the proprioception ``[q, dq/dt]`` of the two joints (as in
:class:`~pal.sim.env.BabblingEnv`). ``info`` of every reset and step adds ``hand`` (3,), the palm
centre in table coordinates, metres (the agent's sense of where its hand is), and ``touch``
(n_objects,), the fraction of the step's physics sub-steps in which the arm touched each object
(touch sensing). With ``camera=True`` it also carries the view: ``rgbd`` (:class:`pal.frames.RGBDFrame`),
``table_from_camera`` (4, 4) (the calibrated camera pose) and ``self_mask`` (H, W) bool, the
pixels of the agent's own body (what its self-model renders), so an agent needs nothing but
``reset`` and ``step``. Ground truth, for evaluation only, is in ``info["truth"]`` (object name
-> (3,) body centre, table frame, m) and ``info["state"]`` (the :meth:`get_state` vector after
the step, from which it can be replayed), and in :meth:`PushingEnv.object_positions`,
:meth:`PushingEnv.object_poses` and :meth:`PushingEnv.replay` (a batch of alternative actions
from one saved state, with ``mujoco.rollout``).

Frames: the *table frame* of :mod:`pal.sim.tabletop` (origin at the centre of the table top, z up,
+y away from the camera). ``gymnasium.make("pal/Pushing-v0")`` builds the default world.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict
from typing import Any

import gymnasium
import mujoco
import mujoco.rollout
import numpy as np

from pal.checks import check_int
from pal.frames import RGBDFrame
from pal.sim.bodies import LoadedModel
from pal.sim.camera import Camera, CameraFrame
from pal.sim.env import STATE_SPEC, BabblingEnv
from pal.sim.pushing_scene import (
    BOX_HALF,
    JOINTS,
    OBJECT_RADIUS,
    RESTING,
    PushingLayout,
    pushing_spec,
    quat_z,
)
from pal.sim.pushing_scene import BOX_MASS as BOX_MASS  # re-exported
from pal.sim.tabletop import CAMERA, OBJECTS, tabletop_path

__all__ = [
    "BOX_HALF",
    "ENV_ID",
    "JOINTS",
    "OBJECT_RADIUS",
    "RESTING",
    "PushingEnv",
    "PushingLayout",
    "pushing_spec",
]

#: gymnasium registry id.
ENV_ID = "pal/Pushing-v0"


class PushingEnv(BabblingEnv):
    """The pushing world as a gymnasium environment (module docstring).

    Action: target angles of (shoulder, elbow), rad, float32 Box over the joint ranges.
    Observation: ``[q_shoulder, q_elbow, dq_shoulder/dt, dq_elbow/dt]`` float64.

    Reset: joints at ``layout.home`` (servo targets too), zero velocity, and the objects at
    seeded random places (``spawn_radius`` x ``spawn_angle_deg`` around the shoulder, upright,
    random yaw, non-overlapping); ``options={"objects": {name: (x, y, yaw_deg)}}`` places some
    explicitly, ``options={"q": (shoulder, elbow)}`` sets the joints, and
    ``options={"state": s}`` restores a :meth:`get_state` vector instead.

    Args:
        objects: objects on the table (default box and ball).
        layout: geometry and servo parameters.
        frame_skip: physics steps of 2 ms per environment step (default 200: 0.4 s).
        texture_seed: seed of the object textures.
        camera_size: (width, height) of :meth:`camera_frame`, pixels.
        camera_backend: :data:`pal.sim.camera.BACKENDS` entry.
        touch_every: physics steps between two contact checks for ``info["touch"]``.
        camera: put the camera's view in every ``info`` (module docstring).
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"]}  # noqa: RUF012 - gymnasium's class attribute

    def __init__(
        self,
        objects: tuple[str, ...] | list[str] = ("box", "ball"),
        *,
        layout: PushingLayout | None = None,
        frame_skip: int = 200,
        texture_seed: int = 0,
        camera_size: tuple[int, int] = (320, 240),
        camera_backend: str = "auto",
        touch_every: int = 5,
        render_mode: str | None = None,
        camera: bool = False,
    ) -> None:
        objects = tuple(objects)
        if not objects:
            raise ValueError("objects is empty; expected a subset of " + str(list(OBJECTS)))
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r} unknown; expected None or 'rgb_array'")
        check_int("touch_every", touch_every)
        self.layout = layout or PushingLayout()
        spec = pushing_spec(objects, self.layout, texture_seed)
        model = spec.compile()
        digest = hashlib.sha256(
            (spec.to_xml() + repr(sorted(asdict(self.layout).items())) + str(texture_seed)).encode()
        ).hexdigest()
        loaded = LoadedModel(model=model, name="pushing", path=tabletop_path(), sha256=digest)
        super().__init__(loaded, joints=list(JOINTS.values()), actuators=list(JOINTS), frame_skip=frame_skip)
        self.render_mode = render_mode
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": 1.0 / self.dt}
        self.objects: tuple[str, ...] = tuple(n for n in OBJECTS if n in objects)
        self.touch_every = touch_every
        self.camera_size = (int(camera_size[0]), int(camera_size[1]))
        self.camera_backend = camera_backend
        self.camera_info = bool(camera)
        self._camera: Camera | None = None
        m = self.model
        top = int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table_top"))
        self.world_from_table = np.eye(4)
        self.world_from_table[:3, 3] = self.data.geom_xpos[top] + np.array([0.0, 0.0, m.geom_size[top][2]])
        bodies = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) or "" for i in range(m.nbody)]
        self.arm_body_ids = np.array([i for i, n in enumerate(bodies) if n.startswith("arm/")], dtype=np.intp)
        self._arm_geoms = np.array(
            [i for i in range(m.ngeom) if int(m.geom_bodyid[i]) in set(self.arm_body_ids.tolist())], np.intp
        )
        self._object_body = {n: bodies.index(n) for n in self.objects}
        self._object_geoms = {
            n: np.flatnonzero(np.asarray(m.geom_bodyid) == b).astype(np.intp)
            for n, b in self._object_body.items()
        }
        self._object_qpos = {n: int(m.jnt_qposadr[m.body_jntadr[b]]) for n, b in self._object_body.items()}
        self._object_qvel = {n: int(m.jnt_dofadr[m.body_jntadr[b]]) for n, b in self._object_body.items()}
        self._hand_body = bodies.index("arm/hand")
        # the workspace's central bearing: the hand's bearing about the shoulder with the shoulder at
        # mid-range and the elbow bent so that the hand is at the middle of the spawn radii
        self._shoulder = np.array(self.layout.shoulder[:2])
        mid = float(np.mean(self.model.jnt_range[self.joint_ids[0]]))
        r_mid = float(np.mean(self.layout.spawn_radius))
        best = (np.inf, 0.0)
        for elbow in np.linspace(*self.model.jnt_range[self.joint_ids[1]], 301):
            self.data.qpos[self.qpos_indices] = (mid, elbow)
            d = self.hand_position()[:2] - self._shoulder
            best = min(best, (abs(float(np.linalg.norm(d)) - r_mid), math.atan2(d[1], d[0])))
        self._heading = best[1]
        self._links = self._link_lengths()
        self.reset(seed=0)

    @property
    def workspace_bearing(self) -> float:
        """Central bearing of the workspace about the shoulder, rad (where objects are placed)."""
        return float(self._heading)

    @property
    def link_lengths(self) -> tuple[float, float]:
        """(shoulder -> elbow, elbow -> palm centre) in the table plane, m, read from the compiled model."""
        return self._links

    def _link_lengths(self) -> tuple[float, float]:
        # joint anchors and the palm centre of the compiled model, on a scratch MjData (the
        # joints hinge about the vertical, so the planar distances do not depend on q)
        m = self.model
        data = mujoco.MjData(m)
        mujoco.mj_kinematics(m, data)
        shoulder, elbow = (data.xanchor[j, :2] for j in self.joint_ids)
        palm = data.geom_xpos[int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "arm/palm")), :2]
        return float(np.linalg.norm(elbow - shoulder)), float(np.linalg.norm(palm - elbow))

    # ------------------------------------------------------------------ senses
    def hand_position(self) -> np.ndarray:
        """(3,) palm centre in table coordinates, metres (after the last step or reset)."""
        mujoco.mj_kinematics(self.model, self.data)
        b = self._hand_body
        world = self.data.xpos[b] + self.data.xmat[b].reshape(3, 3) @ np.array([0.0, 0.03, 0.0])
        return world - self.world_from_table[:3, 3]

    def _touching(self) -> np.ndarray:
        n = int(self.data.ncon)
        out = np.zeros(len(self.objects))
        if n == 0:
            return out
        pairs = np.asarray(self.data.contact.geom[:n])
        arm_a, arm_b = np.isin(pairs[:, 0], self._arm_geoms), np.isin(pairs[:, 1], self._arm_geoms)
        for k, name in enumerate(self.objects):
            g = self._object_geoms[name]
            hit = (arm_a & np.isin(pairs[:, 1], g)) | (arm_b & np.isin(pairs[:, 0], g))
            out[k] = float(hit.any())
        return out

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Servo towards the target angles for ``frame_skip`` physics steps.

        Returns:
            ``(observation, 0.0, False, False, info)``; ``info`` has ``ctrl`` (applied targets),
            ``time`` (s), ``hand`` (3,) m and ``touch`` (n_objects,) in [0, 1] (module docstring).
        """
        ctrl = self.check_action(action)
        self.data.ctrl[self.actuator_ids] = ctrl
        touch = np.zeros(len(self.objects))
        checks = 0
        done = 0
        while done < self.frame_skip:
            n = min(self.touch_every, self.frame_skip - done)
            mujoco.mj_step(self.model, self.data, nstep=n)
            done += n
            touch += self._touching()
            checks += 1
        info = {"ctrl": ctrl, **self._senses(touch / checks)}
        return self._obs(), 0.0, False, False, info

    def _senses(self, touch: np.ndarray) -> dict[str, Any]:
        """The ``info`` entries of every reset and step (module docstring)."""
        info: dict[str, Any] = {"time": float(self.data.time), "hand": self.hand_position(), "touch": touch}
        if self.camera_info:
            view = self.camera_frame()
            info["rgbd"] = RGBDFrame(view.rgb, view.depth, view.K, view.time)
            info["table_from_camera"] = self.table_from_camera(view)
            info["self_mask"] = self.arm_mask(view)
        info["truth"] = {k: v.copy() for k, v in self.object_positions().items()}
        info["state"] = self.get_state()
        return info

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset (class docstring). ``info`` has ``time``, ``hand`` and zero ``touch``."""
        options = dict(options or {})
        unknown = sorted(set(options) - {"state", "objects", "q"})
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; expected 'state', 'objects' or 'q'")
        placements = dict(options.pop("objects", None) or {})
        q0 = options.pop("q", None)
        if "state" in options and (placements or q0 is not None):
            raise ValueError("reset option 'state' cannot be combined with 'objects' or 'q'")
        bad = sorted(set(placements) - set(getattr(self, "objects", placements)))
        if bad:
            raise ValueError(f"reset places unknown object(s) {bad}; the scene has {list(self.objects)}")
        super().reset(seed=seed, options=options)
        if "state" not in options:
            q = np.asarray(self.layout.home if q0 is None else q0, dtype=np.float64)
            if q.shape != (len(JOINTS),) or not np.all(np.isfinite(q)):
                raise ValueError(
                    f"reset q has shape {q.shape} or non-finite entries; expected ({len(JOINTS)},) rad"
                )
            q = np.clip(q, self.ctrl_low, self.ctrl_high)
            self.data.qpos[self.qpos_indices] = q
            self.data.ctrl[self.actuator_ids] = q
            self._place(placements)
            mujoco.mj_forward(self.model, self.data)
        return self._obs(), self._senses(np.zeros(len(self.objects)))

    def _place(self, placements: dict[str, Any]) -> None:
        rng = self.np_random
        placed: dict[str, np.ndarray] = {}
        for name in self.objects:
            if name in placements:
                p = np.asarray(placements[name], dtype=np.float64)
                if p.shape != (3,) or not np.all(np.isfinite(p)):
                    raise ValueError(
                        f"placement of {name!r} is {placements[name]!r}; expected (x, y, yaw_deg)"
                    )
                x, y, yaw = p
            else:
                for _ in range(1000):
                    r = rng.uniform(*self.layout.spawn_radius)
                    a = self._heading + math.radians(rng.uniform(*self.layout.spawn_angle_deg))
                    x, y = (
                        self.layout.shoulder[0] + r * math.cos(a),
                        self.layout.shoulder[1] + r * math.sin(a),
                    )
                    clear = all(
                        math.dist((x, y), other[:2]) > OBJECT_RADIUS[name] + OBJECT_RADIUS[o] + 0.01
                        for o, other in placed.items()
                    )
                    if clear:
                        break
                yaw = rng.uniform(-180.0, 180.0)
            placed[name] = np.array([x, y, yaw])
            adr, dof = self._object_qpos[name], self._object_qvel[name]
            self.data.qpos[adr : adr + 3] = self.world_from_table[:3, 3] + [x, y, RESTING[name]]
            self.data.qpos[adr + 3 : adr + 7] = quat_z(float(yaw))
            self.data.qvel[dof : dof + 6] = 0.0

    # ------------------------------------------------------------------ ground truth (evaluation)
    def object_poses(self) -> dict[str, np.ndarray]:
        """Ground truth ``table_from_object`` (4, 4) of every object."""
        mujoco.mj_kinematics(self.model, self.data)
        out = {}
        for name, b in self._object_body.items():
            T = np.eye(4)
            T[:3, :3] = self.data.xmat[b].reshape(3, 3)
            T[:3, 3] = self.data.xpos[b] - self.world_from_table[:3, 3]
            out[name] = T
        return out

    def object_positions(self) -> dict[str, np.ndarray]:
        """Ground truth (3,) body centre of every object, table frame, metres."""
        return {k: v[:3, 3].copy() for k, v in self.object_poses().items()}

    def replay(self, state: Any, actions: Any) -> dict[str, np.ndarray]:
        """Where every object would be one step after ``state`` under each action (evaluation only).

        The batch runs open loop with ``mujoco.rollout`` (the servo targets are held for the
        step's ``frame_skip`` physics steps, as :meth:`step` holds them); the environment's own
        state is not changed.

        Args:
            state: a :meth:`get_state` vector.
            actions: (B, 2) servo targets, rad (clipped to the joint ranges as :meth:`step` does).

        Returns:
            object name -> (B, 3) body centre after the step, table frame, m.

        Raises:
            ValueError: a state of the wrong size or non-finite, or actions not (B, 2).
        """
        s = np.asarray(state, dtype=np.float64)
        if s.shape != (self.state_size,) or not np.all(np.isfinite(s)):
            raise ValueError(
                f"state has shape {s.shape} or non-finite entries; expected a get_state() vector ({self.state_size},)"
            )
        a = np.asarray(actions, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != len(JOINTS) or not np.all(np.isfinite(a)):
            raise ValueError(
                f"actions have shape {a.shape}; expected finite (B, {len(JOINTS)}) servo targets, rad"
            )
        m = self.model
        scratch = mujoco.MjData(m)
        mujoco.mj_setState(m, scratch, s, STATE_SPEC)
        full = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        mujoco.mj_getState(m, scratch, full, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        ctrl = np.tile(scratch.ctrl, (a.shape[0], 1))
        ctrl[:, self.actuator_ids] = np.clip(a, self.ctrl_low, self.ctrl_high)
        controls = np.repeat(ctrl[:, None, :], self.frame_skip, axis=1)
        warm = np.tile(scratch.qacc_warmstart, (a.shape[0], 1))
        states, _ = mujoco.rollout.rollout(m, scratch, full[None], controls, initial_warmstart=warm)
        qpos = states[:, -1, 1 : 1 + m.nq]  # FULLPHYSICS: time, qpos, qvel, ...
        origin = self.world_from_table[:3, 3]
        return {n: qpos[:, adr : adr + 3] - origin for n, adr in self._object_qpos.items()}

    # ------------------------------------------------------------------ camera
    @property
    def camera(self) -> Camera:
        """The oblique RGB-D camera (opened on first use, closed by :meth:`close`)."""
        if self._camera is None:
            w, h = self.camera_size
            self._camera = Camera(
                self.model, self.data, CAMERA, width=w, height=h, backend=self.camera_backend
            )
        return self._camera

    def camera_frame(self) -> CameraFrame:
        """Render the current state: RGB, depth (m), segmentation, K, camera pose."""
        return self.camera.render()

    def arm_mask(self, frame: CameraFrame) -> np.ndarray:
        """(H, W) bool: pixels of the agent's own body in ``frame`` (its self-model)."""
        return np.isin(frame.body_segmentation, self.arm_body_ids)

    def table_from_camera(self, frame: CameraFrame) -> np.ndarray:
        """(4, 4) pose of the OpenCV camera frame of ``frame`` in table coordinates."""
        out = frame.world_from_camera.copy()
        out[:3, 3] -= self.world_from_table[:3, 3]
        return out

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """``render_mode="rgb_array"``: the camera's (H, W, 3) uint8 image; otherwise None."""
        if self.render_mode != "rgb_array":
            return None
        return self.camera_frame().rgb

    def close(self) -> None:
        """Release the camera's renderer, then close the environment."""
        if self._camera is not None:
            self._camera.close()
            self._camera = None
        super().close()


if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="pal.sim.pushing:PushingEnv")
