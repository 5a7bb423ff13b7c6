"""The depth sensor's noise model and the depth-dependent thresholds derived from it.

Structured-light and stereo RGB-D sensors measure depth by triangulation, so the standard
deviation of a reading grows with the square of the distance (Khoshelham and Elberink 2012
measured ``1.4 mm x z²`` for the Kinect, z in metres)::

    sigma_z(z) = floor + quadratic * z²      metres

``floor`` covers quantisation and the noise of near readings. Every geometric threshold of the
segmentation (plane inliers, the height above the support, depth discontinuities) is
``max(fixed threshold, k * sigma_z(z))``, so the same configuration works at 0.6 m on a
tabletop and at 4 m in a room: a fixed 1 cm threshold is 7 sigma at 1 m but 0.4 sigma at 3 m,
where depth noise on the floor would become objects.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pal.checks import check_float

__all__ = ["DepthNoise"]


@dataclass(frozen=True)
class DepthNoise:
    """sigma_z(z) = floor + quadratic z² (module docstring).

    Attributes:
        quadratic: standard deviation at 1 m, metres (grows with z²); 0.0015 for a Kinect.
        floor: standard deviation at any range, metres (quantisation, near readings).
    """

    quadratic: float = 0.0015
    floor: float = 0.0005

    def __post_init__(self) -> None:
        check_float("quadratic", self.quadratic, 0.0, 0.1)
        check_float("floor", self.floor, 0.0, 0.1)

    def sigma(self, z: np.ndarray | float) -> np.ndarray:
        """Standard deviation of depth readings at depth ``z`` (any shape, metres), float32 metres."""
        z = np.asarray(z, dtype=np.float32)
        return np.float32(self.floor) + np.float32(self.quadratic) * z * z

    def threshold(self, z: np.ndarray | float, k: float, minimum: float) -> np.ndarray:
        """``max(minimum, k * sigma_z(z))`` at depth ``z``, float32 metres."""
        return np.maximum(np.float32(minimum), np.float32(k) * self.sigma(z))
