"""Poses with their provenance (Eq. 4.17) and per-object trajectories T_i(t) (Eq. 4.18).

Every pose carries its *source*:

- ``"estimated"``: measured this frame by a geometric solver (or the canonical-frame
  definition); the only poses counted as valid.
- ``"propagated"``: predicted (constant velocity from the last two estimated poses), flagged
  and never counted as valid — the proof of concept stored such guesses as valid poses.
- ``"rejected"``: a solver's fit that failed a validity check (too few inliers, reprojection
  error, ill-conditioned, inconsistent with the camera's motion for an object presumed static,
  too fast in the world frame); it carries the rejected transform and the reason, and is never
  counted as valid.
- ``"lost"``: no pose; ``camera_from_object`` is None.

An estimated pose carries its covariance: (6, 6) over (rotation vector [rad], translation [m])
of ``camera_from_object``, from the solver's Jacobian (:mod:`pal.perception.pnp`).

A pose is the transform ``camera_from_object`` of the object's canonical frame (see
:mod:`pal.perception.pose`) into the OpenCV camera frame: position in metres, orientation as a
rotation matrix / rotation vector (rad).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from pal.io.files import FileFormatError, check_json, read_npz, write_npz

__all__ = ["SOURCES", "Pose", "PoseDiagnostics", "PoseSource", "Trajectory"]

PoseSource = Literal["estimated", "propagated", "rejected", "lost"]
#: Pose sources in the order of their integer codes on disk.
SOURCES: tuple[str, ...] = ("lost", "estimated", "propagated", "rejected")
_FORMAT = "pal.trajectory/3"
_OLD_FORMATS = ("pal.trajectory/2",)


@dataclass(frozen=True)
class PoseDiagnostics:
    """How a pose came about.

    Attributes:
        matches: ratio-test matches inside both masks, summed over the snapshots tried.
        pairs: of those, matches with valid depth on both sides (3-D/3-D pairs).
        inliers: inliers of the accepted fit.
        rmse: inlier RMSE: metres (``kabsch``, ``icp``), pixels (``pnp``); None without a fit.
        solver: ``"canonical"`` (frame definition), ``"kabsch"``, ``"pnp"``, ``"icp"`` (the
            dense fallback), ``"constant_velocity"`` (propagation) or None.
        reason: human-readable outcome, e.g. why estimation failed or was rejected.
        snapshot: index of the gallery snapshot that contributed most inliers, if any.
        attempts: snapshots tried.
        inlier_ratio: inliers / pairs tried by the solver (None without a fit).
        checks: the validity checks that failed (empty when accepted).
    """

    matches: int = 0
    pairs: int = 0
    inliers: int = 0
    rmse: float | None = None
    solver: str | None = None
    reason: str = ""
    snapshot: int | None = None
    attempts: int = 0
    inlier_ratio: float | None = None
    checks: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible dict (None stays null)."""
        return {
            "matches": self.matches,
            "pairs": self.pairs,
            "inliers": self.inliers,
            "rmse": self.rmse,
            "solver": self.solver,
            "reason": self.reason,
            "snapshot": self.snapshot,
            "attempts": self.attempts,
            "inlier_ratio": self.inlier_ratio,
            "checks": list(self.checks),
        }


