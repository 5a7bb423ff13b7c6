"""The frame contract, re-exported from :mod:`pal.frames` (its home, shared with :mod:`pal.sim`)."""

from pal.frames import (
    MAX_PLAUSIBLE_DEPTH,
    DepthUnitsWarning,
    RGBDFrame,
    backproject,
    check_depth_units,
    check_intrinsics,
    crop_intrinsics,
    project,
)

__all__ = [
    "MAX_PLAUSIBLE_DEPTH",
    "DepthUnitsWarning",
    "RGBDFrame",
    "backproject",
    "check_depth_units",
    "check_intrinsics",
    "crop_intrinsics",
    "project",
]
