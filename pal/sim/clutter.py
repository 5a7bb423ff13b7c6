"""The cluttered tabletop: touching boxes and cylinders rendered with MuJoCo, with known masks.

A scene is a seeded :func:`pal.sim.clutter_layout.layout` (boxes, cans, short cans, short boxes
and flat objects of many sizes and colours, some printed, in clusters whose members touch)
on a wood-grain table, seen by an oblique RGB-D camera from a seeded viewpoint: ``distance``
metres from a point near the objects, ``tilt_deg`` from the vertical, ``azimuth_deg`` around
it from the front. :func:`render_clutter` returns the frame (:class:`pal.frames.RGBDFrame`,
``labels`` the objects' ids, 0 for table and floor) and the layout.

The depth has the sensor model of :mod:`pal.sim.recording`: noise ``N(0, (depth_sigma z²)²)``
(metres at 1 m), then the sensor's disparity quantisation, projector shadows and dropouts
(:class:`pal.sim.recording.Realism`; its occluder, blur and lighting fields do not apply
here). Colour gets ``N(0, rgb_sigma²)`` grey levels. Like all of :mod:`pal.sim`, this module
does not import :mod:`pal.perception`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import mujoco
import numpy as np

from pal.checks import check_choice, check_float, check_int
from pal.frames import RGBDFrame
from pal.sim.camera import BACKENDS, Camera
from pal.sim.clutter_layout import ClutterObject, LayoutConfig, layout
from pal.sim.recording import Realism, sensor_depth
from pal.sim.tabletop_assets import generate_assets, printed_texture

__all__ = ["CAMERA", "ClutterConfig", "ClutterScene", "clutter_xml", "render_clutter"]

#: The camera of the scene.
CAMERA = "clutter"
_FACE = 128


@dataclass(frozen=True)
class ClutterConfig:
    """A cluttered scene's objects, viewpoint and sensor (module docstring).

    Attributes:
        layout: how the objects are drawn and placed.
        image: (width, height), pixels.
        fovy: vertical field of view, degrees.
        distance: (nearest, farthest) camera distance from the look-at point, metres.
        tilt_deg: (least, most) angle of the optical axis from the vertical, degrees.
        azimuth_deg: (least, most) camera direction around the vertical from the front, degrees.
        depth_sigma: depth noise std at 1 m, metres (grows with z²); 0 for none.
        rgb_sigma: colour noise std, grey levels; 0 for none.
        sensor: quantisation, shadows and dropouts of the depth, or None for exact depth.
        backend: camera backend (:data:`pal.sim.camera.BACKENDS`).
    """

    layout: LayoutConfig = field(default_factory=LayoutConfig)
    image: tuple[int, int] = (640, 480)
    fovy: float = 45.0
    distance: tuple[float, float] = (0.55, 0.75)
    tilt_deg: tuple[float, float] = (35.0, 55.0)
    azimuth_deg: tuple[float, float] = (-30.0, 30.0)
    depth_sigma: float = 0.002
    rgb_sigma: float = 2.0
    sensor: Realism | None = Realism(occluder=False, blur_subframes=1, lighting=0.0)
    backend: str = "auto"

    def __post_init__(self) -> None:
        check_int("image[0]", self.image[0], minimum=16)
        check_int("image[1]", self.image[1], minimum=16)
        check_float("fovy", self.fovy, 1.0, 150.0)
        for name, lo_bound, hi_bound in (
            ("distance", 0.1, 5.0),
            ("tilt_deg", 0.0, 80.0),
            ("azimuth_deg", -180.0, 180.0),
        ):
            lo, hi = getattr(self, name)
            if not lo_bound <= lo <= hi <= hi_bound:
                raise ValueError(f"{name} is {(lo, hi)}, expected lo <= hi within [{lo_bound}, {hi_bound}]")
        check_float("depth_sigma", self.depth_sigma, 0.0, 0.1)
        check_float("rgb_sigma", self.rgb_sigma, 0.0, 100.0)
        check_choice("backend", self.backend, BACKENDS)


@dataclass(frozen=True, eq=False)
class ClutterScene:
    """One rendered cluttered scene.

    Attributes:
        frame: RGB-D with ``labels`` (H, W) int32: each object's ``label``, 0 elsewhere.
        objects: the layout (labels 1, 2, ...).
        seed: the scene's seed.
        backend: the camera backend that rendered it.
    """

    frame: RGBDFrame
    objects: tuple[ClutterObject, ...]
    seed: int
    backend: str


def _texture(obj: ClutterObject) -> np.ndarray:
    """A printed cube texture (4x3 cross layout) on the object's colour."""
    rng = np.random.default_rng(obj.texture)
    base = tuple(int(255 * c) for c in obj.rgba[:3])
    palette = rng.integers(0, 256, (5, 3))
    out = np.zeros((3 * _FACE, 4 * _FACE, 3), np.uint8)
    for row, col in ((0, 1), (1, 0), (1, 1), (1, 2), (1, 3), (2, 1)):
        tile = printed_texture(rng, (_FACE, _FACE), base, palette, shapes=18)
        out[row * _FACE : (row + 1) * _FACE, col * _FACE : (col + 1) * _FACE] = tile
    return out


