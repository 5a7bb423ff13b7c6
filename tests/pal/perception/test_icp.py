"""Dense RGB-D object pose (point-to-plane ICP + photometric) against ray-cast frames with known motion."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.icp import IcpConfig, icp_fit, surface_points
from pal.perception.masks import Mask
from pal.perception.memory import AdmissionConfig, Gallery, ObjectRecord
from pal.perception.pose import PoseConfig, PoseEstimator
from pal.perception.segmentation import OracleSegmenter
from pal.perception.synthetic import Box, SyntheticCamera

CAM = SyntheticCamera(320, 240)
SIZE = (0.12, 0.10, 0.07)


def on_table(yaw_deg: float, x: float, y: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = [x, y, 0.035]
    return CAM.table @ T


def rot_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(Ra.T @ Rb).magnitude()))


def model_of(frame, label: int = 1):
    mask = Mask.from_full(frame.labels == label)
    x0, y0, x1, y1 = mask.bbox
    pts, gray, step = surface_points(
        frame.depth[y0:y1, x0:x1], mask.crop, (x0, y0), frame.K, 400, gray=frame.gray()[y0:y1, x0:x1]
    )
    return mask, pts, gray, step


@pytest.mark.parametrize("photometric", [True, False])
def test_a_box_is_found_where_it_moved(photometric):
    A, B = on_table(10.0, 0.0), on_table(14.0, 0.015, 0.01)
    fa, fb = CAM.render([Box(SIZE, A)]), CAM.render([Box(SIZE, B)], 0.1)
    _, model, gray, step = model_of(fa)  # object frame = camera frame of fa
    truth = B @ np.linalg.inv(A)
    mask_b = Mask.from_full(fb.labels == 1)
    # started 1.8 cm and 4 deg away (a prediction leaves much less): more steps than the default
    cfg = IcpConfig(photometric_sigma=6.0 if photometric else None, iterations=25)
    fit = icp_fit(model, np.eye(4), fb, mask_b, config=cfg, model_gray=gray, step=step)
    assert fit is not None
    assert rot_deg(fit.T[:3, :3], truth[:3, :3]) < 0.5 and np.linalg.norm(fit.T[:3, 3] - truth[:3, 3]) < 0.003
    assert fit.agreement > 0.9 and fit.condition < cfg.max_condition and fit.covariance is not None
    assert fit.rmse_sigma < 1.0 and (fit.photometric > 0) == photometric


def test_a_plane_is_unobservable_and_bad_input_is_refused():
    f = CAM.render([])
    table = Mask.from_full(f.depth > 0)
    x0, y0, x1, y1 = table.bbox
    pts, _, step = surface_points(f.depth[y0:y1, x0:x1], table.crop, (x0, y0), f.K, 400)
    fit = icp_fit(pts, np.eye(4), f, table, config=IcpConfig(photometric_sigma=None), step=step)
    assert fit is not None and fit.condition > IcpConfig().max_condition  # slides along the plane
    with pytest.raises(ValueError, match=r"model has shape \(5, 2\), expected \(M, 3\)"):
        icp_fit(np.zeros((5, 2)), np.eye(4), f, table)
    with pytest.raises(ValueError, match="T0 has shape"):
        icp_fit(pts, np.full((4, 4), np.nan), f, table)
    with pytest.raises(ValueError, match="min_points"):
        IcpConfig(min_points=2)


def test_a_textureless_box_gets_a_dense_pose_when_features_fail():
    """A one-colour box has no corners inside its silhouette: the features give no pose, ICP does."""
    est = PoseEstimator(PoseConfig(), rng=0)
    seg = OracleSegmenter()
    rec, poses, truth = None, [], []
    for k in range(4):
        T = on_table(10.0 + 2.0 * k, 0.005 * k)
        truth.append(T)
        f = CAM.render([Box(SIZE, T, cells=1)], 0.1 * k)
        mask = seg(f)[0].mask
        if rec is None:
            rec = ObjectRecord(1, Gallery(AdmissionConfig(min_area=200)), f.timestamp, f.timestamp, mask, 1)
        gray = f.gray()
        feats = est.features(gray, mask)
        pose, decision = est.estimate(rec, f, gray, mask, feats)
        if decision is None:
            rec.gallery.consider(f, gray, mask, feats, est.extractor, est.anchor_for(pose))
        rec.trajectory.append(pose)
        poses.append(pose)
    assert poses[0].diagnostics.solver == "canonical"
    dense = [p for p in poses[1:] if p.diagnostics.solver == "icp"]
    assert len(dense) == 3 and all(p.source == "estimated" and p.covariance is not None for p in dense)
    X = np.linalg.inv(truth[0]) @ poses[0].camera_from_object  # canonical frame in the box frame
    for p, T in zip(poses[1:], truth[1:], strict=True):
        want = T @ X
        assert rot_deg(p.camera_from_object[:3, :3], want[:3, :3]) < 1.0
        assert np.linalg.norm(p.camera_from_object[:3, 3] - want[:3, 3]) < 0.005
    assert "depth fit; features:" in dense[0].diagnostics.reason