@dataclass(frozen=True, eq=False)
class Pose:
    """One pose sample (module docstring).

    Attributes:
        timestamp: s.
        source: ``"estimated"``, ``"propagated"``, ``"rejected"`` or ``"lost"``.
        camera_from_object: (4, 4) float64, or None when lost.
        diagnostics: how it was obtained.
        covariance: (6, 6) covariance of (rotation vector rad, translation m) of an estimated
            pose, or None.
    """

    timestamp: float
    source: PoseSource
    camera_from_object: np.ndarray | None
    diagnostics: PoseDiagnostics = PoseDiagnostics()
    covariance: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"pose source {self.source!r} unknown; expected one of {SOURCES}")
        if (self.camera_from_object is None) != (self.source == "lost"):
            raise ValueError(
                f"a {self.source} pose must {'not ' if self.source == 'lost' else ''}carry a transform"
            )
        if self.camera_from_object is not None:
            T = np.asarray(self.camera_from_object, dtype=np.float64)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise ValueError(f"camera_from_object must be a finite (4, 4) matrix, got shape {T.shape}")
            object.__setattr__(self, "camera_from_object", T)
        if self.covariance is not None:
            C = np.asarray(self.covariance, dtype=np.float64)
            if C.shape != (6, 6) or not np.all(np.isfinite(C)):
                raise ValueError(f"covariance must be a finite (6, 6) matrix, got shape {C.shape}")
            object.__setattr__(self, "covariance", C)

    @property
    def std(self) -> np.ndarray | None:
        """(6,) 1-sigma of (rotation vector rad, translation m), or None without a covariance."""
        return None if self.covariance is None else np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def is_valid(self) -> bool:
        """True only for estimated poses."""
        return self.source == "estimated"

    @property
    def position(self) -> np.ndarray | None:
        """(3,) metres, camera frame; None when lost."""
        return None if self.camera_from_object is None else self.camera_from_object[:3, 3].copy()

    @property
    def rotation(self) -> np.ndarray | None:
        """(3, 3) rotation camera_R_object; None when lost."""
        return None if self.camera_from_object is None else self.camera_from_object[:3, :3].copy()

    @property
    def rotvec(self) -> np.ndarray | None:
        """(3,) rotation vector, rad (Eq. 4.17); None when lost (computed once per rotation)."""
        if self.camera_from_object is None:
            return None
        R = self.camera_from_object[:3, :3]
        cached = self.__dict__.get("_rotvec")
        if cached is None or cached[0] != R.tobytes():
            cached = (R.tobytes(), Rotation.from_matrix(R).as_rotvec())
            object.__setattr__(self, "_rotvec", cached)
        return cached[1].copy()


