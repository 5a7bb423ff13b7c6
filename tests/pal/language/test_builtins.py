"""The built-in predicates against the perception grades they twin, and grounding errors.

near, on, left_of and touch (without a contact variable) are compared, within 1e-6, with
:func:`pal.perception.grounding.grade` on :class:`ObjectGeometry` boxes built from the same
position, radius (footprint half-width), height and sigma; reachable and moving with their
closed forms (module docstring of :mod:`pal.language.builtins`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from pal.language.builtins import builtin_predicates
from pal.language.predicates import (
    MissingVariableError,
    WindowError,
    conjunction,
    literal_grade,
    predicate,
)
from pal.language.signature import Constant, GroundingRangeError, LanguageError, Signature
from pal.language.terms import Literal, atom
from pal.language.world import Outcome
from pal.perception.grounding import GroundingConfig, ObjectGeometry, grade

CONFIG = GroundingConfig()
TOL = 1e-6


def phi(z: float) -> float:
    return 0.5 * math.erfc(-z / math.sqrt(2.0))


def _geometry(p: np.ndarray, radius: float, height: float, sigma: float) -> ObjectGeometry:
    return ObjectGeometry(
        position=p,
        lo=p[:2] - radius,
        hi=p[:2] + radius,
        bottom=float(p[2] - height / 2),
        top=float(p[2] + height / 2),
        sigma=sigma,
        surface=p[None, :],
    )


def _signature(ga: dict, gb: dict, **options) -> Signature:
    a = Constant("a", "object", {"position": "pa"}, ga)
    b = Constant("b", "object", {"position": "pb"}, gb)
    return Signature([a, b], builtin_predicates(**options))


def _grade(sig: Signature, name: str, values, *args: str, time: str = "end") -> torch.Tensor:
    return literal_grade(Literal(atom(name, *args), time=time), sig, values)


# (attributes of a, attributes of b): radius and height in m, sigma in m
GEOMETRIES = [
    ({"radius": 0.03, "height": 0.06, "sigma": 0.01}, {"radius": 0.05, "height": 0.04, "sigma": 0.02}),
    ({"radius": 0.0, "height": 0.0, "sigma": 0.01}, {"radius": 0.1, "height": 0.2, "sigma": 0.005}),
    ({"radius": 0.2, "height": 0.02, "sigma": 0.03}, {"radius": 0.02, "height": 0.3, "sigma": 0.01}),
]


def _positions(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Eight pairs: random ones, a stacked one (a on b) and a coincident one, (8, 3) m each."""
    rng = np.random.default_rng(seed)
    pa, pb = rng.uniform(-0.3, 0.3, (8, 3)), rng.uniform(-0.3, 0.3, (8, 3))
    pb[6] = pa[6] - np.array([0.01, 0.0, 0.05])
    pb[7] = pa[7]
    return pa, pb


@pytest.mark.parametrize(("ga", "gb"), GEOMETRIES)
def test_spatial_builtins_agree_with_the_perception_grades(ga, gb):
    sig = _signature(ga, gb)
    pa, pb = _positions(len(ga) + int(100 * ga["radius"]))
    values = {"pa": torch.as_tensor(pa), "pb": torch.as_tensor(pb)}
    got = {n: _grade(sig, n, values, "a", "b") for n in ("near", "on", "left_of", "touch")}
    for i in range(8):
        a = _geometry(pa[i], ga["radius"], ga["height"], ga["sigma"])
        b = _geometry(pb[i], gb["radius"], gb["height"], gb["sigma"])
        gap = max(0.0, float(np.linalg.norm(pa[i] - pb[i])) - ga["radius"] - gb["radius"])
        want = grade(a, b, CONFIG, gap=gap)
        for name, key in (("near", "near"), ("on", "on"), ("left_of", "left_of"), ("touch", "touching")):
            assert abs(float(got[name][i]) - want[key]) < TOL, (name, i, float(got[name][i]), want[key])
    for g in got.values():
        assert g.shape == (8,) and bool(((g >= 0) & (g <= 1)).all())
    # the cases chosen to give definite answers do
    assert float(got["near"][7]) > 0.9 and float(got["touch"][7]) == float(got["touch"].max()) > 0.7


