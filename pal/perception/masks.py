"""Instance masks (``Mask``: a tight bounding box plus a boolean crop) and their overlap measures.

The overlap measures are those of Eq. 4.9-4.10 (IoU, IoM). Storing the crop instead of the
full (H, W) image keeps memory and overlap tests proportional to the object's size: two masks
whose boxes do not intersect cost nothing to compare.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Mask", "intersection_area", "iom", "iou"]


@dataclass(frozen=True, eq=False)
class Mask:
    """A non-empty instance mask.

    Attributes:
        bbox: (x0, y0, x1, y1) pixel box, x1/y1 exclusive, tight around the mask.
        crop: (y1 - y0, x1 - x0) bool, the mask inside ``bbox``.
        image_shape: (H, W) of the image the mask lives in.
        area: number of mask pixels (> 0).
    """

    bbox: tuple[int, int, int, int]
    crop: np.ndarray
    image_shape: tuple[int, int]
    area: int

    @staticmethod
    def from_full(mask: np.ndarray) -> Mask:
        """Build from an (H, W) boolean image.

        Raises:
            ValueError: not 2-D, or zero-size (no pixel set).
        """
        mask = np.asarray(mask, dtype=bool)
        if mask.ndim != 2:
            raise ValueError(f"mask has shape {mask.shape}, expected (H, W)")
        rows = np.flatnonzero(mask.any(axis=1))
        if rows.size == 0:
            raise ValueError(
                f"mask of shape {mask.shape} is empty (zero-size); an object mask needs >= 1 pixel"
            )
        cols = np.flatnonzero(mask.any(axis=0))
        y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        crop = mask[y0:y1, x0:x1].copy()
        return Mask((x0, y0, x1, y1), crop, (int(mask.shape[0]), int(mask.shape[1])), int(crop.sum()))

    @staticmethod
    def from_crop(crop: np.ndarray, x0: int, y0: int, image_shape: tuple[int, int]) -> Mask:
        """Build from a boolean crop whose top-left pixel is (x0, y0); the box is tightened.

        Raises:
            ValueError: zero-size mask, or the crop leaves the image.
        """
        crop = np.asarray(crop, dtype=bool)
        if crop.ndim != 2:
            raise ValueError(f"mask crop has shape {crop.shape}, expected (h, w)")
        h, w = crop.shape
        if x0 < 0 or y0 < 0 or y0 + h > image_shape[0] or x0 + w > image_shape[1]:
            raise ValueError(f"mask crop at ({x0}, {y0}) of size {w}x{h} leaves the image {image_shape}")
        rows = np.flatnonzero(crop.any(axis=1))
        if rows.size == 0:
            raise ValueError(
                f"mask crop of shape {crop.shape} is empty (zero-size); an object mask needs >= 1 pixel"
            )
        cols = np.flatnonzero(crop.any(axis=0))
        r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        tight = crop[r0:r1, c0:c1].copy()
        return Mask(
            (x0 + c0, y0 + r0, x0 + c1, y0 + r1),
            tight,
            (int(image_shape[0]), int(image_shape[1])),
            int(tight.sum()),
        )

    @property
    def xywh(self) -> tuple[int, int, int, int]:
        """The bounding box as ``(x0, y0, width, height)``, pixels."""
        x0, y0, x1, y1 = self.bbox
        return x0, y0, x1 - x0, y1 - y0

    def full(self) -> np.ndarray:
        """(H, W) bool image of the mask."""
        out = np.zeros(self.image_shape, dtype=bool)
        x0, y0, x1, y1 = self.bbox
        out[y0:y1, x0:x1] = self.crop
        return out

    def centroid(self) -> tuple[float, float]:
        """(u, v) mean pixel coordinate of the mask (computed once)."""
        cached = self.__dict__.get("_centroid")
        if cached is None:
            ys, xs = np.nonzero(self.crop)
            cached = (float(xs.mean() + self.bbox[0]), float(ys.mean() + self.bbox[1]))
            object.__setattr__(self, "_centroid", cached)
        return cached

    def region(self, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """The mask rendered inside an arbitrary box [x0, x1) x [y0, y1) (zeros elsewhere)."""
        out = np.zeros((y1 - y0, x1 - x0), dtype=bool)
        bx0, by0, bx1, by1 = self.bbox
        ix0, iy0, ix1, iy1 = max(x0, bx0), max(y0, by0), min(x1, bx1), min(y1, by1)
        if ix0 < ix1 and iy0 < iy1:
            out[iy0 - y0 : iy1 - y0, ix0 - x0 : ix1 - x0] = self.crop[
                iy0 - by0 : iy1 - by0, ix0 - bx0 : ix1 - bx0
            ]
        return out


def intersection_area(a: Mask, b: Mask) -> int:
    """|A ∩ B| in pixels (0 when the boxes do not overlap)."""
    ax0, ay0, ax1, ay1 = a.bbox
    bx0, by0, bx1, by1 = b.bbox
    x0, y0, x1, y1 = max(ax0, bx0), max(ay0, by0), min(ax1, bx1), min(ay1, by1)
    if x0 >= x1 or y0 >= y1:
        return 0
    sa = a.crop[y0 - ay0 : y1 - ay0, x0 - ax0 : x1 - ax0]
    sb = b.crop[y0 - by0 : y1 - by0, x0 - bx0 : x1 - bx0]
    return int(np.count_nonzero(sa & sb))


def iou(a: Mask, b: Mask) -> float:
    """Intersection over union (Eq. 4.9), in [0, 1]."""
    inter = intersection_area(a, b)
    return inter / float(a.area + b.area - inter)


def iom(a: Mask, b: Mask) -> float:
    """Intersection over the smaller area (Eq. 4.10), in [0, 1]."""
    return intersection_area(a, b) / float(min(a.area, b.area))
