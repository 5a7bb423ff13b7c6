"""Scoring instance masks against ground-truth labels: clean, merged, split or missed.

Every visible ground-truth object (at least ``min_pixels`` pixels) gets one outcome, from the
pixel counts ``N[i, k]`` of object ``i`` inside candidate mask ``k`` (the candidates are
painted in order, so a pixel belongs to at most one):

- **clean**: some candidate has IoU ``N[i, k] / (|i| + |k| - N[i, k]) >= clean_iou`` with it;
- else **missed**: less than half of its pixels lie in any candidate;
- else **merged**: the candidate holding most of its pixels also holds at least half of
  another object, e.g. two touching objects in one mask;
- else **split**: at least two candidates each hold ``split_share`` of its pixels;
- else **partial**: one candidate holds it but covers too little of it (a shrunken mask).

A merge is counted for every object it spoils (two objects in one mask: two merged objects,
unless one of them still has IoU >= ``clean_iou``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pal.perception.masks import Mask

__all__ = ["OUTCOMES", "ObjectScore", "score_masks"]

#: The outcomes, in the order tables list them.
OUTCOMES = ("clean", "merged", "split", "missed", "partial")


@dataclass(frozen=True)
class ObjectScore:
    """The outcome for one ground-truth object.

    Attributes:
        label: its ground-truth id.
        pixels: its visible pixels.
        best_iou: its best IoU with any candidate.
        outcome: one of :data:`OUTCOMES`.
    """

    label: int
    pixels: int
    best_iou: float
    outcome: str


def score_masks(
    labels: np.ndarray,
    masks: Sequence[Mask],
    *,
    clean_iou: float = 0.7,
    min_pixels: int = 1,
    split_share: float = 0.2,
) -> list[ObjectScore]:
    """Score candidate masks against a ground-truth label image (module docstring).

    Args:
        labels: (H, W) int ground-truth ids, 0 = background.
        masks: the candidates' masks, each of shape (H, W).
        clean_iou: IoU at which a mask is the object's clean mask.
        min_pixels: objects with fewer visible pixels are not scored.
        split_share: share of an object's pixels that makes a candidate one of its pieces.

    Returns:
        one score per visible object, in increasing label order.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer) or (labels.size and labels.min() < 0):
        raise ValueError(
            f"labels has shape {labels.shape} and dtype {labels.dtype}, expected (H, W) ids >= 0"
        )
    painted = np.zeros(labels.shape, np.int64)
    for k, m in enumerate(masks, start=1):
        if m.image_shape != labels.shape:
            raise ValueError(f"mask {k} lives in an image of shape {m.image_shape}, expected {labels.shape}")
        x0, y0, x1, y1 = m.bbox
        painted[y0:y1, x0:x1][m.crop] = k
    n = len(masks) + 1
    counts = np.bincount(
        labels.ravel().astype(np.int64) * n + painted.ravel(), minlength=(int(labels.max()) + 1) * n
    )
    counts = counts.reshape(-1, n)
    cand_size = counts.sum(axis=0)
    out = []
    for i in range(1, counts.shape[0]):
        row = counts[i]
        area = int(row.sum())
        if area < max(min_pixels, 1):
            continue
        inside = row[1:]
        ious = inside / np.maximum(area + cand_size[1:] - inside, 1) if n > 1 else np.zeros(0)
        best = float(ious.max()) if ious.size else 0.0
        if best >= clean_iou:
            outcome = "clean"
        elif inside.sum() < 0.5 * area:
            outcome = "missed"
        else:
            k = int(np.argmax(inside)) + 1
            others = np.delete(counts[1:, k] >= 0.5 * np.maximum(counts[1:].sum(axis=1), 1), i - 1)
            if others.any():
                outcome = "merged"
            elif int((inside >= split_share * area).sum()) >= 2:
                outcome = "split"
            else:
                outcome = "partial"
        out.append(ObjectScore(i, area, best, outcome))
    return out
