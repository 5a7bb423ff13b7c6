"""A track's mask predicted under the camera's motion, association on geometry plus appearance
over a short history, and the dense pose fallback of static objects posed recently.

The tracker's scenes are drawn directly: a fronto-parallel patch (red, blue or a mix of the
two by columns) at a known depth in front of a grey wall, 160x120 pixels, fx = fy = 200 px.
The pose scenes reuse the printed box of :mod:`test_pose_predicted`.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.association import predict_mask, surface_sample
from pal.perception.egomotion import CameraMotion
from pal.perception.frames import RGBDFrame, backproject, project
from pal.perception.masks import Mask, iou
from pal.perception.pose import PoseConfig, PoseEstimator
from pal.perception.pose_checks import PoseChecks
from pal.perception.pose_dense import dense_request
from pal.perception.segmentation import Candidate
from pal.perception.synthetic import Box
from pal.perception.tracking import Tracker
from pal.perception.trajectory import Pose, PoseDiagnostics

from .test_pose_predicted import CAM, SIZE, _posed_record

SHAPE = (120, 160)
K = np.array([[200.0, 0.0, 80.0], [0.0, 200.0, 60.0], [0.0, 0.0, 1.0]])
RED, BLUE = (255, 0, 0), (0, 0, 255)


def patch(
    x0: int, t: float = 0.0, *, w: int = 40, blue: float = 0.0, depth: float = 1.0, y0: int = 40
) -> tuple[RGBDFrame, Candidate]:
    """A square patch ``w`` px wide at (x0, y0) and ``depth`` m whose first ``blue`` of columns are blue."""
    rgb = np.full((*SHAPE, 3), 128, np.uint8)
    z = np.full(SHAPE, 2.0, np.float32)
    full = np.zeros(SHAPE, bool)
    full[y0 : y0 + w, x0 : x0 + w] = True
    rgb[full] = RED
    rgb[y0 : y0 + w, x0 : x0 + round(blue * w)] = BLUE
    z[full] = depth
    return RGBDFrame(rgb, z, K, t), Candidate(Mask.from_full(full), 1)


def translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [x, y, z]
    return T


def plane_seen_after(mask: Mask, depth: float, T: np.ndarray) -> Mask:
    """The mask of a fronto-parallel plane patch at ``depth`` seen after the motion ``T`` (old -> new
    camera): every new pixel centre's ray is traced back to the plane and looked up in ``mask``."""
    h, w = mask.image_shape
    v, u = np.mgrid[0:h, 0:w]
    rays = backproject(u, v, np.ones((h, w)), K) @ T[:3, :3]  # R^T d, in the old camera frame
    origin = -T[:3, :3].T @ T[:3, 3]
    points = origin + ((depth - origin[2]) / rays[..., 2])[..., None] * rays
    uv = np.rint(project(points, K)).astype(int)
    ok = (uv[..., 0] >= 0) & (uv[..., 0] < w) & (uv[..., 1] >= 0) & (uv[..., 1] < h)
    inside = np.zeros((h, w), bool)
    inside[ok] = mask.full()[uv[..., 1][ok], uv[..., 0][ok]]
    return Mask.from_full(inside)


def centroid_gap(a: Mask, b: Mask) -> float:
    return float(np.hypot(a.centroid()[0] - b.centroid()[0], a.centroid()[1] - b.centroid()[1]))


# --- 1. the mask predicted from the camera's egomotion and the object's depth ---------------------


@pytest.mark.parametrize(("depth", "shift_px"), [(1.0, -20.0), (2.0, -10.0)])
def test_a_static_objects_mask_shifts_by_the_parallax_of_its_depth(depth, shift_px):
    """The camera slides 10 cm to the right: a patch 1 m away moves 20 px left, one 2 m away 10 px."""
    frame, cand = patch(60, depth=depth)
    T = translation(x=-0.10)  # old camera -> new camera: the camera moved +10 cm along x
    pred = predict_mask(surface_sample(frame, cand.mask, 2), T, K, SHAPE, 2)
    assert pred is not None
    moved = patch(60 + round(shift_px), depth=depth)[1].mask
    assert iou(pred, moved) >= 0.9
    du = pred.centroid()[0] - cand.mask.centroid()[0]
    dv = pred.centroid()[1] - cand.mask.centroid()[1]
    assert du == pytest.approx(shift_px, abs=1.0) and dv == pytest.approx(0.0, abs=1.0)


def test_a_turning_and_advancing_camera_moves_the_mask_where_the_projection_puts_it():
    """4 degrees of yaw, 5 degrees of pitch and 20 cm forward: the patch shifts and grows by 25 %."""
    frame, cand = patch(60, depth=1.0)
    T = translation(x=0.03, y=-0.02, z=-0.20)
    T[:3, :3] = Rotation.from_euler("yx", [4.0, -5.0], degrees=True).as_matrix()
    pred = predict_mask(surface_sample(frame, cand.mask, 2), T, K, SHAPE, 2)
    assert pred is not None
    truth = plane_seen_after(cand.mask, 1.0, T)
    assert truth.area > 1.4 * cand.mask.area and centroid_gap(truth, cand.mask) > 10.0  # it did move
    assert iou(pred, truth) >= 0.9
    assert centroid_gap(pred, truth) <= 1.0


