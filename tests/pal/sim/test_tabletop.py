"""The tabletop scene, its procedural assets and the scripted motions of thesis Table 5.1."""

from __future__ import annotations

import math
import warnings

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.sim.bodies import body_path
from pal.sim.camera import intrinsics
from pal.sim.motions import MOTIONS, script
from pal.sim.recording import RecordConfig
from pal.sim.tabletop import BALL_RADIUS, OBJECTS, load_tabletop, tabletop_spec
from pal.sim.tabletop_assets import ASSET_NAMES, generate_assets


@pytest.fixture(scope="module")
def scene():
    return load_tabletop()


def test_scene_has_table_camera_and_objects(scene):
    m = scene.model
    assert scene.objects == OBJECTS
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "overhead") >= 0
    # table frame: top surface 0.3 m above the floor, z up
    np.testing.assert_allclose(scene.world_from_table[:3, 3], [0.0, 0.0, 0.3], atol=1e-9)
    np.testing.assert_allclose(scene.world_from_table[:3, :3], np.eye(3), atol=1e-9)
    only = tabletop_spec(("box", "ball")).compile()
    assert mujoco.mj_name2id(only, mujoco.mjtObj.mjOBJ_BODY, "boat") == -1
    with pytest.raises(ValueError, match="distinct names"):
        tabletop_spec(("box", "cup"))


def test_scene_composes_with_the_arm_without_conflicts():
    spec = tabletop_spec(("box", "ball"))
    arm = mujoco.MjSpec.from_file(str(body_path("arm")))
    spec.worldbody.add_frame(pos=[0.0, -0.45, 0.0]).attach_body(arm.body("torso"), "arm/", "")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an option conflict with arm.xml would warn
        model = spec.compile()
    assert model.nu == 8 and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "arm/hand") >= 0
    assert model.opt.timestep == pytest.approx(0.005)


def test_assets_are_procedural_and_seeded():
    a, b, c = generate_assets(0), generate_assets(0), generate_assets(1)
    assert sorted(a) == sorted(ASSET_NAMES)
    assert a == b
    assert a["box_cube.png"] != c["box_cube.png"] and a["boat_hull.obj"] == c["boat_hull.obj"]


def test_set_pose_places_objects_in_table_coordinates(scene):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    T[:3, 3] = [0.05, -0.02, 0.04]
    scene.set_pose("box", T)
    scene.forward()
    np.testing.assert_allclose(scene.world_from_object("box"), scene.world_from_table @ T, atol=1e-9)
    with pytest.raises(ValueError, match="expected a finite"):
        scene.set_pose("box", np.eye(3))
    with pytest.raises(ValueError, match="not in this scene"):
        scene.set_pose("cup", T)


def _yaw_deg(T: np.ndarray) -> float:
    return float(np.degrees(math.atan2(T[1, 0], T[0, 0])))


@pytest.mark.parametrize("motion", sorted(MOTIONS))
def test_scripts_are_seeded_and_do_what_table_5_1_says(motion):
    a, b, c = script(motion, 3), script(motion, 3), script(motion, 4)
    obj = MOTIONS[motion].object
    assert a.object == obj and np.array_equal(a.poses[obj], b.poses[obj]) and a.params == b.params
    assert not np.array_equal(a.poses[obj][-1], c.poses[obj][-1])
    P = a.poses[obj]
    start, end = P[0], P[-1]
    np.testing.assert_allclose(P[:5], np.broadcast_to(start, P[:5].shape))  # still at the start
    shift = end[:3, 3] - start[:3, 3]
    kind = MOTIONS[motion].kind
    if kind in ("translation", "roll"):
        assert shift[0] >= 0.13 and abs(shift[1]) < 0.06
    elif kind == "depth translation":
        assert shift[1] <= -0.11 and abs(shift[0]) < 0.05
    else:
        turn = (_yaw_deg(end) - _yaw_deg(start)) % 360
        assert 90 <= turn <= 180 and np.linalg.norm(shift) < 0.005
    if kind == "roll":  # rolling without slipping: turned angle = path length / radius
        path = np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1).sum()
        turned = sum(
            np.linalg.norm(Rotation.from_matrix(P[k + 1, :3, :3] @ P[k, :3, :3].T).as_rotvec())
            for k in range(len(P) - 1)
        )
        assert turned == pytest.approx(path / BALL_RADIUS, rel=1e-6)
    for other in OBJECTS:
        if other != obj:
            assert np.ptp(a.poses[other], axis=0).max() == 0.0  # parked objects do not move


