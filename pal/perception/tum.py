"""Reader of the TUM RGB-D benchmark layout (Sturm et al., 2012).

A TUM sequence directory holds ``rgb.txt`` and ``depth.txt`` (lines ``<timestamp> <file>``,
``#`` comments), the images they name (8-bit colour PNG; 16-bit depth PNG, TUM's files with
5000 units per metre, 0 = invalid) and optionally ``groundtruth.txt`` (``t tx ty tz qx qy qz
qw``, the camera pose in the motion-capture world).

The camera is not assumed: pass ``K`` and ``depth_scale`` (e.g. ``FREIBURG2_K`` and
``TUM_DEPTH_SCALE`` for a freiburg2 sequence), or put them in ``calibration.json`` next to the
lists (:mod:`pal.perception.calibration`). The first depth image is checked against the
stated scale (:func:`pal.frames.check_depth_range`).

RGB and depth images are associated as in TUM's ``associate.py``: every pair within
``max_difference`` seconds is a candidate, and pairs are taken greedily by increasing time
difference, each image used at most once. Frame timestamps are the RGB timestamps.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from pal.frames import RGBDFrame, check_depth_range
from pal.io.sequence_files import (
    CameraPoses,
    FrameSequence,
    MissingFramesWarning,
    SequenceError,
    check_timestamps,
    read_depth,
    read_image,
    read_text,
    read_text_rows,
    resolve_inside,
)
from pal.perception.calibration import intrinsics_matrix, resolve_calibration
from pal.perception.folders import pose_matrices
from pal.perception.undistort import Undistortion

__all__ = [
    "FREIBURG1_DISTORTION",
    "FREIBURG1_K",
    "FREIBURG2_K",
    "FREIBURG3_K",
    "FREIBURG_DEFAULT_K",
    "TUM_DEPTH_SCALE",
    "TUMSequence",
    "associate",
]

#: TUM's "ROS default" intrinsics of a Kinect at 640x480, pixels (for when the sensor is unknown).
FREIBURG_DEFAULT_K = intrinsics_matrix(525.0, 525.0, 319.5, 239.5)
#: Calibrated intrinsics of the three TUM cameras (freiburg1, 2, 3), pixels.
FREIBURG1_K = intrinsics_matrix(517.3, 516.5, 318.6, 255.3)
FREIBURG2_K = intrinsics_matrix(520.9, 521.0, 325.1, 249.7)
FREIBURG3_K = intrinsics_matrix(535.4, 539.2, 320.1, 247.6)
#: Published lens distortion of freiburg1's colour camera, OpenCV order k1, k2, p1, p2, k3.
FREIBURG1_DISTORTION = (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
#: TUM depth PNGs store 5000 units per metre.
TUM_DEPTH_SCALE = 1.0 / 5000.0


def _read_list(path: Path) -> tuple[np.ndarray, list[Path]]:
    """Timestamps and files of a TUM list; files resolved inside the list's folder, times unique."""
    if not path.is_file():
        raise SequenceError(f"{path} does not exist; a TUM sequence needs rgb.txt and depth.txt")
    stamps: list[float] = []
    files: list[Path] = []
    lines: dict[float, int] = {}
    text = read_text(path)
    for n, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) < 2:
            raise SequenceError(f"{path}:{n}: expected '<timestamp> <file>', got {line!r}")
        try:
            t = float(parts[0])
        except ValueError:
            raise SequenceError(f"{path}:{n}: timestamp {parts[0]!r} is not a number") from None
        if t in lines:
            raise SequenceError(
                f"{path}:{n}: timestamp {parts[0]} is listed twice (lines {lines[t]} and {n}); "
                "every image needs its own time"
            )
        lines[t] = n
        stamps.append(t)
        files.append(resolve_inside(path.parent, parts[1], f"{path}:{n}"))
    if not stamps:
        raise SequenceError(f"{path} lists no images")
    return np.asarray(stamps), files


def associate(first: np.ndarray, second: np.ndarray, max_difference: float = 0.02) -> list[tuple[int, int]]:
    """Greedy one-to-one association of two timestamp lists (TUM ``associate.py``).

    Returns:
        index pairs ``(i, j)`` sorted by ``i``, with ``|first[i] - second[j]| < max_difference``.
    """
    order = np.argsort(second)
    sorted_second = second[order]
    candidates = []
    for i, t in enumerate(first):
        lo = np.searchsorted(sorted_second, t - max_difference, side="left")
        hi = np.searchsorted(sorted_second, t + max_difference, side="right")
        for k in range(lo, hi):
            diff = abs(t - sorted_second[k])
            if diff < max_difference:
                candidates.append((diff, i, int(order[k])))
    candidates.sort()
    used_a, used_b, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs)


