"""A static object's egomotion prediction taken as its pose only when depth and grey levels confirm it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.association import appearance_distance, appearance_distances
from pal.perception.icp import IcpConfig, icp_fit, icp_score, surface_points
from pal.perception.masks import Mask
from pal.perception.memory import AdmissionConfig, Gallery, ObjectRecord
from pal.perception.pipeline import Pipeline, PipelineConfig
from pal.perception.pose import PoseConfig, PoseEstimator
from pal.perception.pose_checks import PoseChecks, static_bounds
from pal.perception.pose_config import FitRetry, PredictionCheck
from pal.perception.pose_predicted import fit_due, predicted_pose, predicted_poses
from pal.perception.segmentation import OracleSegmenter
from pal.perception.synthetic import Box, SyntheticCamera
from pal.perception.trajectory import PoseDiagnostics

CAM = SyntheticCamera(320, 240)
SIZE = (0.12, 0.10, 0.07)


def on_table(yaw_deg: float, x: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = [x, 0.0, 0.035]
    return CAM.table @ T


def model_of(frame):
    mask = Mask.from_full(frame.labels == 1)
    x0, y0, x1, y1 = mask.bbox
    pts, gray, step = surface_points(
        frame.depth[y0:y1, x0:x1], mask.crop, (x0, y0), frame.K, 400, gray=frame.gray()[y0:y1, x0:x1]
    )
    return mask, pts, gray, step


def _posed_record(config: PoseConfig):
    """A printed box on the table seen twice by a static camera: canonical frame, then a fitted pose."""
    est = PoseEstimator(config, rng=0)
    seg = OracleSegmenter()
    T = on_table(10.0, 0.0)
    rec = None
    for k in range(2):
        f = CAM.render([Box(SIZE, T)], 0.033 * k)
        mask = seg(f)[0].mask
        if rec is None:
            rec = ObjectRecord(1, Gallery(AdmissionConfig(min_area=200)), f.timestamp, f.timestamp, mask, 1)
        gray = f.gray()
        feats = est.features(gray, mask)
        pose, decision = est.estimate(rec, f, gray, mask, feats)
        if decision is None:
            rec.gallery.consider(f, gray, mask, feats, est.extractor, est.anchor_for(pose))
        rec.trajectory.append(pose)
        assert pose.source == "estimated"
    return rec, T


def test_the_prediction_is_taken_while_the_box_stays_and_refused_once_it_moved():
    cfg = PoseConfig(prediction=PredictionCheck(refit_every=3))
    rec, T = _posed_record(cfg)
    seg = OracleSegmenter()
    world = rec.world_pose[1].copy()
    out = []
    for k in (2, 3, 4):  # the box stays: two predictions, then a refit is due
        f = CAM.render([Box(SIZE, T)], 0.033 * k)
        p = predicted_pose(rec, f, seg(f)[0].mask, np.eye(4), cfg, camera_known=True)
        out.append(p)
        if p is not None:
            rec.trajectory.append(p)
    assert [p is not None for p in out] == [True, True, False]
    p = out[0]
    assert p.source == "estimated" and p.diagnostics.solver == "egomotion" and p.covariance is not None
    np.testing.assert_allclose(p.camera_from_object, world, atol=1e-12)  # the world pose, re-stamped
    assert rec.world_pose[0] == pytest.approx(0.033 * 3) and rec.predicted_run == 0
    # moved 3 cm along the table: the depth and grey levels refute the prediction
    rec.predicted_run = 0
    f = CAM.render([Box(SIZE, on_table(10.0, 0.03))], 0.2)
    assert predicted_pose(rec, f, seg(f)[0].mask, np.eye(4), cfg, camera_known=True) is None
    # without a measured camera motion nothing is predicted
    f = CAM.render([Box(SIZE, T)], 0.21)
    assert predicted_pose(rec, f, seg(f)[0].mask, np.eye(4), cfg, camera_known=False) is None
    with pytest.raises(ValueError, match="refit_every"):
        PredictionCheck(refit_every=0)


def test_the_predictions_checked_in_one_pass_equal_those_checked_one_at_a_time():
    cfg = PoseConfig(prediction=PredictionCheck(refit_every=3))
    seg = OracleSegmenter()
    frames = [
        CAM.render([Box(SIZE, on_table(10.0, dx))], 0.033 * k) for k, dx in ((2, 0.0), (3, 0.0), (4, 0.03))
    ]
    one, batch = [_posed_record(cfg)[0] for _ in range(3)], [_posed_record(cfg)[0] for _ in range(3)]
    one[2].predicted_run = batch[2].predicted_run = 2  # a refit is due: not eligible
    for f in frames:
        mask = seg(f)[0].mask
        ref = [predicted_pose(r, f, mask, np.eye(4), cfg, camera_known=True) for r in one]
        got = predicted_poses([(r, mask) for r in batch], f, np.eye(4), cfg, camera_known=True)
        assert [p is None for p in got] == [p is None for p in ref]
        for g, r in zip(got, ref, strict=True):
            if r is not None:
                np.testing.assert_array_equal(g.camera_from_object, r.camera_from_object)
                np.testing.assert_allclose(g.covariance, r.covariance, rtol=1e-7, atol=1e-15)
                assert g.diagnostics.inliers == r.diagnostics.inliers
        for a, b in zip(one, batch, strict=True):
            assert a.predicted_run == b.predicted_run and a.world_pose[0] == b.world_pose[0]
    # the known answers: taken twice while the box stays, refused once it slid 3 cm
    assert [r.predicted_run for r in batch] == [0, 0, 0] and batch[0].world_pose[0] == pytest.approx(
        0.033 * 3
    )
    assert predicted_poses([], frames[0], np.eye(4), cfg, True) == []
    with pytest.raises(ValueError, match="more than once"):
        predicted_poses([(batch[0], mask), (batch[0], mask)], frames[0], np.eye(4), cfg, True)


def test_the_score_at_the_truth_agrees_and_a_slide_is_seen():
    A = on_table(10.0, 0.0)
    fa, fb = CAM.render([Box(SIZE, A)]), CAM.render([Box(SIZE, A)], 0.1)
    _, model, gray, step = model_of(fa)
    mask_b = model_of(fb)[0]
    at = icp_score(model, np.eye(4), fb, mask_b, model_gray=gray, step=step)
    assert at is not None and at.iterations == 0 and at.agreement > 0.95 and at.rmse_sigma < 1.0
    assert at.photometric > 0 and at.photometric_sigma < 0.5
    slid = np.eye(4)
    slid[:3, 3] = [0.02, 0.0, 0.0]
    off = icp_score(model, slid, fb, mask_b, model_gray=gray, step=step)
    assert off is not None and (off.agreement < 0.8 or off.photometric_sigma > 1.5)


def test_a_surface_that_cannot_be_pinned_stops_at_the_start():
    f = CAM.render([])
    table = Mask.from_full(f.depth > 0)
    x0, y0, x1, y1 = table.bbox
    pts, _, step = surface_points(f.depth[y0:y1, x0:x1], table.crop, (x0, y0), f.K, 400)
    fit = icp_fit(pts, np.eye(4), f, table, config=IcpConfig(photometric_sigma=None), step=step)
    assert fit is not None and fit.iterations == 0 and fit.condition > IcpConfig().max_condition
    full = icp_fit(
        pts, np.eye(4), f, table, config=IcpConfig(photometric_sigma=None, early_condition=None), step=step
    )
    assert full is not None and full.iterations > 0 and full.condition > IcpConfig().max_condition
    with pytest.raises(ValueError, match="early_condition"):
        IcpConfig(early_condition=0.5)


def test_the_static_slack_is_capped_at_the_bounds():
    chk = PoseChecks()
    assert static_bounds(chk, None) == pytest.approx(
        (2 * chk.static_translation, 2 * chk.static_rotation_deg)
    )
    tight = np.diag([math.radians(0.1) ** 2] * 3 + [0.001**2] * 3)
    m, deg = static_bounds(chk, tight)
    assert m == pytest.approx(chk.static_translation + 3 * 0.001 * math.sqrt(3), rel=1e-9)
    assert deg == pytest.approx(chk.static_rotation_deg + 3 * 0.1 * math.sqrt(3), rel=1e-9)


def test_appearance_distances_equal_opencvs_pair_by_pair():
    rng = np.random.default_rng(3)
    a = rng.random((4, 48)).astype(np.float32)
    b = rng.random((3, 48)).astype(np.float32)
    a /= a.sum(axis=1, keepdims=True)
    b /= b.sum(axis=1, keepdims=True)
    b[1] = a[2]
    D = appearance_distances(a, b)
    want = np.array([[appearance_distance(x, y) for y in b] for x in a])
    np.testing.assert_allclose(D, want, atol=1e-6)
    assert D[2, 1] < 1e-3
    with pytest.raises(ValueError, match="histograms"):
        appearance_distances(a, b[:, :10])


def test_an_object_whose_fits_keep_failing_is_fitted_every_other_frame():
    rec = ObjectRecord(1, Gallery(AdmissionConfig()), 0.0, 0.0, Mask.from_full(np.ones((4, 4), bool)), 1)
    retry = FitRetry(after=2, every=2)
    assert fit_due(rec, retry)  # no canonical frame yet: always tried
    rec, _ = _posed_record(PoseConfig())
    due = []
    for failed in range(7):
        rec.failed_fits = failed
        due.append(fit_due(rec, retry))
    assert due == [True, True, False, True, False, True, False]
    assert fit_due(rec, None) and fit_due(rec, FitRetry(after=2, every=1))
    with pytest.raises(ValueError, match="every"):
        FitRetry(every=0)


@pytest.mark.parametrize("retry", [FitRetry(after=2, every=2), None])
def test_the_pipeline_spaces_out_the_fits_of_an_object_whose_fits_fail(retry):
    pose_cfg = PoseConfig(prediction=None, retry=retry)
    pipe = Pipeline(PipelineConfig(segmenter="oracle", camera_motion=None, relations=None, pose=pose_cfg))
    fitted = []
    real = pipe.estimator.estimate_features

    def failing(record, frame, *args):
        fitted.append(frame.timestamp)
        if record.gallery.canonical is None:
            return real(record, frame, *args)  # the canonical frame is defined
        return pipe.estimator.missing(record, frame.timestamp, PoseDiagnostics(reason="no fit")), None

    pipe.estimator.estimate_features = failing
    pipe.estimator.dense_request = lambda *args: None
    T = on_table(10.0, 0.0)
    states = [pipe(CAM.render([Box(SIZE, T)], 0.033 * k)) for k in range(7)]
    frames = [round(t / 0.033) for t in fitted]
    assert frames == ([0, 1, 2, 4, 6] if retry is not None else list(range(7)))
    reasons = [s.objects[0].pose.diagnostics.reason for s in states]
    assert sum("not fitted" in r for r in reasons) == (2 if retry is not None else 0)
