"""The frame contract shared by the body and the senses: ``RGBDFrame``, intrinsics K, time.

``RGBDFrame`` is one aligned RGB-D observation v(t) = [I(t), D(t)] with its intrinsics
(Eq. 4.8). :mod:`pal.sim` produces frames and :mod:`pal.perception` consumes them; both import
this module and neither imports the other. Conventions (shared with :mod:`pal.sim.camera`):

- ``rgb`` is (H, W, 3) uint8 in **RGB** channel order (red first). OpenCV's ``imread`` returns
  BGR: build such frames with :meth:`RGBDFrame.from_bgr`, or convert with
  ``cv2.cvtColor(image, cv2.COLOR_BGR2RGB)``. Image files store RGB, and every reader of
  :mod:`pal.perception` returns RGB.
- ``depth`` is (H, W) float32, the z distance along the optical axis in metres.
  **0 marks an invalid pixel** (no return, out of range, unknown). NaN, inf and negative
  values are rejected at construction, so no NaN ever enters the pipeline.
- ``K`` is the (3, 3) pinhole intrinsic matrix in pixels, OpenCV convention (x right, y down,
  z forward, pixel centres at integer coordinates): ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
- ``timestamp`` is in seconds (any epoch, finite).
- Depth in millimetres or centimetres passed as metres puts every object out of reach and
  segmentation finds nothing. When the median valid depth exceeds
  :data:`MAX_PLAUSIBLE_DEPTH` (20 m), construction warns with :class:`DepthUnitsWarning`,
  naming the observed range and the fix.
- A depth scale that is wrong by a constant factor (a Kinect's millimetres read as TUM's
  1/5000 m units) leaves plausible-looking but wrong depth: :func:`check_depth_range` (called by
  the readers with the scale they were given) warns when the range is implausible for an RGB-D
  sensor and names the standard scale that would make it plausible.
- ``labels`` (optional) is an (H, W) int32 ground-truth instance-id image (e.g. MuJoCo
  segmentation ids shifted so that 0 is background). Only the oracle segmenter and the
  evaluation read it.

Frames are immutable: the arrays are exposed as read-only views (no copy is made).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "MAX_PLAUSIBLE_DEPTH",
    "STANDARD_DEPTH_SCALES",
    "DepthUnitsWarning",
    "EmptyDepthError",
    "RGBDFrame",
    "TimestampOrderError",
    "backproject",
    "check_depth_range",
    "check_depth_units",
    "check_intrinsics",
    "crop_intrinsics",
    "project",
]

#: Median valid depth above which a frame's depth is taken for mm or cm, metres.
MAX_PLAUSIBLE_DEPTH = 20.0


#: Depth scales (metres per stored unit) of common sensors and formats, by name.
STANDARD_DEPTH_SCALES: dict[str, float] = {
    "millimetres (Kinect, OpenNI, most 16-bit PNG/PGM)": 1e-3,
    "TUM RGB-D (5000 units per metre)": 2e-4,
    "0.1 mm (RealSense high-accuracy presets)": 1e-4,
}
#: The bulk of an RGB-D sensor's readings lies in this range, metres: structured-light and
#: stereo sensors do not measure much closer than 0.3 m, and rarely report beyond 15 m.
PLAUSIBLE_RANGE = (0.35, 15.0)


class DepthUnitsWarning(UserWarning):
    """Depth values that are implausible for metres (probably millimetres or centimetres)."""


class EmptyDepthError(ValueError):
    """A depth image without a single valid pixel (all 0): a wrong file, scale or sensor failure."""


class TimestampOrderError(ValueError):
    """Frames out of time order: a timestamp earlier than the one before it."""


def _range_problem(valid_m: np.ndarray) -> str:
    """Why the valid depths (metres) are implausible for an RGB-D sensor ('' if they are not)."""
    lo, hi = PLAUSIBLE_RANGE
    near = float(np.mean(valid_m < lo))
    p95 = float(np.percentile(valid_m, 95))
    if near > 0.05:
        return f"{near:.0%} of the valid pixels are closer than {lo:g} m"
    if p95 > hi:
        return f"5 % of the valid pixels are farther than {p95:.1f} m (more than {hi:g} m)"
    return ""


def check_depth_range(
    units: np.ndarray, depth_scale: float, *, source: str = "depth", stacklevel: int = 2
) -> bool:
    """Warn if raw depth read with ``depth_scale`` gives a range implausible for an RGB-D sensor.

    The bulk of the readings must lie in :data:`PLAUSIBLE_RANGE`: at most 5 % of the valid
    pixels closer than 0.35 m and at most 5 % farther than 15 m. When the scale is implausible,
    the warning names the range it gives and every standard scale of
    :data:`STANDARD_DEPTH_SCALES` under which the range would be plausible.

    Args:
        units: (H, W) raw depth as stored (e.g. uint16); 0 = invalid.
        depth_scale: the stated metres per unit (> 0).
        source: what is being read, for the message (a file or directory name).
        stacklevel: passed to :func:`warnings.warn`.

    Returns:
        True if the range is plausible (or there is no valid pixel).

    Raises:
        ValueError: ``depth_scale`` is not > 0.
    """
    if not depth_scale > 0:
        raise ValueError(f"depth_scale is {depth_scale}, expected > 0 metres per unit")
    raw = np.asarray(units)
    valid = raw[raw > 0].astype(np.float64)
    if valid.size == 0:
        return True
    if valid.size > 20000:  # a strided sample is enough for percentiles
        valid = valid[:: valid.size // 20000]
    problem = _range_problem(valid * depth_scale)
    if not problem:
        return True
    fits = [
        f"{name}: depth_scale={scale:g}"
        for name, scale in STANDARD_DEPTH_SCALES.items()
        if not _range_problem(valid * scale)
    ]
    median = float(np.median(valid)) * depth_scale
    fix = (
        "the range would be plausible with " + "; or ".join(fits)
        if fits
        else "no standard scale makes it plausible; check the sensor's documentation"
    )
    warnings.warn(
        DepthUnitsWarning(
            f"{source}: depth read with depth_scale={depth_scale:g} m per unit is implausible for an RGB-D "
            f"sensor: {problem} (median {median:.3g} m). The scale is probably wrong: {fix}"
        ),
        stacklevel=stacklevel,
    )
    return False


def check_depth_units(depth: np.ndarray, *, stacklevel: int = 2) -> bool:
    """Warn (:class:`DepthUnitsWarning`) if valid depth looks like mm or cm rather than metres.

    Args:
        depth: (H, W) depth, supposedly metres; 0 = invalid.
        stacklevel: passed to :func:`warnings.warn`.

    Returns:
        True if the depth is plausible for metres (median valid depth <= 20 m, or no valid pixel).
    """
    if not depth.size or float(depth.max()) <= MAX_PLAUSIBLE_DEPTH:  # the common case, without a median
        return True
    valid = depth[depth > 0]
    median = float(np.median(valid))
    if median <= MAX_PLAUSIBLE_DEPTH:
        return True
    warnings.warn(
        DepthUnitsWarning(
            f"depth is implausible for metres: valid pixels span {float(valid.min()):g} to "
            f"{float(valid.max()):g} with median {median:g} (> {MAX_PLAUSIBLE_DEPTH:g} m). It is probably "
            f"millimetres (median {median / 1000:g} m) or centimetres ({median / 100:g} m): divide it by 1000 "
            "or 100, or read the recording with the right depth_scale (metres per unit, 0.001 for mm)"
        ),
        stacklevel=stacklevel,
    )
    return False


def check_intrinsics(K: np.ndarray | None, name: str = "K") -> np.ndarray:
    """Validate a pinhole intrinsic matrix and return it as (3, 3) float64.

    Raises:
        ValueError: ``K`` missing, not (3, 3), not finite, focal lengths not positive, or last row
            not ``[0, 0, 1]``.
    """
    if K is None:
        raise ValueError(
            f"{name} (camera intrinsics) is missing; pass a (3, 3) matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"
        )
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"{name} has shape {K.shape}, expected (3, 3)")
    if not np.all(np.isfinite(K)):
        raise ValueError(f"{name} has non-finite entries: {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{name} has focal lengths fx={K[0, 0]}, fy={K[1, 1]}; expected both > 0 (pixels)")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(f"{name} = {K.tolist()} is not upper-triangular with K[2] = [0, 0, 1]")
    return K


def crop_intrinsics(K: np.ndarray, x0: int, y0: int) -> np.ndarray:
    """Intrinsics of the crop whose top-left pixel is (x0, y0): the principal point shifts by it.

    Forgetting this shift is the proof of concept's crop bug (0.37 m of x bias at 1 m).
    """
    K = check_intrinsics(K).copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return K


def backproject(u: np.ndarray, v: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Lift pixels with depth to camera-frame points.

    Args:
        u: (...) pixel column coordinates (x right), pixels.
        v: (...) pixel row coordinates (y down), pixels.
        z: (...) depth along the optical axis, metres.
        K: (3, 3) intrinsics.

    Returns:
        (..., 3) float64 points in the OpenCV camera frame, metres.
    """
    u, v, z = (np.asarray(a, dtype=np.float64) for a in (u, v, z))
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    y = (v - cy) / fy
    x = (u - cx - s * y) / fx
    return np.stack([x * z, y * z, z], axis=-1)


