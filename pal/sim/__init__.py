"""The simulated body: MuJoCo assets, the babbling environment, the camera, motor babbling.

- :mod:`pal.sim.bodies`: shipped MJCF bodies (``finger``, ``arm``) and loading of any MJCF file.
- :mod:`pal.sim.body_info`: a body's joints, actuators, ranges and force limits by name,
  checked before anything runs (cached per file version).
- :mod:`pal.sim.env`: :class:`BabblingEnv`, a ``gymnasium.Env`` with exact state replay.
- :mod:`pal.sim.camera`: RGB, metric depth and segmentation from a named camera (EGL/OSMesa,
  or a ray-cast fallback).
- :mod:`pal.sim.policies`, :mod:`pal.sim.babbling`: babbling policies and the data source
  that records :class:`pal.io.dataset.TransitionDataset` files.
- :mod:`pal.sim.ranges`: command-range overrides and the effective ranges found in babbling data.
- :mod:`pal.sim.tabletop`, :mod:`pal.sim.motions`, :mod:`pal.sim.recording`: the tabletop
  scene, scripted object motions (thesis Table 5.1) and recordings with ground truth.
- :mod:`pal.sim.clutter`, :mod:`pal.sim.clutter_layout`: the cluttered tabletop, seeded
  layouts of touching boxes and cylinders rendered with known masks.
- :mod:`pal.sim.pushing`: :class:`PushingEnv`, the arm pushing a box and a ball on the table (scene: :mod:`pal.sim.pushing_scene`).

This package imports neither :mod:`models`, :mod:`inference` nor :mod:`pal.perception`: frames
follow the contract of :mod:`pal.frames` and recordings the format of :mod:`pal.io.sequence_files`.
"""

from pal.sim.bodies import BODIES, MJCFError, body_path, check_name, load_body, load_model
from pal.sim.body_info import BodyInfo, body_info
from pal.sim.env import STATE_SPEC, BabblingEnv
from pal.sim.pushing import PushingEnv
from pal.sim.ranges import effective_ranges

__all__ = [
    "BODIES",
    "STATE_SPEC",
    "BabblingEnv",
    "BodyInfo",
    "MJCFError",
    "PushingEnv",
    "body_info",
    "body_path",
    "check_name",
    "effective_ranges",
    "load_body",
    "load_model",
]
