"""The kinematic descriptor (§4.2.2.3): a trajectory T_i as a 90-d point of the motion space.

Steps, for the *estimated* poses of a trajectory (propagated and lost samples are dropped):

1. smoothing: a 1€ filter over time on the positions and on the sign-continuous quaternions
   (renormalised), with the samples' own timestamps;
2. resampling **by time**: ``n_samples + 1`` instants evenly spaced over [first, last valid
   timestamp]; positions are interpolated linearly, orientations by SLERP;
3. relative motion: per step k, the displacement ``p_{k+1} - p_k`` (metres, camera frame) and
   the rotation vector of ``R_{k+1} R_k^T`` (rad) — 60 x 6 samples;
4. DCT-II (orthonormal, ``scipy.fft.dct``) over time per component, keeping the first 15
   coefficients: 6 x 15 = 90 dims, component-major ``[tx, ty, tz, rx, ry, rz]``.

**Gaps.** Lost poses are not invented: the interpolation in step 2 bridges a gap between the
valid poses on either side (constant velocity across it). How much of the support is bridged
is reported, not hidden: ``max_gap_s`` (longest interval without an estimated pose) and
``gap_fraction`` (fraction of the duration inside intervals longer than ``config.max_gap_s``);
``reliable`` is False when any such long gap exists or fewer than ``min_valid`` poses were
estimated. The proof of concept resampled by index and dropped gaps silently.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.fft import dct
from scipy.spatial.transform import Rotation, Slerp

from pal.perception.filters import OneEuroConfig, one_euro
from pal.perception.trajectory import Trajectory

__all__ = [
    "KINEMATIC_DIM",
    "KINEMATIC_NAMES",
    "KinematicConfig",
    "KinematicDescriptor",
    "kinematic_descriptor",
    "trajectory_descriptor",
]

_COMPONENTS = ("tx", "ty", "tz", "rx", "ry", "rz")
KINEMATIC_DIM = 90
KINEMATIC_NAMES: tuple[str, ...] = tuple(f"{c}_dct{k}" for c in _COMPONENTS for k in range(15))


@dataclass(frozen=True)
class KinematicConfig:
    """Descriptor parameters.

    Attributes:
        n_samples: relative-motion samples after resampling (60).
        n_coeffs: DCT coefficients kept per component (15); dimension = 6 * n_coeffs.
        max_gap_s: intervals without an estimated pose longer than this count as gaps, s.
        min_valid: estimated poses needed for a reliable descriptor.
        smoothing: 1€ filter settings, or None for no smoothing.
    """

    n_samples: int = 60
    n_coeffs: int = 15
    max_gap_s: float = 0.5
    min_valid: int = 10
    smoothing: OneEuroConfig | None = field(default_factory=OneEuroConfig)

    def __post_init__(self) -> None:
        if self.n_samples < 2 or not 1 <= self.n_coeffs <= self.n_samples:
            raise ValueError(
                f"need n_samples >= 2 and 1 <= n_coeffs <= n_samples; got {self.n_samples}, {self.n_coeffs}"
            )
        if not self.max_gap_s > 0 or self.min_valid < 2:
            raise ValueError(
                f"max_gap_s must be > 0 s and min_valid >= 2; got {self.max_gap_s}, {self.min_valid}"
            )


@dataclass(frozen=True, eq=False)
class KinematicDescriptor:
    """A motion-space point with its support.

    Attributes:
        vector: (6 * n_coeffs,) float64.
        n_valid: estimated poses used.
        duration_s: time support, s.
        max_gap_s: longest interval between consecutive estimated poses, s.
        gap_fraction: fraction of the duration inside intervals longer than the config's max gap.
        reliable: enough poses and no long gap.
    """

    vector: np.ndarray
    n_valid: int
    duration_s: float
    max_gap_s: float
    gap_fraction: float
    reliable: bool


def kinematic_descriptor(
    timestamps: np.ndarray,
    poses: np.ndarray,
    valid: np.ndarray | None = None,
    config: KinematicConfig | None = None,
) -> KinematicDescriptor:
    """The descriptor of a pose sequence (module docstring).

    Args:
        timestamps: (N,) s, strictly increasing over the valid samples.
        poses: (N, 4, 4) camera_from_object.
        valid: (N,) bool, which samples are estimated (default: all).
        config: descriptor settings (default: ``KinematicConfig()``).

    Raises:
        ValueError: shapes disagree, non-finite valid poses, fewer than 2 valid poses, or
            non-increasing valid timestamps.
    """
    cfg = config or KinematicConfig()
    ts = np.asarray(timestamps, dtype=np.float64)
    T = np.asarray(poses, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or ts.shape != (T.shape[0],):
        raise ValueError(f"timestamps {ts.shape} and poses {T.shape} must be (N,) and (N, 4, 4)")
    ok = np.ones(ts.shape[0], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if ok.shape != ts.shape:
        raise ValueError(f"valid has shape {ok.shape}, expected {ts.shape}")
    ts, T = ts[ok], T[ok]
    if ts.shape[0] < 2:
        raise ValueError(f"a kinematic descriptor needs >= 2 estimated poses, got {ts.shape[0]}")
    if not (np.all(np.isfinite(ts)) and np.all(np.isfinite(T))):
        raise ValueError("estimated poses and their timestamps must be finite")
    if np.any(np.diff(ts) <= 0):
        raise ValueError("timestamps of the estimated poses must increase strictly")
    pos = T[:, :3, 3]
    quat = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    for k in range(1, quat.shape[0]):  # sign continuity, so filtering/interpolation is smooth
        if quat[k] @ quat[k - 1] < 0:
            quat[k] = -quat[k]
    if cfg.smoothing is not None:
        pos = one_euro(pos, ts, cfg.smoothing)
        quat = one_euro(quat, ts, cfg.smoothing)
        quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    grid = np.linspace(ts[0], ts[-1], cfg.n_samples + 1)
    p = np.stack([np.interp(grid, ts, pos[:, j]) for j in range(3)], axis=1)
    R = Slerp(ts, Rotation.from_quat(quat))(grid)
    dp = np.diff(p, axis=0)
    dr = (R[1:] * R[:-1].inv()).as_rotvec()
    signal = np.concatenate([dp, dr], axis=1)  # (n_samples, 6)
    coeffs = dct(signal, type=2, norm="ortho", axis=0)[: cfg.n_coeffs]
    gaps = np.diff(ts)
    duration = float(ts[-1] - ts[0])
    long_gaps = gaps[gaps > cfg.max_gap_s]
    frac = float(long_gaps.sum() / duration) if duration > 0 else 0.0
    return KinematicDescriptor(
        vector=coeffs.T.reshape(-1),
        n_valid=int(ts.shape[0]),
        duration_s=duration,
        max_gap_s=float(gaps.max()),
        gap_fraction=frac,
        reliable=bool(ts.shape[0] >= cfg.min_valid and long_gaps.size == 0),
    )


def trajectory_descriptor(
    trajectory: Trajectory, config: KinematicConfig | None = None
) -> KinematicDescriptor:
    """:func:`kinematic_descriptor` of a :class:`Trajectory` (estimated poses only)."""
    ts, T = trajectory.valid()
    return kinematic_descriptor(ts, T, None, config)