def _png(image_rgb: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR))
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 images
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def _camera(rng: np.random.Generator, cfg: ClutterConfig, objects: tuple[ClutterObject, ...]) -> str:
    """The camera element: a seeded viewpoint looking at the objects' centre."""
    centre = np.mean([o.xy for o in objects], axis=0) if objects else np.zeros(2)
    target = np.array([centre[0], centre[1], 0.04])
    dist = rng.uniform(*cfg.distance)
    tilt = math.radians(rng.uniform(*cfg.tilt_deg))
    az = math.radians(rng.uniform(*cfg.azimuth_deg))
    back = np.array([math.sin(az) * math.sin(tilt), -math.cos(az) * math.sin(tilt), math.cos(tilt)])
    pos = target + dist * back
    forward = -back
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    axes = " ".join(f"{v:.6f}" for v in (*right, *up))
    return (
        f'<camera name="{CAMERA}" pos="{pos[0]:.6f} {pos[1]:.6f} {pos[2]:.6f}" '
        f'xyaxes="{axes}" fovy="{cfg.fovy}"/>'
    )


def clutter_xml(
    objects: tuple[ClutterObject, ...], camera: str, image: tuple[int, int]
) -> tuple[str, dict[str, bytes]]:
    """The scene's MJCF text and its in-memory assets ``{file name: bytes}``.

    Args:
        objects: the layout; body ``obj{label}`` holds each object.
        camera: the ``<camera>`` element.
        image: (width, height) the offscreen buffer must hold, pixels.
    """
    assets = {"table.png": generate_assets(0)["table.png"]}
    materials, bodies = [], []
    for o in objects:
        r, g, b, a = o.rgba
        if o.texture is not None:
            assets[f"obj{o.label}.png"] = _png(_texture(o))
            materials.append(
                f'<texture name="t{o.label}" type="cube" file="obj{o.label}.png" gridsize="3 4" '
                f'gridlayout=".U..LFRB.D.."/><material name="m{o.label}" texture="t{o.label}" specular="0.15"/>'
            )
        else:
            materials.append(
                f'<material name="m{o.label}" rgba="{r:.4f} {g:.4f} {b:.4f} {a}" specular="0.2"/>'
            )
        sx, sy, h = o.size
        size = f"{sx / 2:.5f} {sy / 2:.5f} {h / 2:.5f}" if o.shape == "box" else f"{sx / 2:.5f} {h / 2:.5f}"
        bodies.append(
            f'<body name="obj{o.label}" pos="{o.xy[0]:.6f} {o.xy[1]:.6f} {h / 2:.6f}" euler="0 0 {o.yaw:.6f}">'
            f'<geom name="obj{o.label}" type="{o.shape}" size="{size}" material="m{o.label}"/></body>'
        )
    w, h = max(image[0], 640), max(image[1], 480)
    xml = f"""<mujoco model="clutter">
  <compiler angle="radian"/>
  <visual>
    <global offwidth="{w}" offheight="{h}"/>
    <quality offsamples="0"/>
    <headlight ambient="0.38 0.38 0.38" diffuse="0.3 0.3 0.3" specular="0.05 0.05 0.05"/>
    <map znear="0.01" zfar="20"/>
  </visual>
  <asset>
    <texture name="table" type="2d" file="table.png"/>
    <material name="table" texture="table" texrepeat="3 3" texuniform="true" specular="0.05"/>
    <material name="floor" rgba="0.42 0.45 0.48 1"/>
    {"".join(materials)}
  </asset>
  <worldbody>
    <light name="sun" pos="0.25 -0.35 1.5" dir="-0.2 0.3 -1" directional="true" castshadow="false"
           diffuse="0.55 0.55 0.52" specular="0.15 0.15 0.15"/>
    {camera}
    <geom name="floor" type="plane" pos="0 0 -0.75" size="3 3 0.01" material="floor"/>
    <geom name="table_top" type="box" pos="0 0 -0.02" size="0.6 0.45 0.02" material="table"/>
    {"".join(bodies)}
  </worldbody>
</mujoco>"""
    return xml, assets


def render_clutter(seed: int, config: ClutterConfig | None = None) -> ClutterScene:
    """Draw, build and render one cluttered scene (module docstring); the same seed gives the same scene."""
    cfg = config or ClutterConfig()
    objects = layout(seed, cfg.layout)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xCA3E]))
    xml, assets = clutter_xml(objects, _camera(rng, cfg, objects), cfg.image)
    model = mujoco.MjSpec.from_string(xml, assets=assets).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with Camera(model, data, CAMERA, width=cfg.image[0], height=cfg.image[1], backend=cfg.backend) as cam:
        view = cam.render()
    lut = np.zeros(model.nbody + 1, np.int32)  # index body id + 1; -1 (background) -> 0
    for o in objects:
        lut[int(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"obj{o.label}")) + 1] = o.label
    depth = view.depth
    if cfg.depth_sigma > 0:
        z = (
            depth
            + rng.normal(0.0, 1.0, depth.shape).astype(np.float32) * np.float32(cfg.depth_sigma) * depth**2
        )
        depth = np.where(depth > 0, np.maximum(z, 0.0), 0.0).astype(np.float32)
    if cfg.sensor is not None:
        depth = sensor_depth(depth, cfg.sensor, rng)
    rgb = view.rgb.astype(np.float32)
    if cfg.rgb_sigma > 0:
        rgb = rgb + rng.normal(0.0, cfg.rgb_sigma, rgb.shape)
    frame = RGBDFrame(
        rgb=np.clip(np.rint(rgb), 0, 255).astype(np.uint8),
        depth=depth,
        K=view.K,
        timestamp=0.0,
        labels=lut[view.body_segmentation + 1],
    )
    return ClutterScene(frame, objects, int(seed), view.backend)