def test_on_grades_a_stacked_pair():
    ga, gb = {"radius": 0.03, "height": 0.04, "sigma": 0.01}, {"radius": 0.05, "height": 0.06, "sigma": 0.01}
    sig = _signature(ga, gb)
    values = {"pa": torch.tensor([[0.0, 0.0, 0.05], [0.0, 0.0, -0.05]]), "pb": torch.zeros(2, 3)}
    got = _grade(sig, "on", values, "a", "b")
    a = _geometry(np.array([0.0, 0.0, 0.05]), 0.03, 0.04, 0.01)
    b = _geometry(np.zeros(3), 0.05, 0.06, 0.01)
    assert abs(float(got[0]) - grade(a, b, CONFIG, gap=0.0)["on"]) < TOL and float(got[0]) > 0.8
    assert float(got[1]) == 0.0  # a below b is not on it


def test_reachable_and_moving_have_their_closed_forms():
    hand = Constant("hand", "body_part", {"position": "ee"}, {"reach": 0.25, "base_x": 0.1, "sigma": 0.01})
    box = Constant("box", "object", {"position": "pos"}, {"radius": 0.03, "sigma": 0.02})
    sig = Signature([hand, box], builtin_predicates(moving_distance=0.005))
    po = torch.tensor([[0.1, 0.2, 0.0], [0.5, 0.0, 0.0], [0.1, 0.0, 0.27]], dtype=torch.float64)
    values = {"ee": torch.zeros(3, 3, dtype=torch.float64), "pos": po}
    got = _grade(sig, "reachable", values, "hand", "box")
    s = 0.25 * CONFIG.near_distance + math.hypot(0.01, 0.02)
    for i, p in enumerate(po.tolist()):
        dist = math.dist(p, [0.1, 0.0, 0.0])
        assert abs(float(got[i]) - phi((0.25 + 0.03 - dist) / s)) < TOL
    assert float(got[0]) > 0.95 and float(got[1]) < 0.01
    # moving: the last step's displacement against v0 = 5 mm
    steps = torch.tensor([0.0, 0.002, 0.005, 0.02], dtype=torch.float64)
    path = torch.zeros(4, 3, 3, dtype=torch.float64)  # (batch, T + 1 = 3, d)
    path[:, 2, 1] = steps
    path[:, 1, 0] = 0.3  # an earlier move outside the window does not count
    got = _grade(sig, "moving", {"pos": path}, "box")
    s = 0.25 * 0.005 + math.sqrt(2.0) * 0.02
    for i, d in enumerate(steps.tolist()):
        step = math.hypot(d, 0.3)  # from (0.3, 0, 0) to (0, d, 0)
        assert abs(float(got[i]) - phi((step - 0.005) / s)) < TOL
    path[:, 1, 0] = 0.0
    got = _grade(sig, "moving", {"pos": path}, "box")
    for i, d in enumerate(steps.tolist()):
        assert abs(float(got[i]) - phi((d - 0.005) / s)) < TOL
    assert float(got[0]) < 0.5 < float(got[3])


def test_touch_reads_a_contact_variable_when_bound():
    hand = Constant("hand", "body_part", {"position": "ee"})
    box = Constant("box", "object", {"position": "pos", "contact": "c"})
    c = torch.tensor([[-0.5], [0.0], [0.3], [1.0], [4.0]], dtype=torch.float64)
    values = {"c": c}  # the positions are not read
    plain = Signature([hand, box], builtin_predicates())
    got = _grade(plain, "touch", values, "hand", "box")
    torch.testing.assert_close(got, torch.tensor([0.0, 0.0, 0.3, 1.0, 1.0], dtype=torch.float64))
    assert plain.support(atom("touch", "hand", "box")) == ("c",)
    thresholded = Signature([hand, box], builtin_predicates(touch_threshold=0.5))
    got = _grade(thresholded, "touch", values, "box", "hand")  # the contact of either argument
    for i, v in enumerate(c[:, 0].tolist()):
        assert abs(float(got[i]) - phi((v - 0.5) / 0.25)) < TOL


def test_grades_stay_in_the_unit_interval_on_extreme_values():
    sig = _signature(*GEOMETRIES[0])
    rng = np.random.default_rng(1)
    values = {
        "pa": torch.as_tensor(rng.normal(0, 100, (64, 3))),
        "pb": torch.as_tensor(rng.normal(0, 1e-3, (64, 3))),
    }
    for name in ("near", "on", "left_of", "touch"):
        for args in (("a", "b"), ("b", "a"), ("a", "a")):
            g = _grade(sig, name, values, *args)
            assert bool(((g >= 0) & (g <= 1)).all()) and bool(torch.isfinite(g).all()), (name, args)


