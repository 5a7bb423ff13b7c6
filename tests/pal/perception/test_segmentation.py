"""Segmentation Σ on analytic scenes with known masks; masks, IoU/IoM and the plane fit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.frames import RGBDFrame
from pal.perception.masks import Mask, intersection_area, iom, iou
from pal.perception.plane import Plane, fit_plane_ransac
from pal.perception.segmentation import GeometricSegmenter, OracleSegmenter, SegmentationConfig
from pal.perception.synthetic import Box, Sphere, SyntheticCamera, table_pose


def on_table(cam: SyntheticCamera, x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T[:3, 3] = [x, y, z]
    return cam.table @ T


def scene(cam: SyntheticCamera) -> RGBDFrame:
    return cam.render(
        [
            Box((0.12, 0.08, 0.06), on_table(cam, -0.12, 0.0, 0.03, 0.3), label=1, seed=1),
            Box((0.08, 0.08, 0.10), on_table(cam, 0.12, 0.05, 0.05, -0.2), label=2, seed=2),
            Sphere(0.04, (cam.table @ np.array([0.0, -0.12, 0.04, 1.0]))[:3], label=3),
        ]
    )


def best_iou(gt: Mask, masks: list[Mask]) -> float:
    return max(iou(gt, m) for m in masks)


def test_geometric_segmentation_recovers_objects_on_the_plane():
    cam = SyntheticCamera(160, 120)
    f = scene(cam)
    seg = GeometricSegmenter(SegmentationConfig(min_area=30), rng=0)
    cands = seg(f)
    gt = OracleSegmenter()(f)
    assert len(cands) == 3 and len(gt) == 3
    for g in gt:
        # pixels within min_height (1 cm) of the table are cut: the boxes lose a sliver
        assert best_iou(g.mask, [c.mask for c in cands]) >= 0.85, g.label
    plane = seg.last_plane
    assert plane is not None
    assert np.allclose(plane.normal, cam.table[:3, 2], atol=1e-3)
    assert plane.offset == pytest.approx(-cam.table[:3, 2] @ cam.table[:3, 3], abs=1e-3)
    # a known plane gives the same masks without RANSAC
    known = GeometricSegmenter(SegmentationConfig(min_area=30, plane=plane))(f)
    assert [c.mask.area for c in known] == [c.mask.area for c in cands]


def test_objects_touching_in_the_image_split_at_the_depth_discontinuity():
    cam = SyntheticCamera(160, 120)
    back = Box((0.16, 0.05, 0.16), on_table(cam, 0.0, 0.10, 0.08), label=1, seed=1)
    front = Box((0.06, 0.06, 0.06), on_table(cam, 0.0, -0.02, 0.03), label=2, seed=2)
    f = cam.render([back, front])
    gt = OracleSegmenter()(f)
    assert len(gt) == 2 and intersection_area(gt[0].mask, gt[1].mask) == 0
    cands = GeometricSegmenter(SegmentationConfig(min_area=30))(f)
    assert len(cands) == 2
    for g in gt:
        assert best_iou(g.mask, [c.mask for c in cands]) >= 0.8


def test_min_area_and_frames_without_depth():
    cam = SyntheticCamera(160, 120)
    f = scene(cam)
    big = GeometricSegmenter(SegmentationConfig(min_area=350))(f)
    assert len(big) == 1  # only the larger box (383 px) is above 350 px; the others have 329 and 222
    empty = RGBDFrame(f.rgb, np.zeros_like(f.depth), f.K, 0.0)
    seg = GeometricSegmenter()
    assert seg(empty) == [] and seg.last_plane is None


def test_segmentation_is_deterministic_for_a_seed():
    cam = SyntheticCamera(160, 120)
    f = cam.render(
        [Box((0.1, 0.1, 0.05), on_table(cam, 0, 0, 0.025), seed=4)],
        depth_noise=0.002,
        rng=np.random.default_rng(1),
    )
    a = GeometricSegmenter(SegmentationConfig(min_area=30), rng=7)(f)
    b = GeometricSegmenter(SegmentationConfig(min_area=30), rng=7)(f)
    assert [(c.mask.bbox, c.mask.area) for c in a] == [(c.mask.bbox, c.mask.area) for c in b]


def test_oracle_segmenter():
    cam = SyntheticCamera(160, 120)
    f = scene(cam)
    cands = OracleSegmenter()(f)
    assert [c.label for c in cands] == [1, 2, 3]
    for c in cands:
        assert np.array_equal(c.mask.full(), f.labels == c.label)
    assert [c.label for c in OracleSegmenter(background_ids=(0, 2))(f)] == [1, 3]
    no_labels = RGBDFrame(f.rgb, f.depth, f.K, 0.0)
    with pytest.raises(ValueError, match="needs frame.labels"):
        OracleSegmenter()(no_labels)
    with pytest.raises(ValueError, match="negative ids"):
        OracleSegmenter()(f, labels=-np.ones(f.shape, np.int32))


def test_masks_and_overlap_measures():
    a = np.zeros((20, 30), bool)
    a[2:6, 3:13] = True  # 40 px
    b = np.zeros((20, 30), bool)
    b[4:8, 3:8] = True  # 20 px, 10 shared with a
    ma, mb = Mask.from_full(a), Mask.from_full(b)
    assert ma.bbox == (3, 2, 13, 6) and ma.area == 40 and ma.xywh == (3, 2, 10, 4)
    assert np.array_equal(ma.full(), a)
    assert intersection_area(ma, mb) == 10
    assert iou(ma, mb) == pytest.approx(10 / 50)
    assert iom(ma, mb) == pytest.approx(10 / 20)
    assert ma.centroid() == pytest.approx((7.5, 3.5))
    tight = Mask.from_crop(np.pad(b[4:8, 3:8], 2), 1, 2, (20, 30))
    assert tight.bbox == (3, 4, 8, 8) and tight.area == 20
    far = np.zeros((20, 30), bool)
    far[15:18, 20:25] = True
    assert iou(ma, Mask.from_full(far)) == 0.0
    with pytest.raises(ValueError, match="zero-size"):
        Mask.from_full(np.zeros((20, 30), bool))
    with pytest.raises(ValueError, match="zero-size"):
        Mask.from_crop(np.zeros((3, 3), bool), 0, 0, (20, 30))
    with pytest.raises(ValueError, match="leaves the image"):
        Mask.from_crop(np.ones((3, 3), bool), 29, 0, (20, 30))


def test_ransac_plane_fit_ignores_outliers():
    rng = np.random.default_rng(0)
    n = np.array([0.0, -0.6, -0.8])
    xy = rng.uniform(-0.5, 0.5, size=(500, 2))
    basis = np.array([[1.0, 0.0, 0.0], [0.0, 0.8, -0.6]])
    pts = xy @ basis + np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.002, (500, 1)) * n
    outliers = rng.uniform(-0.5, 0.5, size=(200, 3)) + np.array([0, 0, 1.0])
    plane = fit_plane_ransac(np.vstack([pts, outliers]), 0.01, rng)
    assert abs(plane.normal @ n) == pytest.approx(1.0, abs=1e-3)
    assert plane.offset > 0  # the camera side is positive
    assert plane.height(np.zeros(3)) == pytest.approx(plane.offset)
    with pytest.raises(ValueError, match="N >= 3"):
        fit_plane_ransac(pts[:2], 0.01, rng)
    with pytest.raises(ValueError, match="zero length"):
        Plane(np.zeros(3), 1.0)


def test_segmentation_config_is_checked():
    with pytest.raises(ValueError, match="depth range"):
        SegmentationConfig(min_depth=2.0, max_depth=1.0)
    with pytest.raises(ValueError, match="plane_threshold"):
        SegmentationConfig(plane_threshold=0.0)


def test_the_plane_is_tracked_and_refitted_when_the_support_changes(monkeypatch):
    import pal.perception.segmentation as segmentation

    calls = []
    real = segmentation.choose_support
    monkeypatch.setattr(segmentation, "choose_support", lambda *a, **k: calls.append(1) or real(*a, **k))
    cam = SyntheticCamera(160, 120)
    f = scene(cam)
    seg = GeometricSegmenter(SegmentationConfig(min_area=30), rng=0)
    first = seg(f)
    again = seg(f)  # same support: the previous plane is refined, no RANSAC
    assert len(calls) == 1 and [c.mask.area for c in again] == [c.mask.area for c in first]
    assert np.allclose(seg.last_plane.normal, cam.table[:3, 2], atol=1e-3)
    tilted = SyntheticCamera(160, 120, table=table_pose(0.7, 30.0))
    seg(scene(tilted))  # a different support plane: RANSAC again
    assert len(calls) == 2 and np.allclose(seg.last_plane.normal, tilted.table[:3, 2], atol=1e-3)
    untracked = GeometricSegmenter(SegmentationConfig(min_area=30, track_plane=False), rng=0)
    untracked(f), untracked(f)
    assert len(calls) == 4
    with pytest.raises(ValueError, match="track_tolerance"):
        SegmentationConfig(track_tolerance=0.0)
