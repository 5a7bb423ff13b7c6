"""Lens undistortion of recorded frames: known points land on their pinhole pixels, depth is never blended."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from pal.io.sequence_files import SequenceError
from pal.perception.calibration import resolve_calibration
from pal.perception.tum import FREIBURG1_DISTORTION, FREIBURG1_K
from pal.perception.undistort import Undistortion, check_distortion

H, W = 480, 640


def _distorted_dots(points: np.ndarray, depth_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A frame of one 3x3-pixel dot per point where freiburg1's lens puts it; and the pinhole pixels."""
    seen, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), FREIBURG1_K, np.array(FREIBURG1_DISTORTION))
    rgb = np.zeros((H, W, 3), np.uint8)
    depth = np.zeros((H, W), np.float32)
    for u, v in np.rint(seen.reshape(-1, 2)).astype(int):
        rgb[v - 1 : v + 2, u - 1 : u + 2] = 255
        depth[v - 1 : v + 2, u - 1 : u + 2] = depth_m
    pinhole = (FREIBURG1_K @ (points / points[:, 2:]).T).T[:, :2]
    return rgb, depth, pinhole


def test_points_near_the_corners_land_on_their_pinhole_pixels():
    # points toward the image corners, where freiburg1's lens moves them by several pixels
    rng = np.random.default_rng(3)
    xy = np.column_stack([rng.uniform(-0.5, 0.5, 12), rng.uniform(-0.4, 0.4, 12)])
    points = np.column_stack([xy, np.ones(12)]) * 1.2
    rgb, depth, pinhole = _distorted_dots(points, 1.2)
    seen, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), FREIBURG1_K, np.array(FREIBURG1_DISTORTION))
    assert np.max(np.linalg.norm(seen.reshape(-1, 2) - pinhole, axis=1)) > 4.0  # the lens matters here
    out_rgb, out_depth = Undistortion(FREIBURG1_K, FREIBURG1_DISTORTION)(rgb, depth)
    for u, v in pinhole:
        ui, vi = int(round(u)), int(round(v))
        assert out_rgb[vi, ui].min() > 100, (u, v)  # the dot is back within a pixel of the pinhole pixel
        assert out_depth[vi, ui] == pytest.approx(1.2)
    assert out_rgb.shape == rgb.shape and out_depth.dtype == np.float32


