"""Conceptual spaces (Eq. 1.3-1.7, 4.23-4.26) with hand-computed distances."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pal.perception.concepts import ConceptualSpace, Domain, Entity


@pytest.fixture
def space() -> ConceptualSpace:
    colour = Domain("colour", ("hue", "saturation"), weights=(4.0, 1.0))
    shape = Domain("shape", ("size",))
    motion = Domain("motion", ("speed", "turn"))
    return ConceptualSpace([colour, shape, motion], salience={"colour": 2.0, "shape": 1.0, "motion": 1.0})


def test_weighted_l2_within_and_weighted_l1_across_domains(space):
    a = space.entity("a", {"colour": [0.0, 0.0], "shape": [1.0], "motion": [0.0, 0.0]})
    b = space.entity("b", {"colour": [1.0, 2.0], "shape": [4.0], "motion": [3.0, 4.0]})
    d_colour = math.sqrt(4 * 1 + 1 * 4)  # weighted L2: sqrt(8)
    assert space.domains["colour"].distance(a.points["colour"], b.points["colour"]) == pytest.approx(d_colour)
    # salience 2:1:1 renormalised to 0.5, 0.25, 0.25 (Eq. 1.6)
    assert space.distance(a, b) == pytest.approx(0.5 * d_colour + 0.25 * 3.0 + 0.25 * 5.0)
    assert space.weights(["colour", "shape"]) == pytest.approx({"colour": 2 / 3, "shape": 1 / 3})
    assert sum(space.weights(list(space.domains)).values()) == pytest.approx(1.0)
    assert space.distance(a, b, ["shape"]) == pytest.approx(3.0)
    assert space.distance(a, a) == 0.0


def test_partial_entities_compare_over_shared_or_required_domains(space):
    full = space.entity("full", {"colour": [0.0, 0.0], "motion": [0.0, 0.0]})
    visual_only = space.entity("visual", {"colour": [0.0, 1.0]})
    assert visual_only.domains == {"colour"}
    assert space.distance(full, visual_only) == pytest.approx(1.0)  # only colour is shared, weight 1
    with pytest.raises(ValueError, match="required domain 'motion' is missing on \\['visual'\\]"):
        space.distance(full, visual_only, ["colour", "motion"])
    shape_only = space.entity("shape", {"shape": [2.0]})
    with pytest.raises(ValueError, match="share no domain"):
        space.distance(visual_only, shape_only)


def test_prototypes_average_per_domain_with_their_support(space):
    e1 = space.entity("box1", {"colour": [0.0, 0.0], "motion": [1.0, 0.0]})
    e2 = space.entity("box2", {"colour": [2.0, 2.0]})
    e3 = space.entity("ball", {"colour": [10.0, 10.0], "motion": [0.0, 5.0]})
    protos = space.prototypes([e1, e2, e3], ["box", "box", "ball"])
    assert sorted(protos) == ["ball", "box"]
    box = protos["box"]
    assert np.allclose(box.points["colour"], [1.0, 1.0]) and np.allclose(box.points["motion"], [1.0, 0.0])
    assert box.support == {"colour": 2, "motion": 1}  # N_{l,delta} counts per domain (Eq. 4.26)
    probe = space.entity("probe", {"colour": [2.0, 1.0], "motion": [0.0, 4.0]})
    cat = space.categorize(probe, protos)
    assert cat.domains == ("colour", "motion")
    assert cat.label == "box" and cat.distances["box"] < cat.distances["ball"]
    # restricted to motion, the probe falls in the ball's Voronoi cell (Eq. 1.7)
    assert space.categorize(probe, protos, ["motion"]).label == "ball"
    tie = space.categorize(
        space.entity("mid", {"colour": [5.5, 5.5]}),
        {"b": Entity("b", {"colour": np.zeros(2)}), "a": Entity("a", {"colour": np.full(2, 11.0)})},
    )
    assert tie.label == "a"  # equal distances: the label that sorts first


def test_bad_spaces_and_points(space):
    with pytest.raises(ValueError, match="salience weights must be finite and > 0"):
        ConceptualSpace([Domain("d", ("x",))], salience={"d": 0.0})
    with pytest.raises(ValueError, match="exactly the domains"):
        ConceptualSpace([Domain("d", ("x",))], salience={"e": 1.0})
    with pytest.raises(ValueError, match="unique names"):
        ConceptualSpace([Domain("d", ("x",)), Domain("d", ("y",))])
    with pytest.raises(ValueError, match="weights"):
        Domain("d", ("x", "y"), weights=(1.0, -1.0))
    with pytest.raises(ValueError, match=r"shape \(3,\), expected \(2,\)"):
        space.entity("e", {"colour": [1.0, 2.0, 3.0]})
    with pytest.raises(ValueError, match="NaN"):
        space.entity("e", {"colour": [np.nan, 2.0]})
    with pytest.raises(ValueError, match="unknown domain 'taste'"):
        space.entity("e", {"taste": [1.0]})
    with pytest.raises(ValueError, match="at least one prototype"):
        space.categorize(space.entity("e", {"shape": [1.0]}), {})
