"""Camera: intrinsics, metric depth against known geometry, GL against ray casting.

Tolerances: flat surfaces (planes, boxes) agree to 1e-4 m (the GL depth buffer is 24-bit
reversed-Z read back as float32; measured error ~2e-6 m). Curved geoms are tessellated by
the GL renderer, so sphere/capsule depths agree with the exact ray cast to a median of
3 mm (measured ~1 mm; up to ~1.3 cm at grazing silhouettes). At most 0.2 % of pixels may
carry a different geom id (silhouette pixels; measured 0.005-0.03 %).
"""

import math

import mujoco
import numpy as np
import pytest

from pal.sim import BabblingEnv
from pal.sim.camera import Camera, RenderBackendError, intrinsics

SCENE = """
<mujoco>
  <visual><global offwidth="160" offheight="120"/></visual>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" size="2 2 0.01" rgba="0.5 0.5 0.5 1"/>
    <geom name="ball" type="sphere" pos="0.1 0 0.15" size="0.15" rgba="1 0 0 1"/>
    <geom name="box" type="box" pos="-0.3 0.2 0.1" size="0.1 0.1 0.1" rgba="0 0 1 1"/>
    <geom name="rod" type="capsule" fromto="0.3 0.3 0.05 0.5 0.1 0.05" size="0.05" rgba="0 1 0 1"/>
    <camera name="top" pos="0 0 1.5" xyaxes="1 0 0 0 1 0" fovy="60"/>
    <camera name="oblique" pos="0.9 -0.9 0.9" xyaxes="0.707 0.707 0 -0.408 0.408 0.816" fovy="50"/>
  </worldbody>
</mujoco>
"""
W, H = 160, 120
FLAT, CURVED = (0, 2), (1, 3)  # geom ids: floor, box | ball, rod


@pytest.fixture(scope="module")
def scene():
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


@pytest.fixture(scope="module")
def gl_frames(scene):
    model, data = scene
    frames = {}
    try:
        for name in ("top", "oblique"):
            with Camera(model, data, name, width=W, height=H, backend="gl") as cam:
                frames[name] = cam.render()
    except RenderBackendError as err:
        pytest.skip(f"no offscreen GL context: {err}")
    return frames


def ray_frame(scene, name):
    model, data = scene
    return Camera(model, data, name, width=W, height=H, backend="raycast").render()


def test_intrinsics_from_fovy():
    K = intrinsics(60.0, 320, 240)
    f = 240 / (2 * math.tan(math.radians(30)))
    np.testing.assert_allclose(K, [[f, 0, 159.5], [0, f, 119.5], [0, 0, 1]], rtol=1e-12)
    with pytest.raises(ValueError, match="fovy must be in"):
        intrinsics(0.0, 10, 10)


def test_raycast_depth_of_a_plane_at_a_known_distance(scene):
    frame = ray_frame(scene, "top")
    assert frame.backend == "raycast" and frame.depth.dtype == np.float32 and frame.rgb.dtype == np.uint8
    assert frame.rgb.shape == (H, W, 3) and frame.depth.shape == (H, W) and frame.segmentation.shape == (H, W)
    floor = frame.segmentation == 0
    assert floor.mean() > 0.8
    np.testing.assert_allclose(frame.depth[floor], 1.5, atol=1e-6)
    # back-projected floor pixels lie on z = 0, box tops on z = 0.2, ball pixels on the sphere
    points = frame.points()
    np.testing.assert_allclose(points[floor][:, 2], 0.0, atol=1e-6)
    ball = points[frame.segmentation == 1]
    np.testing.assert_allclose(np.linalg.norm(ball - [0.1, 0, 0.15], axis=1), 0.15, atol=1e-6)
    # flat per-geom colours
    assert (frame.rgb[frame.segmentation == 1] == [255, 0, 0]).all()
    # perception-style labels: 0 = background (none here), world body 0 -> 1, geom id + 1
    assert frame.instance_labels().dtype == np.int32 and (frame.instance_labels() == 1).all()
    np.testing.assert_array_equal(frame.instance_labels("geom"), frame.segmentation + 1)