def test_scripted_objects_stay_in_view_and_never_collide(scene):
    m, d = scene.model, scene.data
    cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "overhead")
    mujoco.mj_forward(m, d)
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3] = d.cam_xmat[cam].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
    world_from_cam[:3, 3] = d.cam_xpos[cam]
    cam_from_table = np.linalg.inv(world_from_cam) @ scene.world_from_table
    K = intrinsics(float(m.cam_fovy[cam]), 640, 480)
    for motion in MOTIONS:
        for seed in range(3):
            run = script(motion, seed, fps=5.0)
            for k in range(len(run)):
                for name in OBJECTS:
                    scene.set_pose(name, run.poses[name][k])
                mujoco.mj_forward(m, d)
                bodies = {(m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]) for c in d.contact[: d.ncon]}
                assert not [p for p in bodies if 0 not in p and p[0] != p[1]], (motion, seed, k)
                centre = cam_from_table @ run.poses[run.object][k][:, 3]
                u, v, w = K @ centre[:3]
                assert 40 < u / w < 600 and 40 < v / w < 440, (motion, seed, k)


def test_bad_motion_requests_raise():
    with pytest.raises(ValueError, match="unknown motion 'box-spin'"):
        script("box-spin")
    with pytest.raises(ValueError, match="non-negative"):
        script("box-rotation", seed=-1)
    with pytest.raises(ValueError, match="fps"):
        script("box-rotation", fps=0.0)
    with pytest.raises(ValueError, match="unknown motion"):
        RecordConfig("spin")
    with pytest.raises(ValueError, match="too small"):
        RecordConfig("ball-roll", width=8)
    with pytest.raises(ValueError, match="must be >= 0"):
        RecordConfig("ball-roll", depth_noise=-0.1)


def test_the_occluder_reaches_over_the_moved_object_and_withdraws():
    from pal.sim.motions import occluder_path
    from pal.sim.tabletop import OCCLUDER, OCCLUDER_LABEL

    run = script("box-translation", 2, fps=10.0)
    hand, params = occluder_path(run, 2)
    again, _ = occluder_path(run, 2)
    assert hand.shape == (len(run), 4, 4) and np.array_equal(hand, again)  # seeded
    assert 0.16 <= params["height_m"] <= 0.19 and np.allclose(hand[:, 2, 3], params["height_m"])
    box = run.poses["box"][:, :2, 3]
    gap = np.linalg.norm(hand[:, :2, 3] - box, axis=1)
    k = len(run) // 2
    assert gap[0] > 0.5 and gap[-1] > 0.5 and gap[k] < 0.12  # away, over the box, away again
    scene = load_tabletop(occluder=True)
    assert scene.occluder and mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_BODY, OCCLUDER) >= 0
    scene.set_pose(OCCLUDER, hand[k])
    scene.forward()
    with scene.camera(160, 120, "raycast") as cam:
        view = cam.render()
    labels = scene.labels(view)
    assert (labels == OCCLUDER_LABEL).sum() > 50 and (labels == 1).sum() > 50
    base = float(scene.model.light_diffuse[0, 0])
    scene.set_lighting(0.5)
    assert float(scene.model.light_diffuse[0, 0]) == pytest.approx(0.5 * base)
    with pytest.raises(ValueError, match="lighting gain"):
        scene.set_lighting(0.0)
    with pytest.raises(ValueError, match="not in this scene"):
        load_tabletop().set_pose(OCCLUDER, np.eye(4))