class Trajectory:
    """The ordered pose samples of one object (all sources; filter with :meth:`valid`)."""

    def __init__(self) -> None:
        self.poses: list[Pose] = []
        self._valid: list[int] = []  # indices of the estimated samples among the first ``_seen``
        self._seen = 0

    def _valid_index(self) -> list[int]:
        """Indices of the estimated samples, brought up to date with the samples appended since."""
        if self._seen > len(self.poses):  # the list was cut: start again
            self._valid, self._seen = [], 0
        for k in range(self._seen, len(self.poses)):
            if self.poses[k].is_valid:
                self._valid.append(k)
        self._seen = len(self.poses)
        return self._valid

    def __len__(self) -> int:
        return len(self.poses)

    def append(self, pose: Pose) -> None:
        """Add a sample; timestamps must not decrease."""
        if self.poses and pose.timestamp < self.poses[-1].timestamp:
            raise ValueError(
                f"pose at {pose.timestamp} s is earlier than the last sample at {self.poses[-1].timestamp} s"
            )
        self.poses.append(pose)

    @property
    def num_valid(self) -> int:
        """Number of estimated (valid) samples."""
        return len(self._valid_index())

    def last_valid(self, k: int = 1) -> list[Pose]:
        """The last ``k`` estimated poses, oldest first."""
        index = self._valid_index()
        return [self.poses[i] for i in (index[max(len(index) - k, 0) :] if k > 0 else index)]

    def valid(self) -> tuple[np.ndarray, np.ndarray]:
        """Estimated samples only: ((M,) timestamps s, (M, 4, 4) camera_from_object)."""
        ps = [p for p in self.poses if p.is_valid]
        ts = np.array([p.timestamp for p in ps], dtype=np.float64)
        Ts = np.stack([p.camera_from_object for p in ps]) if ps else np.zeros((0, 4, 4))  # type: ignore[misc]
        return ts, Ts

    def arrays(self) -> dict[str, np.ndarray]:
        """Columnar arrays of all samples: ``timestamps``, ``source``, ``poses``, ``covariance``.

        ``timestamps`` (N,) s, ``source`` (N,) int8 codes into :data:`SOURCES`, ``poses``
        (N, 4, 4) camera_from_object (zeros where lost), ``covariance`` (N, 6, 6) (zeros where
        none) and ``has_covariance`` (N,) bool.
        """
        n = len(self.poses)
        poses = np.zeros((n, 4, 4))
        cov = np.zeros((n, 6, 6))
        for k, p in enumerate(self.poses):
            if p.camera_from_object is not None:
                poses[k] = p.camera_from_object
            if p.covariance is not None:
                cov[k] = p.covariance
        return {
            "timestamps": np.array([p.timestamp for p in self.poses], dtype=np.float64),
            "source": np.array([SOURCES.index(p.source) for p in self.poses], dtype=np.int8),
            "poses": poses,
            "covariance": cov,
            "has_covariance": np.array([p.covariance is not None for p in self.poses], dtype=bool),
        }

    def save(self, path: str | os.PathLike[str], metadata: Mapping[str, Any] | None = None) -> Path:
        """Write the trajectory as a checked ``.npz`` and return its path.

        The file (:mod:`pal.io.files`: no pickle, atomic, checksummed) holds the arrays, and the
        diagnostics and ``metadata`` (provenance) as JSON; versions are added.
        """
        meta = {
            "metadata": dict(metadata or {}),
            "diagnostics": [p.diagnostics.to_dict() for p in self.poses],
        }
        check_json(meta, "trajectory metadata")
        return write_npz(path, self.arrays(), meta, format=_FORMAT)

    @staticmethod
    def load(path: str | os.PathLike[str]) -> tuple[Trajectory, dict[str, Any]]:
        """Read a file written by :meth:`save`: ``(trajectory, meta)``.

        ``meta`` holds ``metadata``, ``diagnostics``, ``versions`` and ``format``.

        Raises:
            FileFormatError: the file is missing, corrupted, not a trajectory, or inconsistent.
        """
        f = None
        for fmt in (_FORMAT, *_OLD_FORMATS):
            try:
                f = read_npz(path, format=fmt)
                break
            except FileFormatError as err:
                error = err
        if f is None:
            raise FileFormatError(f"not a readable trajectory: {error}") from error
        arrays, diags = f.arrays, f.meta.get("diagnostics")
        n = len(arrays.get("timestamps", ()))
        ok = (
            {"timestamps", "source", "poses"} <= set(arrays)
            and arrays["poses"].shape == (n, 4, 4)
            and arrays["source"].shape == (n,)
            and isinstance(diags, list)
            and len(diags) == n
            and all(isinstance(d, dict) for d in diags)
            and all(0 <= int(c) < len(SOURCES) for c in arrays["source"])
        )
        if not ok:
            raise FileFormatError(f"{path}: the trajectory arrays and diagnostics are inconsistent")
        traj = Trajectory()
        cov = arrays.get("covariance", np.zeros((n, 6, 6)))
        has = arrays.get("has_covariance", np.zeros(n, dtype=bool))
        try:
            for k, (t, code, T, diag) in enumerate(
                zip(arrays["timestamps"], arrays["source"], arrays["poses"], diags, strict=True)
            ):
                src = SOURCES[int(code)]
                d = PoseDiagnostics(**{**diag, "checks": tuple(diag.get("checks", ()))})
                C = cov[k] if bool(has[k]) else None
                pose = Pose(float(t), src, None if src == "lost" else T, d, C)  # type: ignore[arg-type]
                traj.append(pose)
        except (TypeError, ValueError) as err:
            raise FileFormatError(f"{path}: invalid pose sample ({err})") from err
        return traj, {**f.meta, "versions": f.versions, "format": f.format}