def test_without_camera_motion_the_predicted_mask_stays_put():
    frame, cand = patch(60, depth=1.0)
    pred = predict_mask(surface_sample(frame, cand.mask, 2), np.eye(4), K, SHAPE, 2)
    assert pred is not None
    assert iou(pred, cand.mask) >= 0.9 and centroid_gap(pred, cand.mask) <= 1.0


def test_no_mask_is_predicted_behind_the_camera_or_outside_the_image():
    frame, cand = patch(60, depth=1.0)
    points = surface_sample(frame, cand.mask, 2)
    assert predict_mask(points, translation(z=-1.5), K, SHAPE, 2) is None  # the camera passed it
    assert predict_mask(points, translation(x=2.0), K, SHAPE, 2) is None  # 400 px to the right
    assert predict_mask(points[:0], np.eye(4), K, SHAPE, 2) is None


def test_the_tracker_keeps_a_static_objects_id_across_a_camera_jump_only_with_the_motion():
    """The camera slides 15 cm: the 24 px patch 1 m away jumps 30 px and leaves its last mask."""
    f0, c0 = patch(60, 0.0, w=24)
    f1, c1 = patch(30, 0.1, w=24)
    assert iou(c0.mask, c1.mask) == 0.0
    W = translation(x=0.15)  # world_from_camera of the second frame (the world: the first camera)
    motion = CameraMotion(np.linalg.inv(W), W, "estimated")
    with_motion = Tracker()
    first = with_motion.update([c0], 0.0, frame=f0, motion=CameraMotion(np.eye(4), np.eye(4), "first"))
    obs = with_motion.update([c1], 0.1, frame=f1, motion=motion)
    assert obs[0].track_id == first[0].track_id and obs[0].status == "tracked"
    assert obs[0].iou >= 0.85  # IoU with the prediction, less the appearance cost (same colour: ~0)
    unaware = Tracker()
    unaware.update([c0], 0.0, frame=f0)
    assert unaware.update([c1], 0.1, frame=f1)[0].status == "born"


# --- 2. association on geometry plus appearance over a short history ------------------------------


def test_an_object_whose_colour_changes_gradually_keeps_its_id_but_a_sudden_other_one_does_not():
    """Red turning blue a tenth of its width per frame stays one object; blue replacing red is new."""
    tr = Tracker()
    ids, statuses = [], []
    for k in range(11):
        frame, cand = patch(60, 0.1 * k, blue=0.1 * k)
        obs = tr.update([cand], 0.1 * k, frame=frame)[0]
        ids.append(obs.track_id)
        statuses.append(obs.status)
    assert ids == [1] * 11 and statuses == ["born"] + ["tracked"] * 10
    swapped = Tracker()
    for k in range(3):
        frame, cand = patch(60, 0.1 * k)
        swapped.update([cand], 0.1 * k, frame=frame)
    frame, cand = patch(60, 0.3, blue=1.0)
    obs = swapped.update([cand], 0.3, frame=frame)[0]
    assert obs.status == "born" and obs.track_id == 2 and 1 in swapped.tracks


def test_the_appearance_memory_spans_several_frames_so_two_steps_cannot_swap_an_object():
    """Half blue, then all blue: a track remembering one half-blue view follows; one that saw red
    for three frames first does not (its running histogram is still mostly red)."""
    short = Tracker()
    for k, blue in enumerate([0.5, 1.0]):
        frame, cand = patch(60, 0.1 * k, blue=blue)
        last = short.update([cand], 0.1 * k, frame=frame)[0]
    assert last.track_id == 1 and last.status == "tracked"
    long = Tracker()
    out = []
    for k, blue in enumerate([0.0, 0.0, 0.0, 0.5, 1.0]):
        frame, cand = patch(60, 0.1 * k, blue=blue)
        out.append(long.update([cand], 0.1 * k, frame=frame)[0])
    assert [o.track_id for o in out] == [1, 1, 1, 1, 2]
    assert out[3].status == "tracked" and out[4].status == "born"


def test_a_weak_overlap_is_enough_only_for_a_candidate_of_the_same_size_and_look():
    """Shifted 26 px, a 40 px patch overlaps its prediction with IoU ~0.2 (below tau_predicted 0.3,
    above half of it) and IoM ~0.35: the same patch keeps its id, a half-blue or 2.6x larger one
    (the same pixels 1.6 m away) does not; the half-blue one in place does."""
    cases = {
        "same": dict(x0=86),
        "other look": dict(x0=86, blue=0.5),
        "larger": dict(x0=86, depth=1.6),
        "other look in place": dict(x0=60, blue=0.5),
    }
    status = {}
    for name, kw in cases.items():
        tr = Tracker()
        frame, cand = patch(60, 0.0)
        tr.update([cand], 0.0, frame=frame)
        frame, cand = patch(t=0.1, **kw)
        status[name] = tr.update([cand], 0.1, frame=frame)[0].status
    assert status == {
        "same": "tracked",
        "other look": "born",
        "larger": "born",
        "other look in place": "tracked",
    }


