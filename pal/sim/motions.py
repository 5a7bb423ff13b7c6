"""Scripted object motions on the tabletop, reproducing the interaction variants of thesis Table 5.1.

=======================  ======  ===============================================================
motion                   object  what happens (table frame: x right, y away from the camera)
=======================  ======  ===============================================================
box-translation          box     slides sideways (+x) 20-28 cm along a curved path
box-depth-translation    box     slides towards the camera (-y) 12-18 cm
box-rotation             box     turns about its vertical axis by 90-180° in place
boat-translation         boat    slides sideways 14-20 cm along a curved path
boat-rotation            boat    turns by 90-180° in place
ball-roll                ball    rolls without slipping 22-30 cm along a curved path
=======================  ======  ===============================================================

A script is a function of ``(motion, seed)``: the seed draws the path (start, length,
curvature), the speed (translations 4-14 cm/s, rotations 30-60°/s, the ball
10-22 cm/s), the initial heading and a small heading drift (translations) or a small hand
wobble (rotations), and jitters where the other two objects are parked at the back of the
table. Directions are fixed per motion (sideways: left to right, +x; depth: towards the
camera; rotations: counter-clockwise seen from above), so that each motion is one category of a
camera-frame motion space. Every motion holds still for ``hold_start`` s, then follows a minimum-jerk profile
``s(τ) = 10τ³ - 15τ⁴ + 6τ⁵``, then holds still for ``hold_end`` s. Poses are exact: they are the
ground truth the recordings store.

:func:`occluder_path` adds a hand that reaches in from the right while the object moves,
hovers between the camera and the moved object (hiding part of it), and withdraws: the
occluder of the harder tabletop (:mod:`pal.sim.recording`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from pal.sim.tabletop import BALL_RADIUS, OBJECTS, RESTING_HEIGHT

__all__ = ["MOTIONS", "Motion", "Script", "occluder_path", "script"]


@dataclass(frozen=True)
class Motion:
    """One row of Table 5.1: the moved object and the kind of motion."""

    object: str
    kind: str


#: The scripted motions, by name (Table 5.1).
MOTIONS: dict[str, Motion] = {
    "box-translation": Motion("box", "translation"),
    "box-depth-translation": Motion("box", "depth translation"),
    "box-rotation": Motion("box", "rotation"),
    "boat-translation": Motion("boat", "translation"),
    "boat-rotation": Motion("boat", "rotation"),
    "ball-roll": Motion("ball", "roll"),
}

#: Where objects wait at the back of the table while another one moves: (x, y, yaw deg).
PARKED: dict[str, tuple[float, float, float]] = {
    "box": (-0.21, 0.21, 10.0),
    "boat": (0.2, 0.22, -8.0),
    "ball": (-0.01, 0.25, 0.0),
}

#: Sideways paths per object: ranges of the length, of the start's distance from the centre
#: line and of the start's y, metres; the long boat gets shorter paths so that it stays in view.
_SIDEWAYS: dict[str, tuple[tuple[float, float], ...]] = {
    "box": ((0.20, 0.28), (0.10, 0.14), (-0.08, 0.0)),
    "boat": ((0.14, 0.20), (0.06, 0.08), (-0.05, 0.0)),
    "ball": ((0.22, 0.30), (0.10, 0.14), (-0.08, 0.0)),
}


@dataclass(frozen=True, eq=False)
class Script:
    """A scripted run.

    Attributes:
        motion: motion name (a key of :data:`MOTIONS`).
        seed: the seed that drew it.
        fps: frame rate, frames/s.
        timestamps: (N,) seconds from 0.
        poses: ``{object: (N, 4, 4) table_from_object}`` for every object of the scene.
        params: the drawn parameters (JSON-compatible), for provenance.
    """

    motion: str
    seed: int
    fps: float
    timestamps: np.ndarray
    poses: dict[str, np.ndarray]
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def object(self) -> str:
        """Name of the object the motion moves."""
        return MOTIONS[self.motion].object

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    t = np.clip(tau, 0.0, 1.0)
    return t**3 * (10.0 - 15.0 * t + 6.0 * t * t)


def _pose(x: np.ndarray, y: np.ndarray, z: float, R: np.ndarray) -> np.ndarray:
    """(N, 4, 4) from (N,) positions and (N, 3, 3) rotations."""
    T = np.zeros((x.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, 0, 3], T[:, 1, 3], T[:, 2, 3], T[:, 3, 3] = x, y, z, 1.0
    return T


def _yaw(deg: np.ndarray) -> np.ndarray:
    return (
        Rotation.from_euler("z", np.asarray(deg, dtype=np.float64), degrees=True)
        .as_matrix()
        .reshape(-1, 3, 3)
    )


def _bezier(p0: np.ndarray, c: np.ndarray, p1: np.ndarray, s: np.ndarray) -> np.ndarray:
    s = s[:, None]
    return (1 - s) ** 2 * p0 + 2 * (1 - s) * s * c + s**2 * p1


def _path(
    rng: np.random.Generator,
    length: tuple[float, float],
    start: tuple[float, float],
    start_y: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """A left-to-right curved path: start, control point, end (2-D, table frame) and its parameters."""
    L = float(rng.uniform(*length))
    x0 = -float(rng.uniform(*start))
    y0 = float(rng.uniform(*start_y))
    y1 = y0 + float(rng.uniform(-0.03, 0.03))
    bulge = float(rng.uniform(-0.05, 0.05))
    p0, p1 = np.array([x0, y0]), np.array([x0 + L, y1])
    c = 0.5 * (p0 + p1) + np.array([0.0, 2.0 * bulge])
    return p0, c, p1, {"length_m": L, "start": p0.tolist(), "end": p1.tolist(), "bulge_m": bulge}


def _draw_path(
    rng: np.random.Generator, kind: str, obj: str, yaw0: float, params: dict[str, Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """Draw a translation or roll: its curve (start, control point, end), heading drift (deg) and duration (s).

    The drawn parameters are added to ``params``.
    """
    if kind == "depth translation":
        x0 = float(rng.uniform(-0.06, 0.06))
        p0 = np.array([x0, rng.uniform(0.03, 0.06)])
        p1 = np.array([x0 + rng.uniform(-0.04, 0.04), rng.uniform(-0.12, -0.09)])
        c = 0.5 * (p0 + p1) + np.array([rng.uniform(-0.03, 0.03), 0.0])
        params.update(start=p0.tolist(), end=p1.tolist())
        speed = float(rng.uniform(0.04, 0.10))
    else:
        p0, c, p1, extra = _path(rng, *_SIDEWAYS[obj])
        params.update(extra)
        speed = float(rng.uniform(0.10, 0.22) if kind == "roll" else rng.uniform(0.04, 0.14))
    curve = _bezier(p0, c, p1, np.linspace(0.0, 1.0, 201))
    duration = float(np.linalg.norm(np.diff(curve, axis=0), axis=1).sum()) / speed
    drift = 0.0 if kind == "roll" else float(rng.uniform(-10.0, 10.0))
    params.update(speed_mps=speed, yaw0_deg=yaw0, yaw_drift_deg=drift)
    return p0, c, p1, drift, duration


def _draw_turn(
    rng: np.random.Generator, yaw0: float, params: dict[str, Any]
) -> tuple[float, np.ndarray, float, float]:
    """Draw a rotation in place: its angle (deg), centre (2-D, m), hand wobble (m) and duration (s).

    The drawn parameters are added to ``params``.
    """
    angle = float(rng.uniform(90.0, 180.0))
    omega = float(rng.uniform(30.0, 60.0))
    centre = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.07, 0.0)])
    wobble = float(rng.uniform(0.0, 0.01))
    duration = abs(angle) / omega
    params.update(
        angle_deg=angle, angular_speed_dps=omega, centre=centre.tolist(), wobble_m=wobble, yaw0_deg=yaw0
    )
    return angle, centre, wobble, duration


def _rolled(rng: np.random.Generator, xy: np.ndarray) -> np.ndarray:
    """(N, 3, 3) orientations of the ball rolling without slipping along (N, 2) ``xy`` from a random one."""
    R0 = Rotation.from_rotvec(rng.normal(size=3) * math.pi / math.sqrt(3.0))
    Rs = [R0]
    for k in range(1, xy.shape[0]):  # rolling without slipping: axis z x dp, angle |dp| / r
        dp = np.append(xy[k] - xy[k - 1], 0.0)
        Rs.append(Rotation.from_rotvec(np.cross([0.0, 0.0, 1.0], dp) / BALL_RADIUS) * Rs[-1])
    return np.stack([r.as_matrix() for r in Rs])


def _parked(rng: np.random.Generator, obj: str, n: int) -> dict[str, np.ndarray]:
    """(n, 4, 4) still poses of the objects other than ``obj``, jittered about :data:`PARKED`."""
    poses = {}
    for other in OBJECTS:
        if other == obj:
            continue
        px, py, pyaw = PARKED[other]
        jx, jy, jyaw = rng.uniform(-0.01, 0.01), rng.uniform(-0.01, 0.01), rng.uniform(-10.0, 10.0)
        poses[other] = _pose(
            np.full(n, px + jx), np.full(n, py + jy), RESTING_HEIGHT[other], _yaw(np.full(n, pyaw + jyaw))
        )
    return poses


def script(
    motion: str, seed: int = 0, fps: float = 15.0, hold_start: float = 0.6, hold_end: float = 0.5
) -> Script:
    """Draw the script of one run (module docstring).

    Args:
        motion: a key of :data:`MOTIONS`.
        seed: run seed (any non-negative int).
        fps: frames per second.
        hold_start: still time before the motion, s.
        hold_end: still time after the motion, s.

    Raises:
        ValueError: unknown motion, negative seed, non-positive fps or negative hold times.
    """
    if motion not in MOTIONS:
        raise ValueError(f"unknown motion {motion!r}; expected one of {sorted(MOTIONS)}")
    if int(seed) < 0:
        raise ValueError(f"seed is {seed}, expected a non-negative int")
    if not fps > 0 or hold_start < 0 or hold_end < 0:
        raise ValueError(f"fps ({fps}) must be > 0 and hold times ({hold_start}, {hold_end}) >= 0 s")
    spec = MOTIONS[motion]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), sorted(MOTIONS).index(motion)]))
    obj = spec.object
    params: dict[str, Any] = {"object": obj, "kind": spec.kind}
    yaw0 = float(rng.uniform(-30.0, 30.0))
    if spec.kind in ("translation", "roll", "depth translation"):
        p0, c, p1, drift, duration = _draw_path(rng, spec.kind, obj, yaw0, params)
    else:  # rotation
        angle, centre, wobble, duration = _draw_turn(rng, yaw0, params)
    params["duration_s"] = duration
    total = hold_start + duration + hold_end
    n = math.floor(total * fps + 1e-9) + 1
    t = np.arange(n) / fps
    s = _min_jerk((t - hold_start) / duration)
    z = RESTING_HEIGHT[obj]
    if spec.kind == "rotation":
        xy = centre + wobble * np.stack([np.sin(2 * math.pi * s), 1.0 - np.cos(2 * math.pi * s)], axis=1)
        moving = _pose(xy[:, 0], xy[:, 1], z, _yaw(yaw0 + angle * s))
    else:
        xy = _bezier(p0, c, p1, s)
        R = _rolled(rng, xy) if spec.kind == "roll" else _yaw(yaw0 + drift * s)
        moving = _pose(xy[:, 0], xy[:, 1], z, R)
    poses = {obj: moving, **_parked(rng, obj, n)}
    params["parked"] = {k: v[0, :3, 3].tolist() for k, v in poses.items() if k != obj}
    return Script(motion, int(seed), float(fps), t, poses, params)


def occluder_path(run: Script, seed: int = 0) -> tuple[np.ndarray, dict[str, Any]]:
    """The occluding hand's ``table_from_occluder`` poses (N, 4, 4) for a run, and their parameters.

    The hand (palm down, forearm towards +x, out of view on the right) enters during
    [0.2, 0.4] of the run with a minimum-jerk profile, hovers above and in front of the moved
    object (beside it towards the camera, 16-19 cm above the table (above the tallest object, the boat's funnel at 11 cm), its palm 0-4 cm in front of the
    object's centre and 5-9 cm to its right: the fingers cover part of the object) until 0.65 of
    the run, following it, and leaves by
    0.85. The seed draws the height, the offsets and a slight tilt.

    Args:
        run: the scripted run (its moved object's path is followed).
        seed: seed of the hand's path parameters.
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x0CC1]))
    n = len(run)
    tau = np.arange(n) / max(n - 1, 1)
    height = float(rng.uniform(0.16, 0.19))
    front = float(rng.uniform(0.0, 0.04))
    side = float(rng.uniform(0.05, 0.09))
    tilt = float(rng.uniform(-10.0, 10.0))
    target = run.poses[run.object][:, :2, 3] + np.array([side, -front])
    away = target + np.array([0.55, 0.0])
    reach = _min_jerk((tau - 0.2) / 0.2) - _min_jerk((tau - 0.65) / 0.2)
    xy = away + reach[:, None] * (target - away)
    R = Rotation.from_euler("zy", [tilt, -8.0], degrees=True).as_matrix()
    poses = _pose(xy[:, 0], xy[:, 1], height, np.broadcast_to(R, (n, 3, 3)))
    return poses, {"height_m": height, "front_m": front, "side_m": side, "yaw_deg": tilt}
