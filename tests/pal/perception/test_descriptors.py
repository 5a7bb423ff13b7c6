"""Descriptors: kinematic (90-d, time-resampled DCT), visual (54-d) and the robust normaliser."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.kinematic import (
    KINEMATIC_DIM,
    KINEMATIC_NAMES,
    KinematicConfig,
    kinematic_descriptor,
    trajectory_descriptor,
)
from pal.perception.normalise import NotFittedError, RobustNormaliser
from pal.perception.trajectory import Pose, Trajectory
from pal.perception.visual import (
    VISUAL_DIM,
    VISUAL_FAMILIES,
    VISUAL_NAMES,
    gallery_visual_descriptor,
    visual_descriptor,
)

RAW = KinematicConfig(smoothing=None)


def poses_at(ts: np.ndarray, velocity: np.ndarray, omega: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(ts), 1, 1))
    T[:, :3, 3] = ts[:, None] * velocity
    T[:, :3, :3] = Rotation.from_rotvec(ts[:, None] * omega).as_matrix()
    return T


def test_constant_motion_has_only_dc_coefficients():
    ts = np.linspace(0.0, 2.0, 41)
    v, w = np.array([0.1, 0.0, -0.05]), np.array([0.0, 0.0, 0.5])
    d = kinematic_descriptor(ts, poses_at(ts, v, w), config=RAW)
    assert d.vector.shape == (KINEMATIC_DIM,) == (len(KINEMATIC_NAMES),)
    coeffs = d.vector.reshape(6, 15)
    step = 2.0 / 60  # the 2 s support resampled to 60 steps
    assert np.allclose(coeffs[:3, 0], v * step * math.sqrt(60))  # orthonormal DCT of a constant
    assert np.allclose(coeffs[3:, 0], w * step * math.sqrt(60), atol=1e-9)
    assert np.allclose(coeffs[:, 1:], 0.0, atol=1e-9)
    assert d.reliable and d.n_valid == 41 and d.duration_s == pytest.approx(2.0)


def test_resampling_is_by_time_not_by_index():
    rng = np.random.default_rng(0)
    uniform = np.linspace(0.0, 3.0, 61)
    irregular = np.sort(np.concatenate([[0.0, 3.0], rng.uniform(0.0, 3.0, 200)]))

    def curved(ts: np.ndarray) -> np.ndarray:  # curvature, so index-based resampling would distort it
        T = poses_at(ts, np.array([0.05, 0.02, 0.0]), np.array([0.1, 0.0, 0.0]))
        T[:, 0, 3] = 0.05 * np.sin(ts)
        return T

    a = kinematic_descriptor(uniform, curved(uniform), config=RAW).vector
    b = kinematic_descriptor(irregular, curved(irregular), config=RAW).vector
    assert np.allclose(a, b, atol=2e-4)


def test_lost_poses_are_dropped_and_gaps_reported():
    ts = np.linspace(0.0, 2.0, 41)
    T = poses_at(ts, np.array([0.1, 0.0, 0.0]), np.zeros(3))
    valid = np.ones(41, bool)
    valid[10:30] = False  # 1 s without an estimated pose
    d = kinematic_descriptor(ts, T, valid, KinematicConfig(smoothing=None, max_gap_s=0.5))
    kept = kinematic_descriptor(ts[valid], T[valid], config=KinematicConfig(smoothing=None, max_gap_s=0.5))
    assert np.allclose(d.vector, kept.vector)
    assert d.n_valid == 21 and d.max_gap_s == pytest.approx(1.05) and d.gap_fraction == pytest.approx(0.525)
    assert not d.reliable
    traj = Trajectory()
    for k, t in enumerate(ts):
        traj.append(Pose(float(t), "estimated", T[k]) if valid[k] else Pose(float(t), "lost", None))
    assert np.allclose(trajectory_descriptor(traj, KinematicConfig(smoothing=None)).vector, d.vector)
    smoothed = trajectory_descriptor(traj)  # with the default 1€ smoothing
    assert smoothed.vector.shape == (90,) and np.all(np.isfinite(smoothed.vector))
    with pytest.raises(ValueError, match=">= 2 estimated poses"):
        kinematic_descriptor(ts, T, np.eye(1, 41, dtype=bool)[0])
    with pytest.raises(ValueError, match="increase"):
        kinematic_descriptor(np.zeros(3), T[:3])


def test_visual_descriptor_of_known_shapes():
    rgb = np.zeros((40, 60, 3), np.uint8)
    rgb[:] = (200, 30, 30)
    mask = np.zeros((40, 60), bool)
    mask[10:30, 10:50] = True  # a 40 x 20 rectangle, 800 px in a 2400 px crop
    d = visual_descriptor(rgb, mask)
    assert d.shape == (VISUAL_DIM,) == (len(VISUAL_NAMES),)
    geo = d[VISUAL_FAMILIES["geometry"]]
    assert geo[0] == pytest.approx(800 / 2400) and geo[1] == pytest.approx(2.0)
    assert geo[2] == pytest.approx(1.0) and geo[3] == pytest.approx(1.0)
    assert geo[5] == pytest.approx(math.sqrt(1 - 0.25), abs=0.01)  # eigenvalues scale with 20^2 : 40^2
    hsv = d[VISUAL_FAMILIES["hsv"]]
    assert hsv.sum() == pytest.approx(1.0) and hsv.max() == pytest.approx(1.0)  # one colour, one bin
    assert d[VISUAL_FAMILIES["edges"]][0] == 0.0  # uniform colour: no Canny edge inside
    assert np.all(d[VISUAL_FAMILIES["orientation"]] == 0.0)  # no gradient: zeros, not NaN
    assert np.all(np.isfinite(d[VISUAL_FAMILIES["hu"]]))
    disk = np.zeros((101, 101), np.uint8)
    cv2.circle(disk, (50, 50), 40, 1, -1)
    texture = np.random.default_rng(0).integers(0, 255, (101, 101, 3), dtype=np.uint8)
    dd = visual_descriptor(texture, disk.astype(bool))
    assert dd[4] == pytest.approx(1.0, abs=0.15) and dd[5] < 0.1  # compact and round
    assert dd[45] > 0.05 and dd[46:54].sum() == pytest.approx(1.0)
    assert np.allclose(gallery_visual_descriptor([d, dd]), (d + dd) / 2)
    with pytest.raises(ValueError, match="zero-size"):
        visual_descriptor(rgb, np.zeros((40, 60), bool))
    with pytest.raises(ValueError, match="expected"):
        visual_descriptor(rgb, mask[:10])
    with pytest.raises(ValueError, match="at least one snapshot"):
        gallery_visual_descriptor([])


def test_robust_normaliser_balances_families():
    rng = np.random.default_rng(0)
    X = np.concatenate(
        [rng.normal(0, 1000.0, (30, 2)), rng.normal(5, 0.01, (30, 8)), np.ones((30, 1))], axis=1
    )
    X[0, 0] = 1e6  # an outlier does not move median/IQR much
    fam = {"big": slice(0, 2), "small": slice(2, 10), "const": slice(10, 11)}
    norm = RobustNormaliser(fam).fit(X)
    assert norm.center_.shape == norm.scale_.shape == norm.weight_.shape == (11,)
    assert norm.scale_[10] == 1.0  # a constant family falls back to unit scale
    Z = norm.transform(X[1:])
    contrib = {k: np.mean(np.sum(Z[:, s] ** 2, axis=1)) for k, s in fam.items() if k != "const"}
    assert 0.3 < contrib["big"] / contrib["small"] < 3.0  # raw ratio would be ~1e9
    assert np.allclose(norm.inverse_transform(norm.transform(X)), X)
    state = json.loads(json.dumps(norm.to_dict()))
    assert np.allclose(RobustNormaliser.from_dict(state).transform(X), norm.transform(X))
    with pytest.raises(NotFittedError, match="not fitted"):
        RobustNormaliser().transform(X)
    with pytest.raises(ValueError, match="partition"):
        RobustNormaliser({"a": slice(0, 5)}).fit(X)
    with pytest.raises(ValueError, match="dimensions"):
        norm.transform(X[:, :3])
    visual = RobustNormaliser(VISUAL_FAMILIES).fit(rng.random((10, 54)))
    assert visual.weight_[13] == pytest.approx(1 / math.sqrt(32)) and visual.weight_[45] == 1.0


def test_histogram_families_are_scaled_as_a_whole():
    """Near-empty bins must not dominate: per-bin IQR scaling divides their count noise by ~0."""
    rng = np.random.default_rng(1)
    a = np.tile([0.7, 0.3, 0.0], (6, 1))
    b = np.tile([0.3, 0.7, 0.0], (6, 1))
    X = np.concatenate([a, b]) + rng.normal(0, 0.01, (12, 3)).clip(0)
    X[:, 2] = np.where(rng.random(12) < 0.3, 0.01, 0.0)  # a nearly empty, noisy bin
    fam = {"hist": slice(0, 3)}
    per_bin = RobustNormaliser(fam).fit_transform(X)
    shared = RobustNormaliser(fam, shared=("hist",)).fit(X)
    Z = shared.transform(X)
    assert np.ptp(shared.scale_) == 0.0 and shared.weight_[0] == 1.0
    # the noisy bin's share of the squared distances from the median
    share = lambda M: np.sum((M[:, 2] - np.median(M[:, 2])) ** 2) / np.sum((M - np.median(M, axis=0)) ** 2)  # noqa: E731
    assert share(Z) < 0.01 < share(per_bin)
    state = json.loads(json.dumps(shared.to_dict()))
    assert np.allclose(RobustNormaliser.from_dict(state).transform(X), Z)
    with pytest.raises(ValueError, match="shared families"):
        RobustNormaliser(fam, shared=("hsv",))
