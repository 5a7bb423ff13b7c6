"""Touching objects kept apart: concave creases, colour edges backed by creases, small objects on the support."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.creases import creases, normal_change, surface_normals
from pal.perception.masks import iou
from pal.perception.regions import merge_small, smooth_pairs, supported_colour_edges
from pal.perception.segmentation import GeometricSegmenter, OracleSegmenter, SegmentationConfig
from pal.perception.synthetic import Box, SyntheticCamera


def on_table(cam: SyntheticCamera, x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T[:3, 3] = [x, y, z]
    return cam.table @ T


def fold(sign: float) -> tuple[np.ndarray, np.ndarray]:
    """Depth (60, 80) of two planes meeting at column 40: a valley (sign -1) or a ridge (+1), and K."""
    K = np.array([[100.0, 0.0, 39.5], [0.0, 100.0, 29.5], [0.0, 0.0, 1.0]])
    u = np.arange(80, dtype=np.float64)
    x = (u - K[0, 2]) / K[0, 0]
    # z = 1 + sign * 0.8 |X| along the rays X = x z: solve z (1 - sign 0.8 |x|) = 1
    z = 1.0 / (1.0 - sign * 0.8 * np.abs(x))
    return np.tile(z.astype(np.float32), (60, 1)), K


def test_concave_creases_mark_a_valley_and_convex_ones_a_ridge():
    for sign, want, other in ((-1.0, 0, 1), (1.0, 1, 0)):
        depth, K = fold(sign)
        pts, n = surface_normals(depth, K, window=3, step=2)
        assert pts.shape == (3, 60, 80) and np.allclose(np.linalg.norm(n[:, 10:-10, 10:-10], axis=0), 1.0)
        assert (n[2, 10:-10, 10:-10] < 0).all()  # towards the camera
        gap = np.full(depth.shape, 0.05, np.float32)
        marks = creases(pts, n, 2, 0.3, gap, np.full(depth.shape, 0.001, np.float32))
        cols = np.flatnonzero(marks[want][30])
        assert cols.size > 0 and np.all(np.abs(cols - 39.5) < 4), cols
        assert not marks[other].any()
        assert normal_change(n, 2)[30, 40] > 0.1 and normal_change(n, 2)[30, 10] < 1e-3
    # noise larger than the crease's depth is no crease
    depth, K = fold(-1.0)
    pts, n = surface_normals(depth, K, 3, 2)
    big = np.full(depth.shape, 1.0, np.float32)
    assert not creases(pts, n, 2, 0.3, big, big)[0].any()
    with pytest.raises(ValueError, match="tau"):
        creases(pts, n, 2, 2.5, big, big)
    with pytest.raises(ValueError, match="window"):
        surface_normals(depth, K, 4, 2)


def test_colour_edge_curves_cut_only_where_they_touch_a_crease():
    rgb = np.full((40, 60, 3), 120, np.uint8)
    rgb[:, 30:] = (200, 40, 40)  # a boundary curve at column 30, rows 0-39
    rgb[5:12, 5:12] = (20, 20, 200)  # a printed square far from any crease
    region = np.ones((40, 60), bool)
    evidence = np.zeros((40, 60), bool)
    evidence[36:40, 29:31] = True  # a crease at the bottom end of the boundary
    cut = supported_colour_edges(rgb, region, evidence, reach=2)
    assert cut[:, 28:32].any(axis=1).mean() > 0.8  # the whole boundary, also far from the crease
    assert not cut[:15, :15].any()  # the print is not cut
    assert not supported_colour_edges(rgb, region, np.zeros_like(evidence), reach=2).any()


def test_small_pieces_join_only_across_smooth_borders():
    labels = np.zeros((10, 12), np.int32)
    labels[:, :6] = 1  # large
    labels[:, 6:9] = 2  # small, behind a depth step from 1
    labels[:, 9:] = 3  # small, smooth with 2
    depth = np.ones((10, 12), np.float32)
    depth[:, 6:] = 1.2
    keep = np.array([False, True, False, False])
    joined = merge_small(labels, keep, smooth_pairs(depth, np.full(depth.shape, 0.05, np.float32)))
    assert (joined[:, :6] == 1).all() and (joined[:, 6:] == 2).all()  # 2 and 3 unite, apart from 1
    old = merge_small(labels, keep)  # without the depth rule: 2 joins 1, 3 (no kept neighbour) is dropped
    assert (old[:, 6:9] == 1).all() and (old[:, 9:] == 0).all()


@pytest.fixture(scope="module")
def cam() -> SyntheticCamera:
    return SyntheticCamera(320, 240)


def test_touching_boxes_of_different_heights_split_and_a_printed_box_does_not(cam):
    # side by side, faces touching, the lower one 3 cm further forward: no depth jump along the
    # contact, concave creases instead (its top against the tall one's side, the fronts' corner)
    left = Box((0.08, 0.10, 0.12), on_table(cam, -0.04, 0.0, 0.06), label=1, seed=1)
    right = Box((0.08, 0.10, 0.06), on_table(cam, 0.04, -0.03, 0.03), label=2, seed=2)
    f = cam.render([left, right], depth_noise=0.0005, rng=np.random.default_rng(0))
    gt = OracleSegmenter()(f)
    got = GeometricSegmenter(SegmentationConfig(), rng=0)(f)
    assert len(got) == 2
    for g in gt:
        assert max(iou(g.mask, c.mask) for c in got) >= 0.8
    old = GeometricSegmenter(SegmentationConfig(crease_tau=0.0, cut_width=0.0), rng=0)(f)
    assert len(old) == 1  # depth jumps alone keep them together
    single = cam.render([Box((0.16, 0.10, 0.12), on_table(cam, 0.0, 0.0, 0.06), label=1, seed=3, cells=12)])
    assert len(GeometricSegmenter(SegmentationConfig(), rng=0)(single)) == 1


def test_a_flat_object_on_the_support_is_kept(cam):
    flat = Box((0.08, 0.03, 0.015), on_table(cam, 0.0, -0.05, 0.0075, 0.4), label=1, seed=4)
    f = cam.render([flat])
    got = GeometricSegmenter(SegmentationConfig(), rng=0)(f)
    assert len(got) == 1 and iou(got[0].mask, OracleSegmenter()(f)[0].mask) >= 0.6
    assert got[0].size < SegmentationConfig().min_size  # kept by the smaller size on the support
    # ... only when it covers enough pixels to be described (here about 10 times fewer than asked)
    coarse = SegmentationConfig(grounded_pixels=10 * got[0].mask.area * (640 // f.width) ** 2)
    assert GeometricSegmenter(coarse, rng=0)(f) == []
    # the same piece floating 10 cm above the table is a fragment, not an object
    high = cam.render([Box((0.08, 0.03, 0.015), on_table(cam, 0.0, -0.05, 0.1075, 0.4), label=1, seed=4)])
    assert GeometricSegmenter(SegmentationConfig(), rng=0)(high) == []


def test_new_segmentation_settings_are_checked():
    with pytest.raises(ValueError, match="crease_tau"):
        SegmentationConfig(crease_tau=2.0)
    with pytest.raises(ValueError, match="cut_width"):
        SegmentationConfig(cut_width=-1.0)
    with pytest.raises(ValueError, match="normal_step"):
        SegmentationConfig(normal_step=0)
    with pytest.raises(ValueError, match="grounded_pixels"):
        SegmentationConfig(grounded_pixels=-1)
