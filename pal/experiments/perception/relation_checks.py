"""Relations on real frames checked without labels: far pairs are not near, hidden bottoms do not rest.

Real frames carry no relation labels, but two failures can be read off the geometry alone:

- ``near`` of a pair whose 3-D boxes (footprint box and height span in the support-plane frame)
  are more than ``FAR_GAP`` apart should be about 0 (``near`` is graded by that metric gap with
  the scale ``GroundingConfig.near_distance``, 0.1 m; a wall-sized segment is not near
  everything): ``near_far_max`` is its largest value over such pairs;
- ``on_support`` of an object whose bottom is mostly hidden (``bottom_visible`` below
  ``HIDDEN``, e.g. a chair's legs behind a table edge) should be about 0: ``on_support_hidden_max``.

``on_max`` is the largest ``on`` over ordered pairs with its pair of ids, for information (no
stacked pair of the samples is known).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

from pal.perception.grounding import ObjectGeometry, box_gap
from pal.perception.state import PerceptionState

__all__ = ["FAR_GAP", "HIDDEN", "merge_relation_checks", "relation_checks"]

#: Pairs whose 3-D boxes are farther apart than this are far, metres (3 x ``near_distance``).
FAR_GAP = 0.3
#: Objects with less than this share of their bottom visible have a hidden bottom.
HIDDEN = 0.5


def _gap3d(a: ObjectGeometry, b: ObjectGeometry) -> float:
    """Distance between the two 3-D boxes (footprint box and height span), metres."""
    vertical = max(0.0, a.bottom - b.top, b.bottom - a.top)
    return math.hypot(box_gap(a, b), vertical)


def relation_checks(states: Sequence[PerceptionState]) -> dict[str, Any]:
    """The label-free relation checks (module docstring) over the frames' relation layers."""
    far, hidden, near_far, rest_hidden = 0, 0, [], []
    on_best: tuple[float, int, int, int] | None = None
    for k, state in enumerate(states):
        rel = state.relations
        if rel is None:
            continue
        geo = {i: g for i, g in rel.geometry.items() if g is not None}
        for a, b in itertools.permutations(geo, 2):
            on = rel.grade("on", a, b)
            if on is not None and (on_best is None or on > on_best[0]):
                on_best = (on, k, a, b)
            if _gap3d(geo[a], geo[b]) > FAR_GAP:
                far += 1
                near_far.append(rel.grade("near", a, b))
        for i, g in geo.items():
            if g.bottom_visible < HIDDEN:
                hidden += 1
                rest_hidden.append(rel.on_support.get(i, 0.0))
    return {
        "far_pairs": far,
        "near_far_max": max(near_far, default=None),
        "hidden_bottoms": hidden,
        "on_support_hidden_max": max(rest_hidden, default=None),
        "on_max": None
        if on_best is None
        else {"grade": on_best[0], "frame": on_best[1], "pair": on_best[2:]},
    }


def merge_relation_checks(checks: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The checks of several samples as one: counts summed, maxima over all."""

    def largest(key: str) -> float | None:
        values = [c[key] for c in checks if c[key] is not None]
        return max(values, default=None)

    ons = [c["on_max"] for c in checks if c["on_max"] is not None]
    return {
        "far_pairs": sum(c["far_pairs"] for c in checks),
        "near_far_max": largest("near_far_max"),
        "hidden_bottoms": sum(c["hidden_bottoms"] for c in checks),
        "on_support_hidden_max": largest("on_support_hidden_max"),
        "on_max": max(ons, key=lambda o: o["grade"], default=None),
    }
