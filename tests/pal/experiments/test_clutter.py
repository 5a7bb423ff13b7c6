"""Scoring masks against known labels (clean, merged, split, missed, partial) and the clutter entry's baseline."""

from __future__ import annotations

import numpy as np
import pytest

from pal.experiments.perception import clutter
from pal.experiments.perception.clutter import baseline_segmentation
from pal.experiments.perception.mask_scores import score_masks
from pal.perception.masks import Mask
from pal.perception.segmentation import SegmentationConfig
from pal.sim.clutter import ClutterConfig


def box(shape: tuple[int, int], y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    m = np.zeros(shape, bool)
    m[y0:y1, x0:x1] = True
    return m


def test_each_object_gets_one_outcome():
    shape = (40, 60)
    labels = np.zeros(shape, np.int32)
    labels[2:12, 2:12] = 1  # clean
    labels[2:12, 20:30] = 2  # merged with 3
    labels[2:12, 30:40] = 3
    labels[20:30, 2:22] = 4  # split in two halves
    labels[20:30, 30:40] = 5  # missed
    labels[20:30, 45:55] = 6  # partial: 60 % of it
    labels[35:37, 0:3] = 7  # too small to score
    masks = [
        box(shape, 2, 12, 2, 13),
        box(shape, 2, 12, 20, 40),
        box(shape, 20, 30, 2, 12),
        box(shape, 20, 30, 12, 22),
        box(shape, 20, 26, 45, 55),
    ]
    scores = score_masks(labels, [Mask.from_full(m) for m in masks], clean_iou=0.7, min_pixels=10)
    assert [s.label for s in scores] == [1, 2, 3, 4, 5, 6]
    assert [s.outcome for s in scores] == ["clean", "merged", "merged", "split", "missed", "partial"]
    assert scores[0].best_iou == pytest.approx(100 / 110) and scores[0].pixels == 100
    assert scores[4].best_iou == 0.0
    # a larger threshold turns the clean mask into a partial one; no masks: everything missed
    assert score_masks(labels, [Mask.from_full(masks[0])], clean_iou=0.95)[0].outcome == "partial"
    assert {s.outcome for s in score_masks(labels, [])} == {"missed"}


def test_bad_labels_and_masks_are_refused():
    with pytest.raises(ValueError, match="ids >= 0"):
        score_masks(-np.ones((4, 4), np.int32), [])
    with pytest.raises(ValueError, match="ids >= 0"):
        score_masks(np.zeros((4, 4), np.float32), [])
    with pytest.raises(ValueError, match="expected \\(4, 4\\)"):
        score_masks(np.zeros((4, 4), np.int32), [Mask.from_full(np.ones((5, 5), bool))])


def test_the_baseline_turns_off_only_the_new_cuts():
    cfg = SegmentationConfig(jump_min=0.015)
    base = baseline_segmentation(cfg)
    assert base.crease_tau == 0 and base.cut_width == 0 and base.support.min_area == 0
    assert base.grounded_size == cfg.min_size and base.jump_min == 0.015


def test_touching_objects_on_rendered_clutter_come_out_as_clean_masks():
    """Three seeded scenes at 320x240 (19 visible objects): the segmenter keeps >= 80 % as one
    clean mask, while the baseline without the new cuts merges most of them (so the scenes do
    hold touching objects)."""
    config = clutter.Config(seed=100, scenes=3, scene=ClutterConfig(image=(320, 240)))
    m = clutter.run(config).metrics
    assert m["objects"] == m["baseline"]["objects"] >= 15
    assert m["share_clean"] >= 0.8
    assert m["baseline"]["share_clean"] <= 0.5
    assert m["merged"] < m["baseline"]["merged"]
