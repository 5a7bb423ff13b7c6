"""The relations of many pairs at once equal the per-pair definitions of the grounding module."""

from __future__ import annotations

import numpy as np

from pal.perception.grounding import PREDICATES, GroundingConfig, ObjectGeometry, box_gap, grade, surface_gap
from pal.perception.pair_geometry import displacements, grade_pairs, surface_gaps


def _objects(n: int, seed: int = 0) -> dict[int, ObjectGeometry]:
    rng = np.random.default_rng(seed)
    out = {}
    for i in range(n):
        c = rng.uniform(-0.3, 0.3, 3) * [1.0, 1.0, 0.2]
        half = rng.uniform(0.02, 0.08, 3)
        surface = c + rng.uniform(-1.0, 1.0, (40, 3)) * half
        bottom = float(c[2] - half[2]) if i % 3 else 0.0
        out[i] = ObjectGeometry(
            c, c[:2] - half[:2], c[:2] + half[:2], bottom, float(c[2] + half[2]), 0.004 + 0.002 * i, surface
        )
    # a small box resting on a big one, a surface point of each where they meet
    out[0] = ObjectGeometry(
        np.array([0.0, 0.0, 0.05]),
        np.array([-0.05, -0.05]),
        np.array([0.05, 0.05]),
        0.0,
        0.1,
        0.004,
        np.vstack([rng.uniform(-0.05, 0.05, (40, 3)) + np.array([0.0, 0.0, 0.05]), [[0.0, 0.0, 0.1]]]),
    )
    out[1] = ObjectGeometry(
        np.array([0.0, 0.0, 0.15]),
        np.array([-0.03, -0.03]),
        np.array([0.03, 0.03]),
        0.1,
        0.2,
        0.004,
        np.vstack([rng.uniform(-0.03, 0.03, (40, 3)) + np.array([0.0, 0.0, 0.15]), [[0.0, 0.0, 0.1]]]),
    )
    return out


def test_grades_and_gaps_of_all_pairs_equal_the_per_pair_ones():
    geo, cfg = _objects(9), GroundingConfig()
    pairs = [(a, b) for a in geo for b in geo if a < b]
    gap = surface_gaps(pairs, geo, cfg, {})
    for k, (a, b) in enumerate(pairs):
        far = box_gap(geo[a], geo[b])
        ref = far if far > cfg.touch_gap + 0.05 else surface_gap(geo[a], geo[b])
        np.testing.assert_allclose(gap[k], ref, rtol=1e-12, atol=1e-15)
    rows = grade_pairs([geo[a] for a, _ in pairs], [geo[b] for _, b in pairs], cfg, gap)
    back = grade_pairs([geo[b] for _, b in pairs], [geo[a] for a, _ in pairs], cfg, gap)
    for k, (a, b) in enumerate(pairs):
        for got, (x, y) in ((rows[k], (a, b)), (back[k], (b, a))):
            ref = grade(geo[x], geo[y], cfg, float(gap[k]))
            np.testing.assert_allclose(got, [ref[p] for p in PREDICATES], rtol=1e-12, atol=1e-15)
    # the known answers: the small box rests on the big one and touches it
    k = pairs.index((0, 1))
    assert back[k][PREDICATES.index("on")] > 0.9 and rows[k][PREDICATES.index("on")] == 0.0
    assert rows[k][PREDICATES.index("touching")] > 0.9 and surface_gaps([], geo, cfg, {}).shape == (0,)


def test_displacements_point_from_a_to_b():
    a = np.array([[0.0, 0.0, 1.0], [1.0, 2.0, 3.0], [0.5, 0.5, 0.5]])
    b = np.array([[0.3, 0.4, 1.0], [1.0, 2.0, 3.0], [0.5, 0.5, 1.5]])
    d, dist, direc = displacements(a, b)
    np.testing.assert_allclose(d, b - a)
    np.testing.assert_allclose(dist, [0.5, 0.0, 1.0])
    np.testing.assert_allclose(direc, [[0.6, 0.8, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