def test_a_small_fragment_cannot_take_over_a_large_objects_id():
    """A strip a fifth of the patch (inside it: IoM 1) is born; half of it keeps the id."""
    outcomes = []
    for width in (8, 20):
        tr = Tracker()
        frame, cand = patch(60, 0.0)
        tr.update([cand], 0.0, frame=frame)
        frame = patch(60, 0.1)[0]
        strip = np.zeros(SHAPE, bool)
        strip[40:80, 70 : 70 + width] = True
        outcomes.append(tr.update([Candidate(Mask.from_full(strip), 1)], 0.1, frame=frame)[0].status)
    assert outcomes == ["born", "tracked"]


# --- 3. the dense fallback of static objects posed recently ---------------------------------------


def _recent_box(posed_at: float):
    """(config, record, box pose, W): a box posed by its features, its last estimate re-stamped at
    ``posed_at`` s, and a camera ``W`` moved 3 cm and turned 5 degrees since."""
    cfg = PoseConfig()
    rec, T = _posed_record(cfg)
    rec.world_pose = (posed_at, rec.world_pose[1])
    W = translation(x=0.03)
    W[:3, :3] = Rotation.from_euler("y", 5.0, degrees=True).as_matrix()
    return cfg, rec, T, W


def lost(t: float) -> Pose:
    return Pose(t, "lost", None, PoseDiagnostics(reason="no matches"))


@pytest.mark.parametrize("age", [0.4, 1.0])
def test_a_static_object_posed_within_the_horizon_gets_a_dense_request_where_the_camera_puts_it(age):
    cfg, rec, T, W = _recent_box(0.5)
    frame = CAM.render([Box(SIZE, T)], 0.5 + age)  # 1.0: exactly dense_horizon_s old, still included
    mask = Mask.from_full(frame.labels == 1)
    req = dense_request(cfg, rec, frame, mask, W, lost(frame.timestamp))
    assert req is not None and req.timestamp == frame.timestamp and req.mask is mask
    want = np.linalg.inv(W) @ rec.world_pose[1]
    np.testing.assert_allclose(req.prior, want, atol=1e-12)
    assert np.linalg.norm(req.prior[:3, 3] - rec.world_pose[1][:3, 3]) > 0.02  # the motion counted
    assert req.snapshot.anchor is not None and req.model.shape[1] == 3 and req.model.shape[0] >= 50
    via = PoseEstimator(cfg).dense_request(rec, frame, mask, W, lost(frame.timestamp))
    assert via is not None and np.allclose(via.prior, want, atol=1e-12)


def test_an_object_posed_too_long_ago_moving_or_never_posed_gets_no_dense_request():
    cfg, rec, T, W = _recent_box(0.5)
    frame = CAM.render([Box(SIZE, T)], 1.52)  # 1.02 s > dense_horizon_s = 1.0
    mask = Mask.from_full(frame.labels == 1)
    assert dense_request(cfg, rec, frame, mask, W, lost(1.52)) is None
    early = CAM.render([Box(SIZE, T)], 0.9)
    rec.moving = True
    assert dense_request(cfg, rec, early, mask, W, lost(0.9)) is None
    rec.moving, rec.world_pose = False, None
    assert dense_request(cfg, rec, early, mask, W, lost(0.9)) is None
    # the estimator asks for none after an accepted feature pose, or with the dense fit off
    cfg, rec, T, W = _recent_box(0.5)
    estimated = Pose(0.9, "estimated", np.eye(4), PoseDiagnostics(inliers=40, solver="pnp"))
    assert PoseEstimator(cfg).dense_request(rec, early, mask, W, estimated) is None
    assert PoseEstimator(PoseConfig(icp=None)).dense_request(rec, early, mask, W, lost(0.9)) is None
    assert PoseEstimator(cfg).dense_request(rec, early, mask, W, lost(0.9)) is not None
    with pytest.raises(ValueError, match="dense_horizon_s"):
        PoseConfig(dense_horizon_s=0.1, checks=PoseChecks(static_horizon_s=0.25))


def test_the_view_of_a_recently_posed_static_object_is_anchored_where_the_camera_motion_puts_it():
    cfg, rec, _, W = _recent_box(0.5)
    est = PoseEstimator(cfg)
    anchor = est.anchor_for(lost(1.3), rec, W, camera_known=True)
    assert anchor is not None
    np.testing.assert_allclose(anchor, np.linalg.inv(np.linalg.inv(W) @ rec.world_pose[1]), atol=1e-12)
    assert est.anchor_for(lost(1.3), rec, W, camera_known=False) is None  # the motion was not measured
    assert est.anchor_for(lost(1.6), rec, W, camera_known=True) is None  # 1.1 s old
    rec.moving = True
    assert est.anchor_for(lost(1.3), rec, W, camera_known=True) is None
