"""Compiling action terms: fixed terms give exactly their plan; inferred terms reach the analytic
optimum of a closed-form linear model; bad inputs get their specific errors.

The linear model: x(t+1) = x(t) + M a(t) (+ 1e-3 noise), x and a in R², a in [-1, 1]², the box
at b (a root held at its start value). ``reach(hand, box)`` targets x(T) = b, so with one step
a* = M^-1 (b - x0), and with T steps the actions sum to it. With a diagonal M and a target out
of reach the optimum of the separable quadratic is a* clipped to the bounds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inference import SamplingConfig
from models.graph import CausalGraph
from models.mechanisms import LinearMechanism
from models.variables import Variable
from models.world import WorldModel
from pal.language.actions import CompileContext, fixed_action_term, inferred_action_term, model_state
from pal.language.builtins import builtin_predicates
from pal.language.evaluate import compile_plans, evaluate
from pal.language.signature import ActionTermDef, Constant, LanguageError, NotAnActionError, Signature
from pal.language.syntax import parse_query
from pal.language.terms import Literal, Query, atom
from pal.language.vocabularies import pusher_signature, pushing_signature
from pal.language.world import ModelWorld, Situations

M = torch.tensor([[1.0, 0.5], [-0.3, 0.8]], dtype=torch.float64)
#: A sampling stage refined long enough to converge on the quadratic.
PRECISE = SamplingConfig(population=64, elites=8, iterations=3, refine_steps=200)


def _model(m: torch.Tensor = M) -> WorldModel:
    graph = CausalGraph(
        [
            Variable("x_prev", "observed", 2, lag=1, lag_of="x"),
            Variable("a", "action", 2, bounds=((-1.0, -1.0), (1.0, 1.0))),
            Variable("b", "observed", 2),
            Variable("x", "latent", 2),
        ],
        [("x_prev", "x"), ("a", "x")],
    )
    assert graph.parents("x") == ("x_prev", "a")
    weight = torch.cat([torch.eye(2, dtype=torch.float64), m], 1)
    return WorldModel(graph, {"x": LinearMechanism.from_coefficients(weight, 0.0, 1e-3)}).double()


def _target(ctx, constants):
    h, o = constants
    return {h.variable("position"): ctx.situations.values[o.variable("position")]}


def _signature(**options) -> Signature:
    hand = Constant("hand", "body_part", {"position": "x", "joints": "x"})
    box = Constant("box", "object", {"position": "b"})
    reach = inferred_action_term(
        "reach", ("body_part", "object"), ("a",), lambda cs: ("x",), _target, **options
    )
    return Signature([hand, box], builtin_predicates(), [reach])


def _situations(n: int = 6, spread: float = 0.4, seed: int = 0) -> Situations:
    rng = np.random.default_rng(seed)
    x0 = torch.as_tensor(rng.uniform(-0.5, 0.5, (n, 2)))
    return Situations({"x": x0, "b": x0 + torch.as_tensor(rng.uniform(-spread, spread, (n, 2)))})


def _compile(sig: Signature, name: str, args: tuple[str, ...], ctx: CompileContext) -> torch.Tensor:
    term, constants = sig.action(atom(name, *args))
    return term.compile(ctx, constants)


def _analytic(sit: Situations, m: torch.Tensor = M) -> torch.Tensor:
    v = sit.values
    return torch.linalg.solve(m, (v["b"] - v["x"]).T).T


def test_fixed_hold_gives_exactly_the_start_targets():
    q = torch.tensor([[0.1, -0.2], [0.3, 0.4], [-1.0, 0.5]], dtype=torch.float64)
    sit = Situations({"q": q, "ee": torch.zeros(3, 3, dtype=torch.float64)})
    sig = pushing_signature()
    ctx = CompileContext(None, sit, torch.Generator().manual_seed(0), horizon=4, layout=(("act", 2),))
    plan = _compile(sig, "hold", ("hand",), ctx)
    assert plan.shape == (3, 4, 2) and plan.dtype == torch.float64
    assert torch.equal(plan, q[:, None, :].expand(3, 4, 2))
    assert ctx.evaluations == {"hold(hand)": 0.0}
    # Pusher-v5 is torque driven: holding is zero torque
    psig = pusher_signature()
    sit7 = Situations({"q": torch.ones(2, 7, dtype=torch.float64)})
    ctx7 = CompileContext(None, sit7, torch.Generator(), horizon=3, layout=(("act", 7),))
    assert torch.equal(
        _compile(psig, "hold", ("fingertip",), ctx7), torch.zeros(2, 3, 7, dtype=torch.float64)
    )
    # through compile_plans, a query's do-terms concatenate in time
    query = parse_query("P(near(hand, box) | do(hold(hand)), do(hold(hand)))", sig)
    (plans,) = compile_plans(query, sig, ctx)
    assert torch.equal(plans, q[:, None, :].expand(3, 8, 2))


def test_a_fixed_term_holds_the_actions_it_does_not_set():
    sit = Situations({"u": torch.tensor([[2.0], [3.0]]), "w": torch.tensor([[0.5, 0.5], [1.0, 1.0]])})
    term = fixed_action_term("nudge", ("body_part",), ("u",), lambda ctx, cs: {"u": torch.ones(2, 3, 1)})
    hand = Constant("hand", "body_part")
    ctx = CompileContext(None, sit, torch.Generator(), horizon=3, layout=(("u", 1), ("w", 2)))
    plan = term.compile(ctx, (hand,))
    assert plan.shape == (2, 3, 3)
    assert torch.equal(plan[..., 0], torch.ones(2, 3, dtype=torch.float64))
    assert torch.equal(
        plan[..., 1:], torch.tensor([[0.5, 0.5], [1.0, 1.0]], dtype=torch.float64)[:, None].expand(2, 3, 2)
    )


def test_inferred_reach_meets_the_analytic_optimum():
    model, sit = _model(), _situations()
    astar = _analytic(sit)
    assert float(astar.abs().max()) < 1.0  # inside the bounds
    sig = _signature(sampling=PRECISE)
    for horizon in (1, 2):
        ctx = CompileContext(model, sit, torch.Generator().manual_seed(0), horizon=horizon)
        plan = _compile(sig, "reach", ("hand", "box"), ctx)
        assert plan.shape == (6, horizon, 2)
        # one step: the actions themselves; more: their sum (x(T) = x0 + M sum_t a(t))
        assert float((plan.sum(1) - astar).abs().max()) < 1e-4, horizon
        assert bool((plan.abs() <= 1.0).all())
        assert ctx.evaluations["reach(hand, box)"] > 200  # at least the refinement's steps
    # the vocabularies' default search (3 CEM rounds, 20 Adam steps) is within 3 cm
    ctx = CompileContext(model, sit, torch.Generator().manual_seed(0))
    plan = _compile(_signature(), "reach", ("hand", "box"), ctx)
    assert float((plan[:, 0] - astar).abs().max()) < 0.03


def test_inferred_reach_out_of_bounds_clips_to_the_constrained_optimum():
    m = torch.diag(torch.tensor([1.0, 0.5], dtype=torch.float64))
    x0 = torch.zeros(3, 2, dtype=torch.float64)
    b = torch.tensor([[1.5, -0.2], [-2.0, 0.3], [0.2, 0.8]], dtype=torch.float64)
    sit = Situations({"x": x0, "b": b})
    expected = torch.tensor([[1.0, -0.4], [-1.0, 0.6], [0.2, 1.0]], dtype=torch.float64)
    ctx = CompileContext(_model(m), sit, torch.Generator().manual_seed(1))
    plan = _compile(_signature(sampling=PRECISE), "reach", ("hand", "box"), ctx)
    torch.testing.assert_close(plan[:, 0], expected, rtol=0, atol=1e-4)


def test_a_reach_query_is_answered_end_to_end():
    model, sit = _model(), _situations()
    sig = _signature(sampling=PRECISE)
    answer = evaluate(
        "P(near(hand, box) | do(reach(hand, box)))", sig, ModelWorld(model), sit, model=model, samples=8
    )
    # at the box: gap ~ 0 (noise 1e-3), near = Phi(0.1 / (0.025 + sqrt(2) 0.01))
    truth = 0.5 * math.erfc(-(0.1 / (0.025 + math.sqrt(2) * 0.01)) / math.sqrt(2))
    assert abs(answer.p - truth) < 1e-3 and answer.evaluations["reach(hand, box)"] > 200


def test_a_do_on_a_predicate_is_not_an_action():
    sig = _signature()
    ctx = CompileContext(_model(), _situations(), torch.Generator())
    with pytest.raises(
        NotAnActionError, match=r"do\(near\(hand, box\)\) at position 0: 'near' is a predicate"
    ):
        sig.action(atom("near", "hand", "box"))
    query = Query((Literal(atom("near", "hand", "box")),), (), (atom("near", "hand", "box"),))
    with pytest.raises(NotAnActionError, match="'near' is a predicate; the action terms are \\['reach'\\]"):
        compile_plans(query, sig, ctx)
    with pytest.raises(NotAnActionError, match="at position 23"):
        parse_query("P(near(hand, box) | do(near(hand, box)))", sig)
    sig.add_action(ActionTermDef("wave", ("body_part",), lambda cs: ("a",)))
    with pytest.raises(LanguageError, match="action term 'wave' has no compile function bound"):
        compile_plans(Query((Literal(atom("near", "hand", "box")),), (), (atom("wave", "hand"),)), sig, ctx)


def test_compile_context_refuses_bad_inputs():
    model, sit = _model(), _situations(3)
    gen = torch.Generator()
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(LanguageError, match=f"horizon must be an int >= 1 steps, got {bad!r}"):
            CompileContext(model, sit, gen, horizon=bad)  # type: ignore[arg-type]
    with pytest.raises(LanguageError, match="needs a model or a layout"):
        CompileContext(None, sit, gen)
    ctx = CompileContext(model, sit, gen, horizon=2)
    assert ctx.layout == (("a", 2),) and ctx.dtype == torch.float64
    with pytest.raises(
        LanguageError, match=r"do\(t\) sets \['zz'\], which are not action variables; they are \['a'\]"
    ):
        ctx.assemble({"zz": torch.zeros(3, 2)}, "do(t)")
    with pytest.raises(
        LanguageError, match=r"action 'a' has shape \(3, 5, 2\), expected \(3, 2, 2\) or \(3, 2\)"
    ):
        ctx.assemble({"a": torch.zeros(3, 5, 2)}, "do(t)")
    with pytest.raises(
        LanguageError, match="does not set the action 'a' and the situations give no start value"
    ):
        ctx.assemble({}, "do(t)")
    assert ctx.assemble({"a": torch.ones(3, 2)}, "do(t)").shape == (3, 2, 2)
    bare = CompileContext(None, sit, gen, layout=(("a", 2),))
    with pytest.raises(
        LanguageError, match=r"do\(reach\(hand, box\)\) infers actions with the world model; pass model="
    ):
        _compile(_signature(), "reach", ("hand", "box"), bare)


def test_action_terms_refuse_what_they_do_not_declare():
    model, sit = _model(), _situations(3)
    hand = Constant("hand", "body_part", {"position": "x"})
    box = Constant("box", "object", {"position": "b"})
    ctx = CompileContext(model, sit, torch.Generator())
    sneaky = fixed_action_term(
        "sneak", ("body_part",), ("a",), lambda c, cs: {"a": torch.zeros(3, 2), "b": torch.zeros(3, 2)}
    )
    with pytest.raises(
        LanguageError, match=r"do\(sneak\(hand\)\) returned values for \['b'\], which it does not declare"
    ):
        sneaky.compile(ctx, (hand,))
    wrong = inferred_action_term("steer", ("body_part", "object"), ("x",), lambda cs: ("x",), _target)
    with pytest.raises(
        LanguageError, match=r"do\(steer\(hand, box\)\) optimises \['x'\], which are not action variables"
    ):
        wrong.compile(ctx, (hand, box))
    with pytest.raises(LanguageError, match="planning needs the start value of 'x' \\(for 'x_prev'\\)"):
        model_state(model, Situations({"b": torch.zeros(3, 2)}), ["a"])
    state = model_state(model, sit, ["a"])
    assert set(state) == {"x_prev", "b"} and torch.equal(state["x_prev"], sit.values["x"])
