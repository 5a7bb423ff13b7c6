"""Grounded predicates in metres: near by the 3-D gap whatever the sizes, on_support needs a visible foot."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pal.experiments.perception.mask_scores import score_masks
from pal.perception.frames import RGBDFrame
from pal.perception.grounding import (
    GroundingConfig,
    ObjectGeometry,
    bottom_visibility,
    grade,
    object_geometry,
    on_support,
    support_frame,
)
from pal.perception.masks import Mask
from pal.perception.plane import Plane
from pal.perception.segmentation import GeometricSegmenter, SegmentationConfig
from pal.perception.synthetic import Box, SyntheticCamera

CONFIG = GroundingConfig()


def _box(lo, hi, bottom: float, top: float, sigma: float = 0.005, visible: float = 1.0) -> ObjectGeometry:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre = np.array([*(lo + hi) / 2, (bottom + top) / 2])
    return ObjectGeometry(centre, lo, hi, bottom, top, sigma, centre[None, :], visible)


def test_near_is_the_metric_gap_so_a_wall_is_not_near_everything():
    cup = _box([0.0, 0.0], [0.08, 0.08], 0.0, 0.1)
    wall = _box([-2.0, 1.17], [2.0, 1.3], 0.0, 2.5)  # 1.09 m behind the cup
    assert grade(cup, wall, CONFIG)["near"] < 1e-6 and grade(wall, cup, CONFIG)["near"] < 1e-6
    s = 0.25 * CONFIG.near_distance + np.hypot(0.005, 0.005)
    for gap, expected in ((0.0, 0.99), (0.1, 0.5), (0.2, 0.0)):
        other = _box([0.08 + gap, 0.0], [0.16 + gap, 0.08], 0.0, 0.1)
        z = (CONFIG.near_distance - gap) / s
        assert grade(cup, other, CONFIG)["near"] == pytest.approx(
            0.5 * math.erfc(-z / math.sqrt(2)), abs=1e-12
        )
        assert grade(cup, other, CONFIG)["near"] == pytest.approx(expected, abs=0.011)
    shelf = _box([0.0, 0.0], [0.08, 0.08], 0.5, 0.52)  # straight above the cup, 40 cm up
    assert grade(cup, shelf, CONFIG)["near"] < 1e-6


def _scene(occluder_depth: float | None, reach_border: bool = False) -> tuple[np.ndarray, Mask]:
    """A 40x40 depth image: floor at 2.00 m, an object at 2.0 m in rows 10-25 (or to the border)."""
    depth = np.full((40, 40), 1.995, np.float32)  # the floor just before the object's foot
    last = 39 if reach_border else 25
    depth[10 : last + 1, 12:28] = 2.0
    if occluder_depth is not None:
        depth[26:, 5:35] = occluder_depth
    full = np.zeros((40, 40), bool)
    full[10 : last + 1, 12:28] = True
    return depth, Mask.from_full(full)


def test_bottom_visibility_tells_a_foot_on_the_floor_from_one_behind_a_table_edge():
    assert bottom_visibility(*_scene(None), margin=0.03) == 1.0
    assert bottom_visibility(*_scene(1.2), margin=0.03) == 0.0  # a table edge 0.8 m nearer
    assert bottom_visibility(*_scene(None, reach_border=True), margin=0.03) == 0.0  # cut by the image
    depth, mask = _scene(None)
    depth[26:, 12:20] = 1.2  # half the foot hidden
    assert bottom_visibility(depth, mask, margin=0.03) == pytest.approx(0.5)
    depth[26:, 12:28] = 0.0  # no depth under the edge: nothing hides it
    assert bottom_visibility(depth, mask, margin=0.03) == 1.0


def test_on_support_needs_the_foot_to_be_seen():
    seen = _box([0, 0], [0.1, 0.1], 0.0, 0.5, visible=1.0)
    hidden = _box([0, 0], [0.1, 0.1], 0.0, 0.5, visible=0.0)
    assert on_support(seen, CONFIG) > 0.9 and on_support(hidden, CONFIG) == 0.0
    assert on_support(_box([0, 0], [0.1, 0.1], 0.0, 0.5, visible=0.5), CONFIG) == pytest.approx(
        0.5 * on_support(seen, CONFIG)
    )


def _rendered_stack() -> tuple[RGBDFrame, np.ndarray]:
    """Box 2 on box 1, box 3 beside box 1 (10.6 cm away) on a table at 320x240; the frame and
    the support frame of the true table plane."""
    cam = SyntheticCamera(320, 240)

    def at(x: float, z: float) -> np.ndarray:
        t = np.eye(4)
        t[:3, 3] = [x, 0.0, z]
        return cam.table @ t

    frame = cam.render(
        [
            Box((0.14, 0.12, 0.08), at(-0.05, 0.04), label=1, seed=1),
            Box((0.08, 0.08, 0.06), at(-0.05, 0.11), label=2, seed=2),
            Box((0.06, 0.06, 0.06), at(0.15, 0.03), label=3, seed=3),
        ]
    )
    n = cam.table[:3, 2]
    return frame, support_frame(Plane(n, -float(n @ cam.table[:3, 3])))


def test_on_grades_a_rendered_stack_and_not_its_neighbour():
    frame, S = _rendered_stack()
    g = {k: object_geometry(frame, Mask.from_full(frame.labels == k), S, CONFIG) for k in (1, 2, 3)}
    assert grade(g[2], g[1], CONFIG)["on"] > 0.7 and grade(g[1], g[2], CONFIG)["on"] == 0.0
    assert grade(g[3], g[1], CONFIG)["on"] == 0.0 and grade(g[2], g[3], CONFIG)["on"] == 0.0
    assert (
        on_support(g[1], CONFIG) > 0.7 and on_support(g[3], CONFIG) > 0.7 and on_support(g[2], CONFIG) < 0.05
    )
    assert 0.3 < grade(g[1], g[3], CONFIG)["near"] < 0.6  # a 10.6 cm gap: about half near


def test_on_holds_for_the_segmenters_own_masks_of_a_rendered_stack():
    """The stack of the test above, segmented by Σ instead of cut out by its labels: the boxes come
    out as three clean masks (IoU >= 0.7), and ``on`` graded on those masks fires (> 0.5) for the
    stacked pair only. It is lower than on the true masks (0.55 against 0.82): the cut between the
    stacked boxes leaves a band of the upper box (8 % of the lower one's mask) in the lower one,
    which lifts its top (98th percentile of the heights) by 2 cm."""
    frame, S = _rendered_stack()
    masks = [c.mask for c in GeometricSegmenter(SegmentationConfig(), rng=0)(frame)]
    assert [s.outcome for s in score_masks(frame.labels, masks, clean_iou=0.7)] == ["clean"] * 3
    best = {k: max(masks, key=lambda m: _iou(m.full(), frame.labels == k)) for k in (1, 2, 3)}
    g = {k: object_geometry(frame, best[k], S, CONFIG) for k in (1, 2, 3)}
    assert grade(g[2], g[1], CONFIG)["on"] > 0.5
    assert grade(g[1], g[2], CONFIG)["on"] == 0.0 and grade(g[3], g[1], CONFIG)["on"] == 0.0


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))
