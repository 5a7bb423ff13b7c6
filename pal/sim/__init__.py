"""The simulated body: MuJoCo assets, the babbling environment, the camera, motor babbling.

- :mod:`pal.sim.bodies`: shipped MJCF bodies (``finger``, ``arm``) and loading of any MJCF file.
- :mod:`pal.sim.env`: :class:`BabblingEnv`, a ``gymnasium.Env`` with exact state replay.
- :mod:`pal.sim.camera`: RGB, metric depth and segmentation from a named camera (EGL/OSMesa,
  or a ray-cast fallback).
- :mod:`pal.sim.policies`, :mod:`pal.sim.babbling`: babbling policies and the data source
  that records :class:`pal.data.TransitionDataset` files.

This package imports neither :mod:`models` nor :mod:`inference`.
"""

from pal.sim.bodies import BODIES, MJCFError, body_path, load_body, load_model
from pal.sim.env import STATE_SPEC, BabblingEnv

__all__ = ["BODIES", "STATE_SPEC", "BabblingEnv", "MJCFError", "body_path", "load_body", "load_model"]
