"""Rule schemas: licensed by graph paths (listed), refused naming the missing path, and checked
against a closed-form world.

The hand-built world is one-dimensional: the hand x(t+1) = x(t) + a(t) + u, u ~ N(0, 0.2²); two
boxes at fixed positions b_k (roots held at their start value) with contact strengths
c_k = 1 + x - b_k (+ 1e-4 noise), so touch(hand, k) = clamp(c_k, 0, 1). ``go(h, o)`` sets
a = b_o - x, ``stay(h)`` sets a = 0. With b_near = x0 + 0.5 and b_far = x0 + 3:

- do(go(hand, far)):  touch = clamp(1 + u, 0, 1), E = 1 - 0.2 / sqrt(2 pi) = 0.920;
- do(stay(hand)):     touch(hand, far) = clamp(-2 + u) = 0 always;
- do(stay(hand)):     touch(hand, near) = clamp(0.5 + u), E = 0.5 by symmetry.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from models.graph import CausalGraph
from models.mechanisms import LinearMechanism
from models.variables import Variable
from models.world import WorldModel
from pal.agent import build_graph, pushing_spec
from pal.language.actions import fixed_action_term
from pal.language.builtins import builtin_predicates
from pal.language.evaluate import Answer
from pal.language.rules import (
    Z_ONE_SIDED,
    RuleBook,
    UnlicensedRuleError,
    instantiate,
    license,
)
from pal.language.signature import Constant, LanguageError, Signature, UnknownPredicateError
from pal.language.syntax import parse_rule
from pal.language.terms import Literal, Rule, atom
from pal.language.vocabularies import pushing_signature
from pal.language.world import ModelWorld, Situations

SIGMA = 0.2
REACH_TOUCH = "reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) > 0.5"
GO_TOUCH = "reachable(h, o) and do(go(h, o)) => P(touch(h, o)) > 0.8"


def _graph(contact_parents=("x", "b_near"), far_parents=("x", "b_far")) -> CausalGraph:
    variables = [
        Variable("x_prev", "observed", lag=1, lag_of="x"),
        Variable("a", "action", bounds=(-5, 5)),
        Variable("b_near", "observed"),
        Variable("b_far", "observed"),
        Variable("x", "latent"),
        Variable("c_near", "latent"),
        Variable("c_far", "latent"),
    ]
    edges = [("x_prev", "x"), ("a", "x")]
    edges += [(p, "c_near") for p in contact_parents] + [(p, "c_far") for p in far_parents]
    return CausalGraph(variables, edges)


def _signature(ghost: bool = False) -> Signature:
    hand = Constant("hand", "body_part", {"position": "x"}, {"reach": 10.0})
    near = Constant("near_box", "object", {"position": "b_near", "contact": "c_near"})
    far = Constant("far_box", "object", {"position": "b_far", "contact": "c_far"})
    constants = [hand, near, far]
    if ghost:
        constants.append(Constant("ghost", "object", {"position": "g", "contact": "g_contact"}))

    def go(ctx, cs):
        h, o = cs
        v = ctx.situations.values
        return {"a": v[o.variable("position")] - v[h.variable("position")]}

    def stay(ctx, cs):
        return {"a": torch.zeros(ctx.situations.n, 1, dtype=torch.float64)}

    actions = [
        fixed_action_term("go", ("body_part", "object"), ("a",), go, aims=lambda cs: ("x",)),
        fixed_action_term("stay", ("body_part",), ("a",), stay),
    ]
    return Signature(constants, builtin_predicates(), actions)


def _model() -> WorldModel:
    mechanisms = {
        "x": LinearMechanism.from_coefficients([[1.0, 1.0]], 0.0, SIGMA),
        # parents in declaration order (b_k, x): c_k = 1 - b_k + x
        "c_near": LinearMechanism.from_coefficients([[-1.0, 1.0]], 1.0, 1e-4),
        "c_far": LinearMechanism.from_coefficients([[-1.0, 1.0]], 1.0, 1e-4),
    }
    graph = _graph()
    assert graph.parents("c_near") == ("b_near", "x") and graph.parents("x") == ("x_prev", "a")
    return WorldModel(graph, mechanisms).double()


def _situations(n: int = 8) -> Situations:
    x0 = torch.as_tensor(np.random.default_rng(0).uniform(-0.5, 0.5, (n, 1)))
    return Situations({"x": x0, "b_near": x0 + 0.5, "b_far": x0 + 3.0})


def test_pushing_graph_licenses_reach_touch_with_its_paths():
    sig = pushing_signature()
    graph = build_graph(pushing_spec(), (np.full(2, -1.0), np.full(2, 1.0)))
    book = RuleBook(sig, graph)
    lic = book.add(REACH_TOUCH, {"h": "hand", "o": "box"})
    assert lic.rule.action == atom("reach", "hand", "box")
    assert [(c.kind, c.term) for c in lic.connections] == [
        ("action", "reach(hand, box)"),
        ("premise", "reachable(hand, box)"),
        ("premise", "reachable(hand, box)"),
    ]
    assert lic.paths == [
        ["act", "dq", "dee", "ee", "rel.box", "contact.box"],  # the action moves the contact
        ["ee", "rel.box", "contact.box"],  # the distance feeds it
        ["pos.box", "pos_prev.box", "rel.box", "contact.box"],  # via the carry to the next step
    ]
    for path in lic.paths:  # every step is a mechanism of the graph or a lag carry
        for u, v in itertools.pairwise(path):
            assert (u, v) in graph.edges or graph.lagged.get(v) == u, (u, v)
    assert book.list() == (lic,)
    assert book.to_dict()["rules"][0]["connections"][0]["path"][-1] == "contact.box"
    assert book.to_dict()["rules"][0]["kappa"] == 0.5


def test_pushing_graph_without_the_contact_mechanism_refuses_the_rule():
    sig = pushing_signature()
    graph = build_graph(pushing_spec(), (np.full(2, -1.0), np.full(2, 1.0)), parents={"contact.box": ()})
    book = RuleBook(sig, graph)
    with pytest.raises(UnlicensedRuleError) as info:
        book.add(REACH_TOUCH, {"h": "hand", "o": "box"})
    msg = str(info.value)
    assert "no directed path from action 'act' to 'contact.box'" in msg
    assert "support of touch(hand, box)" in msg and "\n" not in msg
    assert book.list() == ()  # refused rules are not kept
    # the ball still has its contact mechanism: the same schema is licensed for it
    assert book.add(REACH_TOUCH, {"h": "hand", "o": "ball"}).paths[0][-1] == "contact.ball"
    assert len(book.list()) == 1


def test_hand_built_graph_licenses_with_the_expected_paths():
    lic = license(instantiate(parse_rule(GO_TOUCH), {"h": "hand", "o": "near_box"}), _signature(), _graph())
    assert lic.paths == [["a", "x", "c_near"], ["x", "c_near"], ["b_near", "c_near"]]
    assert lic.to_dict()["rule"].startswith("reachable(hand, near_box)@start and do(go(hand, near_box))")


@pytest.mark.parametrize(
    ("contact_parents", "missing"),
    [
        (("b_near",), "no directed path from action 'a' to 'c_near' (support of touch(hand, near_box))"),
        (
            ("x",),
            "no directed path from 'b_near' (support of reachable(hand, near_box)) to any of ['c_near']",
        ),
    ],
)
def test_a_missing_mechanism_is_named(contact_parents, missing):
    rule = instantiate(parse_rule(GO_TOUCH), {"h": "hand", "o": "near_box"})
    with pytest.raises(UnlicensedRuleError, match="is not licensed") as info:
        license(rule, _signature(), _graph(contact_parents=contact_parents))
    assert missing in str(info.value)


def test_other_refusals_and_bad_rules():
    sig, graph = _signature(ghost=True), _graph()
    book = RuleBook(sig, graph)
    with pytest.raises(
        UnlicensedRuleError, match="variable 'g_contact' .support of touch.hand, ghost.. is not in the graph"
    ):
        book.add("do(go(h, o)) => P(touch(h, o)) > 0.5", {"h": "hand", "o": "ghost"})
    at_start = Rule((), atom("stay", "hand"), Literal(atom("touch", "hand", "near_box"), time="start"), 0.5)
    with pytest.raises(UnlicensedRuleError, match="must be read at end"):
        license(at_start, sig, graph)
    with pytest.raises(ValueError, match="kappa must be a number in"):
        Rule((), atom("stay", "hand"), Literal(atom("touch", "hand", "near_box")), 1.0)
    with pytest.raises(LanguageError, match="variable 'o' of touch\\(hand, o\\) at position 17 is unbound"):
        book.add("do(stay(h)) => P(touch(h, o)) > 0.5", {"h": "hand"})
    with pytest.raises(LanguageError, match="binding 'x' names no argument"):
        instantiate(parse_rule(GO_TOUCH), {"x": "hand"})
    with pytest.raises(LanguageError, match="is not a constant name"):
        instantiate(parse_rule(GO_TOUCH), {"h": "the hand"})
    with pytest.raises(UnknownPredicateError, match="tuch"):
        book.add("do(stay(h)) => P(tuch(h, o)) > 0.5", {"h": "hand", "o": "near_box"})
    with pytest.raises(TypeError, match="signature must be a Signature"):
        RuleBook({}, graph)  # type: ignore[arg-type]
    assert book.list() == ()


def test_check_against_the_closed_form_world():
    sig, model = _signature(), _model()
    book = RuleBook(sig, model.graph)
    book.add(GO_TOUCH, {"h": "hand", "o": "far_box"})
    book.add("reachable(h, o) and do(stay(h)) => P(touch(h, o)) > 0.5", {"h": "hand", "o": "far_box"})
    book.add("reachable(h, o) and do(stay(h)) => P(touch(h, o)) > 0.5", {"h": "hand", "o": "near_box"})
    checks = book.check(ModelWorld(model), _situations(), samples=200, seed=0)
    assert [c.verdict for c in checks] == ["holds", "violated", "undecided"]
    go, never, even = checks
    assert abs(go.p - (1 - SIGMA / math.sqrt(2 * math.pi))) < 4 * go.se and go.se < 0.01
    assert never.p == 0.0 and never.se == 0.0
    assert abs(even.p - 0.5) < Z_ONE_SIDED * even.se and 0.0 < even.se < 0.02
    lo, hi = even.interval
    assert lo < 0.5 < hi and hi - lo == pytest.approx(2 * Z_ONE_SIDED * even.se)
    assert checks[0].to_dict()["verdict"] == "holds" and checks[0].to_dict()["kappa"] == 0.8


@pytest.mark.parametrize(
    ("p", "se", "kappa", "verdict"),
    [
        (0.6, 0.05, 0.5, "holds"),  # 0.6 - 0.08225 = 0.518 > 0.5
        (0.6, 0.05, 0.55, "undecided"),
        (0.6, 0.05, 0.7, "violated"),  # 0.6 + 0.08225 = 0.682 < 0.7
        (0.6, 0.0, 0.6, "undecided"),  # equality is neither
        (0.0, 0.0, 0.0, "undecided"),
    ],
)
def test_verdict_thresholds(p, se, kappa, verdict):
    book = RuleBook(_signature(), _graph())
    book.add(instantiate(parse_rule(GO_TOUCH.replace("0.8", repr(kappa))), {"h": "hand", "o": "near_box"}))
    assert book.list()[0].rule.kappa == kappa
    seen = []

    def evaluator(query, signature, world, situations, **options):
        seen.append((str(query), options))
        return Answer(p, se, 4, 1, 4.0)

    (check,) = book.check(None, None, evaluate=evaluator, samples=3)
    assert check.verdict == verdict and check.p == p and check.se == se
    assert seen == [
        (
            "P(touch(hand, near_box)@end | do(go(hand, near_box)), reachable(hand, near_box)@start)",
            {"samples": 3},
        )
    ]


def test_check_refuses_a_non_finite_answer():
    book = RuleBook(_signature(), _graph())
    book.add(GO_TOUCH, {"h": "hand", "o": "near_box"})
    with pytest.raises(ValueError, match="p=nan"):
        book.check(None, None, evaluate=lambda *a, **k: Answer(float("nan"), 0.1, 1, 1, 1.0))
    with pytest.raises(ValueError, match="se=nan"):
        book.check(None, None, evaluate=lambda *a, **k: Answer(0.5, float("nan"), 1, 1, 1.0))