def test_raycast_projection_matches_K(scene):
    frame = ray_frame(scene, "top")
    # the box's top face centre (-0.3, 0.2, 0.2) in the OpenCV camera frame: x right, y down
    cam = np.linalg.inv(frame.world_from_camera) @ np.array([-0.3, 0.2, 0.2, 1.0])
    u, v = (frame.K @ (cam[:3] / cam[2]))[:2]
    assert frame.segmentation[round(v), round(u)] == 2
    assert frame.depth[round(v), round(u)] == pytest.approx(1.3, abs=1e-6)


@pytest.mark.render
def test_gl_depth_of_a_plane_at_a_known_distance(gl_frames):
    frame = gl_frames["top"]
    assert frame.backend in ("egl", "osmesa", "glfw")
    floor = frame.segmentation == 0
    np.testing.assert_allclose(frame.depth[floor], 1.5, atol=1e-4)
    np.testing.assert_allclose(frame.points()[floor][:, 2], 0.0, atol=1e-4)
    assert frame.rgb[frame.segmentation == 1].mean(axis=0)[0] > 100  # the red ball is reddish


@pytest.mark.render
@pytest.mark.parametrize("name", ["top", "oblique"])
def test_gl_and_raycast_agree(scene, gl_frames, name):
    gl, ray = gl_frames[name], ray_frame(scene, name)
    np.testing.assert_array_equal(gl.K, ray.K)
    same = gl.segmentation == ray.segmentation
    assert same.mean() > 0.998
    for gid in (*FLAT, *CURVED):
        mask = same & (gl.segmentation == gid)
        assert mask.sum() > 50
        diff = np.abs(gl.depth[mask] - ray.depth[mask])
        if gid in FLAT:
            assert diff.max() < 1e-4, gid
        else:
            assert np.median(diff) < 3e-3, gid
    assert ((gl.depth == 0) == (gl.segmentation == -1)).all()


@pytest.mark.render
def test_gl_finger_camera_sees_the_hand():
    env = BabblingEnv("finger")
    env.reset(seed=0)
    env.step([0.3])
    try:
        cam = Camera(env.model, env.data, "overview", width=64, height=48, backend="gl")
    except RenderBackendError as err:
        pytest.skip(f"no offscreen GL context: {err}")
    with cam:
        frame = cam.render()
    names = {
        mujoco.mj_id2name(env.model, mujoco.mjtObj.mjOBJ_GEOM, g)
        for g in np.unique(frame.segmentation)
        if g >= 0
    }
    assert {"palm", "finger_middle", "table"} <= names
    fingers = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_BODY, "fingers")
    assert (frame.body_segmentation == fingers).any()


def test_camera_bad_input(scene):
    model, data = scene
    with pytest.raises(
        ValueError, match=r"unknown camera 'side'; the model's cameras are \['top', 'oblique'\]"
    ):
        Camera(model, data, "side")
    with pytest.raises(ValueError, match="backend 'vulkan' unknown"):
        Camera(model, data, "top", backend="vulkan")
    with pytest.raises(ValueError, match="image size must be positive"):
        Camera(model, data, "top", width=0)
    with pytest.raises(ValueError, match="exceeds the model's offscreen buffer 160x120"):
        Camera(model, data, "top", width=320, height=240, backend="gl")


def test_auto_backend_renders_something(scene):
    model, data = scene
    with Camera(model, data, "top", width=32, height=24) as cam:
        frame = cam.render()
    assert frame.backend in ("egl", "osmesa", "glfw", "raycast")
    assert (frame.depth > 0).all()


def test_without_gl_auto_falls_back_to_raycast_and_gl_raises(scene, monkeypatch, caplog):
    from pal.sim import render_gl

    model, data = scene
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    for backend in render_gl.GL_BACKENDS:
        monkeypatch.setitem(render_gl._FAILED, backend, "simulated: no GL here")
    with pytest.raises(RenderBackendError, match="no OpenGL backend available: .*egl: simulated"):
        Camera(model, data, "top", width=32, height=24, backend="gl")
    with caplog.at_level("WARNING", logger="pal.sim.camera"):
        cam = Camera(model, data, "top", width=32, height=24)
    assert cam.backend == "raycast" and "falling back to the ray-cast camera" in caplog.text