def project(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Project camera-frame points (..., 3), z > 0, to pixels (..., 2)."""
    p = np.asarray(points, dtype=np.float64)
    z = p[..., 2]
    if np.any(z <= 0):
        raise ValueError("project() needs points in front of the camera (z > 0)")
    uvw = p @ K.T
    return uvw[..., :2] / uvw[..., 2:3]


def _readonly(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.flags.writeable = False
    return view


@dataclass(frozen=True, eq=False)
class RGBDFrame:
    """An aligned RGB-D frame; checked at construction.

    Attributes:
        rgb: (H, W, 3) uint8, RGB order.
        depth: (H, W) float32, metres along the optical axis; 0 = invalid.
        K: (3, 3) float64 intrinsics, pixels.
        timestamp: acquisition time, s.
        labels: optional (H, W) int32 ground-truth instance ids, 0 = background.

    Raises:
        ValueError: empty frame, wrong dtypes or shapes, RGB/depth size mismatch, NaN/inf or
            negative depth, invalid intrinsics, non-finite timestamp.

    Warns:
        DepthUnitsWarning: depth implausible for metres (median valid depth > 20 m).
    """

    rgb: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    timestamp: float
    labels: np.ndarray | None = None

    def __post_init__(self) -> None:
        rgb = np.asarray(self.rgb)
        depth = np.asarray(self.depth)
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"rgb has shape {rgb.shape}, expected (H, W, 3)")
        if rgb.dtype != np.uint8:
            raise ValueError(f"rgb has dtype {rgb.dtype}, expected uint8")
        if rgb.shape[0] == 0 or rgb.shape[1] == 0:
            raise ValueError(f"the frame is empty: rgb has shape {rgb.shape}, expected H, W >= 1")
        if depth.shape != rgb.shape[:2]:
            raise ValueError(
                f"depth has shape {depth.shape}, expected {rgb.shape[:2]} to match rgb {rgb.shape}"
            )
        if depth.dtype != np.float32:
            raise ValueError(f"depth has dtype {depth.dtype}, expected float32 metres (0 = invalid)")
        if not np.isfinite(depth).all():
            n = int(np.count_nonzero(~np.isfinite(depth)))
            raise ValueError(f"depth has {n} NaN/inf pixels; mark invalid pixels with 0 instead")
        dmin = float(depth.min())
        if dmin < 0:
            raise ValueError(f"depth has negative values (min {dmin} m); expected >= 0 metres, 0 = invalid")
        check_depth_units(depth, stacklevel=4)  # points at the caller of RGBDFrame(...)
        K = check_intrinsics(self.K)
        t = float(self.timestamp)
        if not np.isfinite(t):
            raise ValueError(f"timestamp is {self.timestamp}, expected a finite number of seconds")
        object.__setattr__(self, "rgb", _readonly(rgb))
        object.__setattr__(self, "depth", _readonly(depth))
        object.__setattr__(self, "K", _readonly(K))
        object.__setattr__(self, "timestamp", t)
        if self.labels is not None:
            labels = np.asarray(self.labels)
            if labels.shape != depth.shape:
                raise ValueError(f"labels has shape {labels.shape}, expected {depth.shape}")
            if not np.issubdtype(labels.dtype, np.integer):
                raise ValueError(f"labels has dtype {labels.dtype}, expected an integer id image")
            object.__setattr__(self, "labels", _readonly(labels.astype(np.int32, copy=False)))

    @classmethod
    def from_bgr(
        cls,
        bgr: np.ndarray,
        depth: np.ndarray,
        K: np.ndarray,
        timestamp: float,
        labels: np.ndarray | None = None,
    ) -> RGBDFrame:
        """A frame from an image in OpenCV's BGR channel order (what ``cv2.imread`` returns).

        Args:
            bgr: (H, W, 3) uint8, blue first.
            depth: (H, W) float32 metres, 0 = invalid.
            K: (3, 3) intrinsics, pixels.
            timestamp: s.
            labels: optional (H, W) ground-truth instance ids.
        """
        image = np.asarray(bgr)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise ValueError(f"bgr has shape {image.shape} dtype {image.dtype}, expected (H, W, 3) uint8")
        return cls(np.ascontiguousarray(image[..., ::-1]), depth, K, timestamp, labels)

    def require_depth(self) -> None:
        """Raise :class:`EmptyDepthError` if no pixel has a depth reading.

        Raises:
            EmptyDepthError: every depth pixel is 0 (invalid).
        """
        if not np.any(self.depth > 0):
            raise EmptyDepthError(
                f"the frame at t={self.timestamp:g} s has no valid depth pixel (all {self.height}x{self.width} "
                "are 0): check the depth file, its depth_scale, and that depth is aligned with the colour image"
            )

    @property
    def height(self) -> int:
        """Image height H, pixels."""
        return int(self.rgb.shape[0])

    @property
    def width(self) -> int:
        """Image width W, pixels."""
        return int(self.rgb.shape[1])

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        return self.height, self.width

    def valid_depth(self) -> np.ndarray:
        """(H, W) bool: pixels with a depth measurement (depth > 0)."""
        return self.depth > 0

    def crop(self, x0: int, y0: int, x1: int, y1: int) -> RGBDFrame:
        """The sub-frame of pixels [x0, x1) x [y0, y1), with the principal point shifted.

        Raises:
            ValueError: the box is empty or leaves the image.
        """
        x0, y0, x1, y1 = (int(v) for v in (x0, y0, x1, y1))
        if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
            raise ValueError(
                f"crop box ({x0}, {y0}, {x1}, {y1}) is empty or outside the {self.width}x{self.height} frame"
            )
        labels = None if self.labels is None else self.labels[y0:y1, x0:x1]
        return RGBDFrame(
            rgb=self.rgb[y0:y1, x0:x1],
            depth=self.depth[y0:y1, x0:x1],
            K=crop_intrinsics(self.K, x0, y0),
            timestamp=self.timestamp,
            labels=labels,
        )

    def points(self) -> np.ndarray:
        """(H, W, 3) float64 camera-frame points, metres; rows of invalid pixels are (0, 0, 0)."""
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        return backproject(u, v, self.depth, self.K)

    def gray(self) -> np.ndarray:
        """(H, W) uint8 luminance (OpenCV's RGB to gray weights), read-only, computed once."""
        cached = self.__dict__.get("_gray")
        if cached is None:
            cached = cv2.cvtColor(np.ascontiguousarray(self.rgb), cv2.COLOR_RGB2GRAY)
            cached.flags.writeable = False
            object.__setattr__(self, "_gray", cached)
        return cached