def test_depth_is_resampled_by_nearest_neighbour_and_unseen_pixels_are_invalid():
    depth = np.where(np.arange(W)[None, :] < 300, 1.0, 2.5).astype(np.float32).repeat(H, 0)
    rgb = np.full((H, W, 3), 90, np.uint8)
    out_rgb, out_depth = Undistortion(FREIBURG1_K, FREIBURG1_DISTORTION)(rgb, depth)
    assert set(np.unique(out_depth).tolist()) <= {0.0, 1.0, 2.5}  # no depth between the two surfaces
    # freiburg1's pincushion-like correction leaves the corners without a recorded source: depth 0
    assert out_depth[0, 0] == 0.0 and out_depth[H // 2, 100] == 1.0 and out_depth[H // 2, W // 2] == 2.5
    assert out_rgb[H // 2, W // 2].tolist() == [90, 90, 90]


def test_zero_coefficients_pass_frames_unchanged():
    rgb = np.random.default_rng(0).integers(0, 255, (H, W, 3), dtype=np.uint8)
    depth = np.ones((H, W), np.float32)
    u = Undistortion(FREIBURG1_K, [0.0] * 5)
    assert u.is_identity
    out_rgb, out_depth = u(rgb, depth)
    assert out_rgb is rgb and out_depth is depth


@pytest.mark.parametrize(
    ("value", "match"),
    [([0.1, 0.2, 0.3], "has 3 values"), ([0.1, np.nan, 0, 0, 0], "finite"), ("lens", "expected 4, 5 or 8")],
)
def test_bad_coefficients_are_refused_naming_them(value, match):
    with pytest.raises(ValueError, match=match):
        check_distortion(value)


def test_colour_and_depth_of_different_sizes_are_refused():
    with pytest.raises(ValueError, match=r"colour is \(480, 640\) and depth \(240, 320\)"):
        Undistortion(FREIBURG1_K, FREIBURG1_DISTORTION)(np.zeros((H, W, 3), np.uint8), np.zeros((240, 320), np.float32))


def test_calibration_file_carries_the_lens_and_arguments_win(tmp_path):
    (tmp_path / "calibration.json").write_text(
        json.dumps({"fx": 517.3, "fy": 516.5, "cx": 318.6, "cy": 255.3, "depth_scale": 2e-4, "distortion": [0.1, 0, 0, 0]})
    )
    assert resolve_calibration(tmp_path, None, None).distortion.tolist() == [0.1, 0, 0, 0]
    given = resolve_calibration(tmp_path, None, None, distortion=FREIBURG1_DISTORTION).distortion
    assert np.allclose(given, FREIBURG1_DISTORTION)
    (tmp_path / "calibration.json").write_text(json.dumps({"K": FREIBURG1_K.tolist(), "depth_scale": 2e-4, "distortion": [1, 2]}))
    with pytest.raises(SequenceError, match=r"calibration.json: distortion has 2 values"):
        resolve_calibration(tmp_path, None, None)


def _tum_folder(tmp_path, calibration: dict) -> object:
    """A 2-frame TUM folder at 640x480 with a dot where freiburg1's lens puts a known point."""
    from pal.perception.tum import TUMSequence

    d = tmp_path / "tum"
    (d / "rgb").mkdir(parents=True)
    (d / "depth").mkdir()
    point = np.array([[0.45, -0.33, 1.0]]) * 1.5
    rgb, depth, pinhole = _distorted_dots(point, 1.5)
    for t in (1.0, 1.04):
        cv2.imwrite(str(d / "rgb" / f"{t:.6f}.png"), rgb)
        cv2.imwrite(str(d / "depth" / f"{t:.6f}.png"), np.where(depth > 0, 7500, 5000).astype(np.uint16))
    for name in ("rgb", "depth"):
        (d / f"{name}.txt").write_text("".join(f"{t:.6f} {name}/{t:.6f}.png\n" for t in (1.0, 1.04)))
    # the camera slides 1 m/s along x: the pose at time t has tx = t
    (d / "groundtruth.txt").write_text("".join(f"{t:.3f} {t:.3f} 0 0 0 0 0 1\n" for t in np.arange(0.9, 1.2, 0.01)))
    (d / "calibration.json").write_text(json.dumps(calibration))
    return TUMSequence(d), pinhole[0]


def test_a_tum_reader_with_the_lens_undistorts_and_its_truth_takes_a_clock_offset(tmp_path):
    calib = {"K": FREIBURG1_K.tolist(), "depth_scale": 2e-4}
    plain, pinhole = _tum_folder(tmp_path / "plain", calib)
    lens, _ = _tum_folder(tmp_path / "lens", {**calib, "distortion": list(FREIBURG1_DISTORTION)})
    u, v = np.rint(pinhole).astype(int)
    assert plain.undistortion is None and plain[0].depth[v, u] == pytest.approx(1.0)  # the dot is elsewhere
    assert lens[0].depth[v, u] == pytest.approx(1.5) and lens[1].rgb[v, u].min() > 100
    poses = lens.camera_poses(offset=-0.02)
    assert np.allclose(poses.poses[:, 0, 3], [0.98, 1.02], atol=1e-9) and poses.valid.all()
    assert np.allclose(lens.camera_poses().poses[:, 0, 3], [1.0, 1.04], atol=1e-9)
    with pytest.raises(ValueError, match="offset is 0.5 s"):
        lens.camera_poses(offset=0.5)
