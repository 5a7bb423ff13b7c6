"""Temporal filter of a static object's pose with the camera's egomotion as its motion prior.

For an object presumed static, the camera's motion predicts its pose: ``prior =
inverse(world_from_camera) world_pose_last``. A new measurement ``T`` of it (a feature or dense
fit that passed every check) is blended with that prediction, each part by its own gain::

    R = R_prior exp(g_R log(R_prior^T R_T))         (a geodesic step towards the measurement)
    t = t_prior + g_t (t_T - t_prior)

With the gains ``g < 1`` the filter is a constant-position Kalman filter in the world frame
with a fixed gain (an exponential average of the object's world pose): at 30 Hz, where a
frame's camera turn (a few tenths of a degree) is below the noise of a single rotation
measurement (about 1 degree), the estimate follows the camera's motion and averages the
measurement noise down instead of passing it on. A measurement further from the prediction
than the gate is taken as it is: the gate is ``gate_deg`` and ``gate_m``, or
``gate_sigmas`` standard deviations of the measurement's own covariance where that is tighter
(a precise fit that disagrees with the prediction is motion, not noise), (the object may have been moved;
the static checks of :mod:`pal.perception.pose_checks` decide that), and a moving object is
never filtered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from pal.checks import check_float

__all__ = ["PoseFilter", "filter_static"]


@dataclass(frozen=True)
class PoseFilter:
    """Gains and gates of :func:`filter_static`.

    Attributes:
        rotation_gain: weight of the measured rotation, in (0, 1] (1: no filtering).
        translation_gain: weight of the measured translation, in (0, 1].
        gate_deg: a measurement turned further than this from the prediction is kept as is, deg.
        gate_m: ... or moved further than this, metres.
        gate_sigmas: ... or further than this many of the measurement's standard deviations.
    """

    rotation_gain: float = 0.02
    translation_gain: float = 0.3
    gate_deg: float = 5.0
    gate_m: float = 0.03
    gate_sigmas: float = 10.0

    def __post_init__(self) -> None:
        check_float("rotation_gain", self.rotation_gain, 0.0, 1.0, open_low=True)
        check_float("translation_gain", self.translation_gain, 0.0, 1.0, open_low=True)
        check_float("gate_deg", self.gate_deg, 0.0, open_low=True)
        check_float("gate_m", self.gate_m, 0.0, open_low=True)
        check_float("gate_sigmas", self.gate_sigmas, 0.0, open_low=True)


def filter_static(
    prior: np.ndarray, measured: np.ndarray, config: PoseFilter, covariance: np.ndarray | None = None
) -> tuple[np.ndarray, bool]:
    """Blend a static object's measured pose with its egomotion prediction (module docstring).

    Args:
        prior: (4, 4) ``camera_from_object`` the camera's motion predicts, metres.
        measured: (4, 4) ``camera_from_object`` measured in this frame, metres.
        config: gains and gates.
        covariance: (6, 6) covariance of the measurement over (rotation vector rad, translation
            m), or None (the fixed gates only).

    Returns:
        ((4, 4) the filtered pose, whether it was filtered: False outside the gate).
    """
    prior = np.asarray(prior, dtype=np.float64)
    measured = np.asarray(measured, dtype=np.float64)
    if prior.shape != (4, 4) or measured.shape != (4, 4):
        raise ValueError(f"poses have shapes {prior.shape} and {measured.shape}; expected (4, 4) each")
    delta = Rotation.from_matrix(prior[:3, :3].T @ measured[:3, :3]).as_rotvec()
    step = measured[:3, 3] - prior[:3, 3]
    gate_rad, gate_m = np.radians(config.gate_deg), config.gate_m
    if covariance is not None:
        sd = np.sqrt(np.clip(np.diag(np.asarray(covariance, dtype=np.float64)), 0.0, None))
        gate_rad = min(gate_rad, config.gate_sigmas * float(np.linalg.norm(sd[:3])))
        gate_m = min(gate_m, config.gate_sigmas * float(np.linalg.norm(sd[3:])))
    if np.linalg.norm(delta) > gate_rad or np.linalg.norm(step) > gate_m:
        return measured, False
    out = np.eye(4)
    out[:3, :3] = prior[:3, :3] @ Rotation.from_rotvec(config.rotation_gain * delta).as_matrix()
    out[:3, 3] = prior[:3, 3] + config.translation_gain * step
    return out, True