def test_builtin_options_and_geometry_errors():
    with pytest.raises(LanguageError, match="moving_distance must be > 0 m, got 0.0"):
        builtin_predicates(moving_distance=0.0)
    with pytest.raises(LanguageError, match="touch_threshold must be > 0 or None, got -1"):
        builtin_predicates(touch_threshold=-1)
    sig = _signature({}, {})
    flat = {"pa": torch.zeros(2, 2), "pb": torch.zeros(2, 2)}
    with pytest.raises(LanguageError, match=r"on\(a, b\) needs 3-D positions .*got dims 2 and 2"):
        _grade(sig, "on", flat, "a", "b")
    sig.add_constant(Constant("arm", "body_part", {"position": "pa"}))
    with pytest.raises(LanguageError, match="body_part 'arm' needs the attribute 'reach'"):
        _grade(sig, "reachable", flat, "arm", "b")


def _user_signature() -> Signature:
    box = Constant("box", "object", {"position": "z"}, {"level": 0.5})
    return Signature([box])


def test_a_user_predicate_works_end_to_end():
    sig = _user_signature()

    @predicate(sorts=("object",), support="position", signature=sig)
    def high(values, constants):
        """The object is above its level.

        More text that is not the listing line.
        """
        (o,) = constants
        return torch.special.ndtr((values[o.variable("position")][..., 0] - o.attributes["level"]) / 0.1)

    @predicate("rising", sorts=("object",), support=("position",), window=2, doc="it went up twice")
    def _rising(values, constants):
        path = values["z"][..., 0]  # (..., 3)
        return ((path[..., 1] > path[..., 0]) & (path[..., 2] > path[..., 1])).double()

    sig.add_predicate(_rising)
    assert sig.predicates["high"] is high and high.doc == "The object is above its level." and high.arity == 1
    assert _rising.name == "rising" and _rising.window == 2 and _rising.doc == "it went up twice"
    z = torch.tensor([[0.5], [0.6], [0.3]], dtype=torch.float64)
    g = literal_grade(Literal(atom("high", "box")), sig, {"z": z})
    torch.testing.assert_close(g, torch.tensor([0.5, phi(1.0), phi(-2.0)], dtype=torch.float64))
    g_not = literal_grade(Literal(atom("high", "box"), negated=True), sig, {"z": z})
    torch.testing.assert_close(g_not, 1 - g)
    # in an outcome (N = 2, S = 1, T + 1 = 3): start is index 0, end index -1, windows end there
    paths = torch.tensor([[0.0, 0.4, 0.9], [0.0, 0.6, 0.2]], dtype=torch.float64)[:, None, :, None]
    out = Outcome({"z": paths})
    start = literal_grade(Literal(atom("high", "box"), time="start"), sig, out)
    end = literal_grade(Literal(atom("high", "box")), sig, out)
    torch.testing.assert_close(start, torch.full((2, 1), phi(-5.0), dtype=torch.float64))
    torch.testing.assert_close(end, torch.tensor([[phi(4.0)], [phi(-3.0)]], dtype=torch.float64))
    rising = literal_grade(Literal(atom("rising", "box")), sig, out)
    torch.testing.assert_close(rising, torch.tensor([[1.0], [0.0]], dtype=torch.float64))
    both = conjunction([Literal(atom("high", "box")), Literal(atom("rising", "box"))], sig, out)
    torch.testing.assert_close(both, end * rising)
    assert conjunction([], sig, out) is None


@pytest.mark.parametrize(
    ("bad", "shown"),
    [
        (1.5, "returned 1.5 at index (1,)"),
        (-0.1, "returned -0.1 at index (1,)"),
        (float("nan"), "returned nan at index (1,)"),
        (float("inf"), "returned inf at index (1,)"),
        (1.0 + 1e-3, "returned 1.001 at index (1,)"),
    ],
)
def test_grounding_outside_the_unit_interval_or_nan_is_refused(bad, shown):
    sig = _user_signature()

    @predicate(sorts=("object",), support="position", signature=sig)
    def broken(values, constants):
        """Grade 0.5, but ``bad`` for the second sample."""
        g = torch.full(values["z"].shape[:-1], 0.5, dtype=torch.float64)
        g[1] = bad
        return g

    with pytest.raises(GroundingRangeError) as info:
        literal_grade(Literal(atom("broken", "box")), sig, {"z": torch.zeros(3, 1)})
    msg = str(info.value)
    assert "the grounding map of broken" in msg and shown in msg and "within [0, 1]" in msg, msg


