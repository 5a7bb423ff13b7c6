"""Lens undistortion of recorded RGB-D frames: one remap for colour and depth, maps built once.

Π's camera model is the pinhole ``K`` of :mod:`pal.frames`. A recording whose lens distorts
(e.g. TUM RGB-D freiburg1, radial k1 = 0.26) puts points away from the image centre a few
pixels off the pinhole projection, which biases the camera's motion and every pose. A reader
given the distortion coefficients (OpenCV's order ``k1, k2, p1, p2[, k3]``) resamples each
frame onto the pinhole image of the same ``K`` before Π sees it:

- colour is resampled bilinearly;
- depth is resampled by nearest neighbour, so no depth is interpolated across an object's
  edge; a pinhole pixel whose source falls outside the recorded image gets depth 0 (invalid)
  and black colour;
- depth is taken as registered to the colour image (pixel (u, v) is the same point in both,
  as the OpenNI driver delivers it), so both images use the same maps.

The maps (``cv2.initUndistortRectifyMap``) are computed once per image size.
"""

from __future__ import annotations

import cv2
import numpy as np

from pal.frames import check_intrinsics

__all__ = ["Undistortion", "check_distortion"]


def check_distortion(coefficients: object, name: str = "distortion") -> np.ndarray:
    """``coefficients`` as a float64 array of 4, 5 or 8 finite OpenCV distortion coefficients.

    Raises:
        ValueError: another length, or a value that is not finite (names the value).
    """
    try:
        d = np.asarray(coefficients, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} is {coefficients!r}; expected 4, 5 or 8 numbers k1, k2, p1, p2[, k3, ...]"
        ) from None
    if d.size not in (4, 5, 8):
        raise ValueError(
            f"{name} has {d.size} values {d.tolist()}; expected 4, 5 or 8 (k1, k2, p1, p2[, k3, ...])"
        )
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name} is {d.tolist()}; every coefficient must be finite")
    return d


class Undistortion:
    """Resample (H, W) frames of a distorting lens onto the pinhole image of the same ``K``.

    Args:
        K: (3, 3) intrinsics of the recording, pixels (kept for the undistorted image).
        coefficients: OpenCV distortion coefficients ``k1, k2, p1, p2[, k3]`` (4, 5 or 8 values).

    Attributes:
        K: (3, 3) float64, the intrinsics of both the recorded and the undistorted image.
        coefficients: (4,), (5,) or (8,) float64.
    """

    def __init__(self, K: np.ndarray, coefficients: object) -> None:
        self.K = check_intrinsics(np.asarray(K, dtype=np.float64))
        self.coefficients = check_distortion(coefficients)
        self._maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}

    @property
    def is_identity(self) -> bool:
        """True when every coefficient is 0 (frames pass unchanged)."""
        return not np.any(self.coefficients)

    def _maps_for(self, height: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(fixed-point map, its interpolation table, nearest x map, nearest y map) for an image size."""
        key = (height, width)
        if key not in self._maps:
            size = (width, height)
            fx, fy = cv2.initUndistortRectifyMap(self.K, self.coefficients, None, self.K, size, cv2.CV_32FC1)
            m1, m2 = cv2.convertMaps(fx, fy, cv2.CV_16SC2)
            nx = np.floor(fx + 0.5).astype(np.float32)  # nearest source pixel, exact under INTER_NEAREST
            ny = np.floor(fy + 0.5).astype(np.float32)
            self._maps[key] = (m1, m2, nx, ny)
        return self._maps[key]

    def __call__(self, rgb: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The undistorted ((H, W, 3) uint8 colour, (H, W) float32 depth in metres, 0 = invalid).

        Raises:
            ValueError: colour and depth differ in size, or depth is not 2-D.
        """
        if depth.ndim != 2 or rgb.shape[:2] != depth.shape:
            raise ValueError(
                f"colour is {rgb.shape[:2]} and depth {depth.shape}; undistortion needs one (H, W) for both"
            )
        if self.is_identity:
            return rgb, depth
        m1, m2, nx, ny = self._maps_for(*depth.shape)
        out_rgb = cv2.remap(rgb, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        out_depth = cv2.remap(depth, nx, ny, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return out_rgb, out_depth

    def __repr__(self) -> str:
        k = ", ".join(f"{c:g}" for c in self.coefficients)
        return f"Undistortion(fx={self.K[0, 0]:g}, fy={self.K[1, 1]:g}, coefficients=[{k}])"