class TUMSequence(FrameSequence):
    """A TUM RGB-D sequence as :class:`RGBDFrame` s.

    Args:
        path: the directory with ``rgb.txt`` and ``depth.txt``.
        K: (3, 3) intrinsics (e.g. :data:`FREIBURG2_K`); None: read from ``calibration.json``.
        depth_scale: metres per depth unit (:data:`TUM_DEPTH_SCALE` for TUM's files); None:
            read from ``calibration.json``.
        max_difference: RGB-depth association tolerance, s.
        missing: ``"raise"``: a listed image not on disk is an error when the sequence is
            opened; ``"skip"``: frames with a missing image are left out with a
            :class:`MissingFramesWarning` naming their count (a partial download).
        distortion: OpenCV lens coefficients ``k1, k2, p1, p2[, k3]`` (e.g.
            :data:`FREIBURG1_DISTORTION`): every frame is undistorted onto the pinhole image of
            ``K`` (:mod:`pal.perception.undistort`); None: ``calibration.json``'s, else none.

    Attributes:
        num_listed: frames the lists pair, present or not; ``len`` counts those present.
        undistortion: the lens correction applied to every frame, or None.

    Raises:
        SequenceError: missing or malformed lists, timestamps out of order, intrinsics or depth
            scale neither given nor in ``calibration.json``, no RGB image has a depth partner,
            a listed image is missing (``missing="raise"``) or none is present (``"skip"``).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        K: np.ndarray | None = None,
        depth_scale: float | None = None,
        max_difference: float = 0.02,
        missing: str = "raise",
        distortion: object = None,
    ) -> None:
        if missing not in ("raise", "skip"):
            raise ValueError(f'missing is {missing!r}; expected "raise" or "skip"')
        self.path = Path(path)
        if not self.path.is_dir():
            raise SequenceError(f"sequence directory {self.path} does not exist or is not a directory")
        calib = resolve_calibration(
            self.path,
            K,
            depth_scale,
            distortion=distortion,
            scale_hint="The TUM RGB-D benchmark's files use TUM_DEPTH_SCALE (1/5000).",
        )
        self.K, self.depth_scale = calib.K, calib.depth_scale
        self.undistortion = None if calib.distortion is None else Undistortion(calib.K, calib.distortion)
        rgb_t, rgb_f = _read_list(self.path / "rgb.txt")
        depth_t, depth_f = _read_list(self.path / "depth.txt")
        check_timestamps(rgb_t, str(self.path / "rgb.txt"))
        check_timestamps(depth_t, str(self.path / "depth.txt"))
        pairs = associate(rgb_t, depth_t, max_difference)
        if not pairs:
            raise SequenceError(
                f"{self.path}: no image of rgb.txt has one of depth.txt within {max_difference} s "
                "(max_difference)"
            )
        self.num_listed = len(pairs)
        pairs = self._present(pairs, rgb_f, depth_f, missing)
        self.timestamps = np.array([rgb_t[i] for i, _ in pairs])
        self._files = [(rgb_f[i], depth_f[j]) for i, j in pairs]
        self.depth_timestamps = np.array([depth_t[j] for _, j in pairs])
        first = self._files[0][1]
        check_depth_range(read_image(first, depth=True), self.depth_scale, source=str(first), stacklevel=3)

    def _present(
        self, pairs: list[tuple[int, int]], rgb_f: list[Path], depth_f: list[Path], missing: str
    ) -> list[tuple[int, int]]:
        """The pairs whose two images exist; raises or warns about the others (``missing``)."""
        present = [(i, j) for i, j in pairs if rgb_f[i].is_file() and depth_f[j].is_file()]
        if len(present) == len(pairs):
            return pairs
        gone = [(i, j) for i, j in pairs if not (rgb_f[i].is_file() and depth_f[j].is_file())]
        i, j = gone[0]
        first, listed = (rgb_f[i], "rgb.txt") if not rgb_f[i].is_file() else (depth_f[j], "depth.txt")
        what = (
            f"{len(gone)} of {len(pairs)} frames paired from rgb.txt and depth.txt have an image missing "
            f"(first: {first.name} of {listed})"
        )
        if missing == "raise":
            raise SequenceError(f"{self.path}: {what}; open a partial download with missing='skip'")
        if not present:
            raise SequenceError(f"{self.path}: {what}; missing='skip' leaves no frames")
        warnings.warn(f"{self.path}: {what}; they are skipped", MissingFramesWarning, stacklevel=3)
        return present

    def frame(self, index: int) -> RGBDFrame:
        """RGB image ``index`` with its associated depth image (undistorted when the lens is known).

        Raises:
            SequenceError: the two images differ in size.
        """
        rgb_file, depth_file = self._files[index]
        rgb = read_image(rgb_file)
        depth = read_depth(depth_file, self.depth_scale)
        if rgb.shape[:2] != depth.shape:
            raise SequenceError(
                f"{rgb_file} is {rgb.shape[:2]} but {depth_file} is {depth.shape}; TUM images must be aligned"
            )
        if self.undistortion is not None:
            rgb, depth = self.undistortion(rgb, depth)
        return RGBDFrame(rgb=rgb, depth=depth, K=self.K, timestamp=float(self.timestamps[index]))

    def groundtruth(
        self, max_difference: float = 0.02, max_gap: float = 0.1, offset: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Camera poses from ``groundtruth.txt`` at the frame timestamps plus ``offset``, interpolated.

        A frame has a pose when a ground-truth sample lies within ``max_difference`` s of it.
        Between two samples at most ``max_gap`` s apart the pose is their linear (translation)
        and spherical linear (rotation) interpolation; otherwise it is the nearer sample.
        ``offset`` (s) corrects a clock offset between the images and the motion capture: the
        pose of frame k is read at ``timestamps[k] + offset`` (negative: the images are stamped
        later than they were exposed).

        Returns:
            ((N, 7) float64 ``tx ty tz qx qy qz qw`` rows, (N,) bool valid); invalid rows are 0.

        Raises:
            SequenceError: the file is missing or malformed, its times are not increasing, or it
                covers no frame.
        """
        path = self.path / "groundtruth.txt"
        data = _groundtruth_rows(path)
        if not np.isfinite(offset) or abs(offset) > max_gap:
            raise ValueError(
                f"offset is {offset!r} s; expected a finite clock offset within +-{max_gap} s (max_gap)"
            )
        out, valid = _interpolate_poses(data, self.timestamps + offset, max_difference, max_gap)
        if not valid.any():
            times = self.timestamps + offset
            shifted = f" with offset {offset:+.3f} s" if offset else ""
            raise SequenceError(
                f"{path}: its {len(data)} poses ({data[0, 0]:.3f}-{data[-1, 0]:.3f} s) cover none of the "
                f"{len(self)} frames ({times[0]:.3f}-{times[-1]:.3f} s{shifted}) within {max_difference} s"
            )
        return out, valid

    def camera_poses(
        self, max_difference: float = 0.02, max_gap: float = 0.1, offset: float = 0.0
    ) -> CameraPoses:
        """Camera-to-world poses at the frame timestamps plus ``offset`` s (:meth:`groundtruth`), and their validity.

        Frames without ground truth are marked invalid and get the identity.

        Raises:
            SequenceError: no ground truth, malformed, or covering no frame.
        """
        rows, valid = self.groundtruth(max_difference, max_gap, offset)
        rows[~valid] = [0, 0, 0, 0, 0, 0, 1]
        return CameraPoses(pose_matrices(rows, str(self.path / "groundtruth.txt")), valid)


