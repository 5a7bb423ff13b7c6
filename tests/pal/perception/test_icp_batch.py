"""The batched scores of several objects' poses equal the per-object scores they replace."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.icp import IcpConfig, IcpFit, icp_score, surface_points
from pal.perception.icp_batch import ScoreItem, icp_scores
from pal.perception.icp_terms import bilinear
from pal.perception.masks import Mask
from pal.perception.memory import Snapshot
from pal.perception.pose_dense import snapshot_surface
from pal.perception.synthetic import Box, SyntheticCamera

CAM = SyntheticCamera(320, 240)
SIZE = (0.12, 0.10, 0.07)


def _scene(t: float):
    poses = [(10.0, -0.15, 0.0), (-20.0, 0.12, 0.05), (40.0, 0.0, -0.12)]
    boxes = []
    for k, (yaw, x, y) in enumerate(poses):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", yaw, degrees=True).as_matrix()
        T[:3, 3] = [x, y, 0.035]
        boxes.append(Box(SIZE, CAM.table @ T, k + 1, seed=k))
    return CAM.render(boxes, t)


def _items() -> tuple[list[ScoreItem], object]:
    """Three boxes' models scored in the next frame at the truth, 1 cm aside, 30 cm aside and 5 cm
    nearer the camera, each with and without grey levels."""
    fa, fb = _scene(0.0), _scene(0.1)
    items = []
    for k in (1, 2, 3):
        mask = Mask.from_full(fa.labels == k)
        x0, y0, x1, y1 = mask.bbox
        crop = (fa.depth[y0:y1, x0:x1], mask.crop, (x0, y0), fa.K, 160)
        pts, gray, step = surface_points(*crop, gray=fa.gray()[y0:y1, x0:x1])
        live = Mask.from_full(fb.labels == k)
        for shift in ([0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, -0.05]):
            T = np.eye(4)
            T[:3, 3] = shift
            items += [ScoreItem(pts, T, live, gray, step), ScoreItem(pts, T, live, None, step)]
    return items, fb


def _same(
    got: IcpFit | None, ref: IcpFit | None, rtol: float = 1e-9, atol: float = 0.0, pose_atol: float = 0.0
) -> None:
    """Equal counts; residuals within ``rtol``/``atol``; poses within ``pose_atol`` (0: bit for bit)."""
    assert (got is None) == (ref is None)
    if ref is None or got is None:
        return
    for name in ("points", "visible", "agree", "free_space", "photometric", "iterations"):
        assert getattr(got, name) == getattr(ref, name), name
    for name in ("rmse", "rmse_sigma", "condition", "photometric_sigma"):
        np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=rtol, atol=atol, err_msg=name)
    if pose_atol:
        np.testing.assert_allclose(got.T, ref.T, atol=pose_atol)
    else:
        np.testing.assert_array_equal(got.T, ref.T)
    assert (got.covariance is None) == (ref.covariance is None)
    if ref.covariance is not None:
        np.testing.assert_allclose(got.covariance, ref.covariance, rtol=1e-7, atol=1e-15)


@pytest.mark.parametrize("grow_px", [15, 0])
def test_the_batched_scores_equal_the_per_object_scores(grow_px):
    items, frame = _items()
    cfg = IcpConfig(grow_px=grow_px)
    got = icp_scores(items, frame, config=cfg)
    ref = [icp_score(i.model, i.T, frame, i.mask, None, cfg, i.model_gray, i.step) for i in items]
    for g, r in zip(got, ref, strict=True):
        _same(g, r)
    # the known answers: at the truth every visible point agrees; 1 cm aside the grey levels see
    # the slide; 30 cm aside nothing is found; 5 cm nearer nothing agrees
    assert ref[0] is not None and ref[0].agreement > 0.95 and ref[0].photometric_sigma < 0.5
    assert ref[2] is not None and ref[2].photometric_sigma > 1.5 and ref[4] is None
    assert ref[6] is not None and ref[6].agree < 6 and ref[6].covariance is None
    assert icp_scores([], frame) == []


def test_a_bad_item_is_refused_by_name():
    items, frame = _items()
    bad = ScoreItem(items[0].model[:, :2], items[0].T, items[0].mask)
    with pytest.raises(ValueError, match="model has shape"):
        icp_scores([items[0], bad], frame)
    with pytest.raises(ValueError, match="model_gray has shape"):
        icp_scores([ScoreItem(items[0].model, items[0].T, items[0].mask, items[0].model_gray[:3])], frame)


def test_grey_levels_and_their_gradients_sampled_together_equal_sampled_apart():
    rng = np.random.default_rng(3)
    levels = rng.random((20, 30, 3)).astype(np.float32)
    u, v = rng.uniform(0, 28.99, 50), rng.uniform(0, 18.99, 50)
    together = bilinear(levels, u, v)
    for c in range(3):
        np.testing.assert_array_equal(together[:, c], bilinear(levels[:, :, c], u, v))
    # the known answer: a linear ramp is sampled exactly
    ramp = np.add.outer(np.arange(20.0), 2.0 * np.arange(30.0))
    np.testing.assert_allclose(bilinear(ramp, u, v), v + 2.0 * u, atol=1e-12)


def test_a_snapshot_surface_is_sampled_once_per_setting():
    frame = _scene(0.0)
    mask = Mask.from_full(frame.labels == 1)
    x0, y0, x1, y1 = mask.bbox
    snap = Snapshot(
        0,
        0.0,
        mask.bbox,
        frame.rgb[y0:y1, x0:x1],
        frame.depth[y0:y1, x0:x1],
        mask.crop,
        frame.K,
        1.0,
        None,
        np.eye(4),
        np.zeros(1),
    )
    first = snapshot_surface(snap, IcpConfig(), (0.1, 6.0))
    assert snapshot_surface(snap, IcpConfig(), (0.1, 6.0))[0] is first[0]
    pts, gray, step = surface_points(
        frame.depth[y0:y1, x0:x1], mask.crop, (x0, y0), frame.K, 160, gray=frame.gray()[y0:y1, x0:x1]
    )
    np.testing.assert_array_equal(first[0], pts)
    np.testing.assert_array_equal(first[1], gray)
    assert first[2] == step and not first[0].flags.writeable
    other = snapshot_surface(snap, IcpConfig(max_points=40), (0.1, 6.0))
    assert len(other[0]) < len(first[0])
