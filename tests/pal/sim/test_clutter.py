"""The cluttered tabletop: seeded layouts of touching objects, rendered with known masks."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pal.sim.clutter import ClutterConfig, render_clutter
from pal.sim.clutter_layout import ClutterObject, LayoutConfig, footprint, layout, overlap


def _gap(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance between the vertices of one polygon and the edges of the other, metres."""
    best = np.inf
    for p, q in ((a, b), (b, a)):
        s, e = q, np.roll(q, -1, axis=0)
        d = e - s
        t = np.clip(((p[:, None] - s[None]) * d[None]).sum(-1) / (d * d).sum(-1)[None], 0.0, 1.0)
        best = min(
            best, float(np.linalg.norm(p[:, None] - (s[None] + t[..., None] * d[None]), axis=-1).min())
        )
    return best


def test_layouts_are_seeded_and_objects_touch_without_overlapping():
    cfg = LayoutConfig(objects=(6, 8), clusters=(1, 1))
    objs = layout(3, cfg)
    assert objs == layout(3, cfg)
    assert objs != layout(4, cfg)
    assert 6 <= len(objs) <= 8 and [o.label for o in objs] == list(range(1, len(objs) + 1))
    polys = [footprint(o) for o in objs]
    for a, b in itertools.combinations(polys, 2):
        assert not overlap(a, b)
    # one cluster: every object touches another (the circumscribed polygon of a can leaves <= 0.1 mm)
    for i, p in enumerate(polys):
        assert min(_gap(p, q) for j, q in enumerate(polys) if j != i) < 2e-4
    for p in polys:
        assert np.all(np.abs(p) <= np.asarray(cfg.area) + 1e-9)
    kinds = {o.kind for s in range(3) for o in layout(s)}
    assert {"flat", "short_can", "box"} <= kinds


def test_overlap_of_convex_polygons():
    box = ClutterObject("box", "box", (0.1, 0.1, 0.1), (0.0, 0.0), 0.0, (1, 0, 0, 1), None, 1)
    assert overlap(footprint(box), footprint(box, (0.099, 0.0)))
    assert not overlap(footprint(box), footprint(box, (0.1, 0.0)))  # touching faces share no area
    can = ClutterObject("can", "cylinder", (0.1, 0.1, 0.1), (0.0, 0.0), 0.0, (1, 0, 0, 1), None, 2)
    assert footprint(can).shape == (48, 2)
    assert not overlap(footprint(box), footprint(can, (0.1002, 0.0)))  # circumscribed: 0.1 mm wider
    assert overlap(footprint(box), footprint(can, (0.1 + 1e-6, 0.0)))


def test_bad_layout_and_scene_settings_are_refused():
    with pytest.raises(ValueError, match="kind_weights"):
        LayoutConfig(kind_weights=(1.0, 1.0))
    with pytest.raises(ValueError, match="objects"):
        LayoutConfig(objects=(5, 3))
    with pytest.raises(ValueError, match="tilt_deg"):
        ClutterConfig(tilt_deg=(50.0, 40.0))
    with pytest.raises(ValueError, match="backend"):
        ClutterConfig(backend="vulkan")


def test_scenes_render_every_object_with_its_label():
    cfg = ClutterConfig(image=(160, 120), backend="raycast", sensor=None, depth_sigma=0.0, rgb_sigma=0.0)
    scene = render_clutter(2, cfg)
    f = scene.frame
    assert f.rgb.shape == (120, 160, 3) and f.labels is not None
    seen = set(np.unique(f.labels)) - {0}
    assert seen <= {o.label for o in scene.objects} and len(seen) >= len(scene.objects) - 1
    # exact depth: the labelled pixels lie on the objects, nearer than the table behind them
    assert (f.depth[f.labels > 0] > 0).all()
    again = render_clutter(2, cfg)
    np.testing.assert_array_equal(again.frame.labels, f.labels)
    np.testing.assert_array_equal(again.frame.depth, f.depth)


@pytest.mark.render
def test_sensor_noise_holes_and_textures_on_the_gl_camera():
    scene = render_clutter(1, ClutterConfig(image=(160, 120), backend="gl"))
    f = scene.frame
    assert scene.backend in ("egl", "osmesa", "glfw")
    holes = f.depth == 0  # dropouts, shadows, and the quantised far floor's edges
    assert 0.0 < float(holes[f.labels > 0].mean()) < 0.1 and float(holes.mean()) < 0.3
    printed = [o.label for o in scene.objects if o.texture is not None and (f.labels == o.label).sum() > 100]
    for label in printed:  # a printed object shows more than one colour
        assert f.rgb[f.labels == label].std(axis=0).max() > 15.0