def test_grounding_shape_and_type_errors_and_tolerance():
    sig = _user_signature()

    @predicate(sorts=("object",), support="position", signature=sig)
    def scalar(values, constants):
        """One grade for the whole batch."""
        return torch.tensor(0.5)

    @predicate(sorts=("object",), support="position", signature=sig)
    def word(values, constants):
        """Not a number."""
        return "yes"

    @predicate(sorts=("object",), support="position", signature=sig)
    def almost(values, constants):
        """Just above 1 and below 0, within the tolerance."""
        return torch.tensor([1.0 + 5e-7, -5e-7, 0.25], dtype=torch.float64)

    @predicate(sorts=("object",), support="position", signature=sig)
    def counts(values, constants):
        """Integer grades."""
        return torch.tensor([0, 1, 1])

    z = {"z": torch.zeros(3, 1)}
    with pytest.raises(
        GroundingRangeError, match=r"returned shape \(\), expected one grade per sample \(3,\)"
    ):
        literal_grade(Literal(atom("scalar", "box")), sig, z)
    with pytest.raises(GroundingRangeError, match="returned str, expected a tensor"):
        literal_grade(Literal(atom("word", "box")), sig, z)
    g = literal_grade(Literal(atom("almost", "box")), sig, z)
    assert g.tolist() == [1.0, 0.0, 0.25]
    g = literal_grade(Literal(atom("counts", "box")), sig, z)
    assert g.dtype == torch.float64 and g.tolist() == [0.0, 1.0, 1.0]
    with pytest.raises(LanguageError, match="window must be an int >= 0, got -1"):
        predicate(sorts=("object",), support="position", window=-1)
    with pytest.raises(LanguageError, match="window must be an int >= 0, got True"):
        predicate(sorts=("object",), support="position", window=True)


def test_a_window_longer_than_the_history_is_refused():
    sig = Signature([Constant("box", "object", {"position": "pos"})], builtin_predicates())
    moving = Literal(atom("moving", "box"))
    with pytest.raises(
        WindowError, match=r"moving needs a window of 1 steps, but the values of 'pos' hold a history of 0"
    ):
        literal_grade(moving, sig, {"pos": torch.zeros(4, 1, 2)})
    with pytest.raises(WindowError, match="history of 0 at start"):
        literal_grade(Literal(atom("moving", "box"), time="start"), sig, {"pos": torch.zeros(4, 3, 2)})
    no_steps = Outcome({"pos": torch.zeros(2, 1, 1, 2)})  # T = 0
    with pytest.raises(WindowError, match=r"the history at end has 0 \(the plan has 0 steps\)"):
        literal_grade(moving, sig, no_steps)
    two = Outcome({"pos": torch.zeros(2, 1, 3, 2)})
    with pytest.raises(WindowError, match="the history at start has 0"):
        literal_grade(Literal(atom("moving", "box"), time="start"), sig, two)
    assert literal_grade(moving, sig, two).shape == (2, 1)

    @predicate(sorts=("object",), support="position", window=3, signature=sig)
    def shaking(values, constants):
        """Reads four times."""
        return torch.zeros(values["pos"].shape[:-2], dtype=torch.float64)

    with pytest.raises(WindowError, match=r"shaking needs a window of 3 steps, but the history at end has 2"):
        literal_grade(Literal(atom("shaking", "box")), sig, two)
    assert literal_grade(
        Literal(atom("shaking", "box")), sig, Outcome({"pos": torch.zeros(2, 1, 4, 2)})
    ).shape == (2, 1)


def test_a_missing_variable_is_named():
    hand = Constant("hand", "body_part", {"position": "ee"})
    box = Constant("box", "object", {"position": "pos"})
    sig = Signature([hand, box], builtin_predicates())
    near = Literal(atom("near", "hand", "box"))
    with pytest.raises(
        MissingVariableError, match=r"near reads 'pos', which is not among the world's variables \['ee'\]"
    ):
        literal_grade(near, sig, {"ee": torch.zeros(2, 3)})
    out = Outcome({"ee": torch.zeros(2, 1, 2, 3), "pos": torch.zeros(2, 1, 2, 3)}, frozenset({"pos"}))
    with pytest.raises(
        MissingVariableError, match="'pos', which has no start value: give it in Situations.values"
    ):
        literal_grade(Literal(near.atom, time="start"), sig, out)
    assert literal_grade(near, sig, out).shape == (2, 1)  # at the end it is known
    with pytest.raises(MissingVariableError, match="no start value"):
        literal_grade(Literal(atom("moving", "box")), sig, out)  # a window reaching back to the start
    roles = Signature([hand])

    @predicate(sorts=("body_part",), support="contact", signature=roles)
    def pressed(values, constants):
        """Reads a contact the hand does not bind."""
        return torch.zeros(())

    with pytest.raises(
        LanguageError, match=r"support: body_part 'hand' has no 'contact' variable; it binds \['position'\]"
    ):
        roles.support(atom("pressed", "hand"))