def _groundtruth_rows(path: Path) -> np.ndarray:
    """(M, 8) ``t tx ty tz qx qy qz qw`` rows with strictly increasing t; SequenceError otherwise."""
    rows = read_text_rows(path)
    if not rows or any(len(r) != 8 for r in rows):
        raise SequenceError(f"{path}: expected rows 't tx ty tz qx qy qz qw'")
    try:
        data = np.array(rows, dtype=np.float64)
    except ValueError as err:
        raise SequenceError(f"{path}: expected rows of 8 numbers 't tx ty tz qx qy qz qw' ({err})") from None
    pose_matrices(data[:, 1:], str(path))  # finite, non-zero quaternions
    check_timestamps(data[:, 0], str(path))
    if np.any(np.diff(data[:, 0]) == 0):
        k = int(np.flatnonzero(np.diff(data[:, 0]) == 0)[0]) + 1
        raise SequenceError(f"{path}: rows {k} and {k + 1} have the same time {data[k, 0]}")
    return data


def _interpolate_poses(
    data: np.ndarray, times: np.ndarray, max_difference: float, max_gap: float
) -> tuple[np.ndarray, np.ndarray]:
    """Poses of (M, 8) rows at ``times`` (N,): valid near a sample; lerp + slerp across short gaps."""
    t = data[:, 0]
    after = np.searchsorted(t, times, side="left").clip(0, len(t) - 1)
    before = (after - 1).clip(0, len(t) - 1)
    nearest = np.where(np.abs(t[before] - times) < np.abs(t[after] - times), before, after)
    valid = np.abs(t[nearest] - times) <= max_difference
    out = np.where(valid[:, None], data[nearest, 1:], 0.0)
    span = (t[before] < times) & (times < t[after]) & (t[after] - t[before] <= max_gap) & valid
    if span.any():
        out[span, 3:] = Slerp(t, Rotation.from_quat(data[:, 4:]))(times[span]).as_quat()
        for k in range(3):
            out[span, k] = np.interp(times[span], t, data[:, 1 + k])
    return out, valid
