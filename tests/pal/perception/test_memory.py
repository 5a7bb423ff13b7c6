"""EEMS (Eq. 4.12-4.13): admission by area, sharpness, rank, MSE and feature overlap; eviction."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pal.perception.features import FeatureExtractor
from pal.perception.frames import RGBDFrame
from pal.perception.memory import AdmissionConfig, Gallery
from pal.perception.segmentation import OracleSegmenter
from pal.perception.synthetic import Box, Sphere, SyntheticCamera

CAM = SyntheticCamera(320, 240)
EXTRACTOR = FeatureExtractor()


def view(yaw_deg: float, t: float = 0.0, sphere: bool = False) -> RGBDFrame:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = [0.0, 0.0, 0.04]
    if sphere:
        return CAM.render([Sphere(0.05, (CAM.table @ np.array([0, 0, 0.05, 1.0]))[:3])], t)
    return CAM.render([Box((0.16, 0.12, 0.08), CAM.table @ T, seed=5)], t)


def consider(g: Gallery, f: RGBDFrame, anchor: np.ndarray | None = None):
    mask = OracleSegmenter()(f)[0].mask
    gray = f.gray()
    return g.consider(f, gray, mask, lambda: EXTRACTOR(gray, mask), EXTRACTOR, anchor)


def test_admission_checks_run_in_order():
    g = Gallery(AdmissionConfig(min_area=100))
    first = consider(g, view(0.0))
    assert first.admitted and first.reason == "admitted" and first.snapshot == 0
    assert consider(g, view(0.0, 0.1)).reason == "mse"  # the same view is redundant
    bright = view(0.0, 0.2)
    bright = RGBDFrame(
        np.clip(bright.rgb.astype(np.float32) * 1.4, 0, 255).astype(np.uint8),
        bright.depth,
        bright.K,
        0.2,
        bright.labels,
    )
    assert consider(g, bright).reason == "features"  # pixels differ, but the same features match
    blurred = view(40.0, 0.3)
    blurred = RGBDFrame(
        cv2.GaussianBlur(np.ascontiguousarray(blurred.rgb), (9, 9), 3.0),
        blurred.depth,
        blurred.K,
        0.3,
        blurred.labels,
    )
    assert consider(g, blurred).reason == "rank"  # much blurrier than the last views
    turned = consider(g, view(40.0, 0.4))
    assert turned.admitted and turned.snapshot == 1
    assert len(g) == 2 and g.visual_descriptor().shape == (54,)
    assert consider(Gallery(AdmissionConfig(min_area=10**6)), view(0.0)).reason == "area"
    assert (
        consider(Gallery(AdmissionConfig(min_area=100, min_sharpness=10.0)), view(0.0, sphere=True)).reason
        == "sharpness"
    )


def test_eviction_removes_the_most_redundant_snapshot_but_never_the_canonical():
    cfg = AdmissionConfig(min_area=100, capacity=3, min_mse=1.0, max_feature_matches=10**6)
    g = Gallery(cfg)
    f0 = view(0.0)
    mask = OracleSegmenter()(f0)[0].mask
    gray = f0.gray()
    assert g.set_canonical(f0, gray, mask, EXTRACTOR(gray, mask), np.eye(4)).reason == "canonical"
    assert consider(g, view(2.0, 0.1)).admitted  # near-duplicate of the canonical view
    assert consider(g, view(60.0, 0.2)).admitted
    d = consider(g, view(90.0, 0.3))
    assert d.admitted and d.evicted == 1  # the 2-degree view, not the canonical one
    assert [s.index for s in g.snapshots] == [0, 2, 3]
    assert g.canonical is g.snapshots[0] and g.anchored() == [g.snapshots[0]]
    with pytest.raises(ValueError, match="already set"):
        g.set_canonical(f0, gray, mask, EXTRACTOR(gray, mask), np.eye(4))


def test_snapshots_keep_crops_metadata_and_anchor():
    g = Gallery(AdmissionConfig(min_area=100, margin=8))
    anchor = np.eye(4)
    anchor[:3, 3] = [0.1, 0.2, 0.3]
    f = view(10.0, 1.5)
    d = consider(g, f, anchor)
    s = g.snapshots[0]
    mask = OracleSegmenter()(f)[0].mask
    x0, y0, x1, y1 = mask.bbox
    assert s.bbox == (x0 - 8, y0 - 8, x1 + 8, y1 + 8) and s.rgb.shape[:2] == s.mask.shape == s.depth.shape
    assert s.mask.sum() == mask.area and s.timestamp == 1.5 and d.snapshot == s.index
    assert np.array_equal(s.anchor, anchor) and s.features is not None and len(s.features) > 10
    assert (
        s.visual is None and s.visual_vector().shape == (54,) and s.visual is not None
    )  # computed once, lazily
    assert s.sharpness > 0


def test_admission_config_is_checked():
    with pytest.raises(ValueError, match="capacity"):
        AdmissionConfig(capacity=1)
    with pytest.raises(ValueError, match="rank_tolerance"):
        AdmissionConfig(rank_tolerance=0.0)
