"""Query answers against closed forms on x(t+1) = x(t) + a(t) + u(t), u ~ N(0, 0.5²).

With x0 = 0 and do(push) = a 0.5 for one step, x1 ~ N(0.5, 0.25), so
P(high) = P(x1 > 0.8) = 1 - Phi(0.6); the counterfactual "had it stayed" (a = 0) given that
it ended high is P(u > 0.8 | u > 0.3) = (1 - Phi(1.6)) / (1 - Phi(0.6)).
"""

import math

import pytest
import torch

from models.graph import CausalGraph
from models.mechanisms import LinearMechanism
from models.variables import Variable
from models.world import WorldModel
from pal.language.actions import fixed_action_term
from pal.language.evaluate import Answer, EvidenceError, answer, compile_plans, evaluate
from pal.language.predicates import predicate
from pal.language.signature import Constant, GroundingRangeError, NotAnActionError, Signature
from pal.language.terms import Literal, Query, atom
from pal.language.world import ModelWorld, Situations

SIGMA = 0.5


def phi(z: float) -> float:
    return 0.5 * math.erfc(-z / math.sqrt(2.0))


def _setup():
    g = CausalGraph(
        [
            Variable("x_prev", "observed", lag=1, lag_of="x"),
            Variable("a", "action", bounds=(-2, 2)),
            Variable("x", "latent"),
        ],
        [("x_prev", "x"), ("a", "x")],
    )
    model = WorldModel(g, {"x": LinearMechanism.from_coefficients([[1.0, 1.0]], 0.0, SIGMA)}).double()
    sig = Signature([Constant("hand", "body_part", {"position": "x", "command": "a"})])

    @predicate(sorts=("body_part",), support="position", signature=sig)
    def high(values, constants):
        """The hand is past 0.8 m."""
        return (values[constants[0].variable("position")][..., 0] > 0.8).double()

    @predicate(sorts=("body_part",), support="position", signature=sig)
    def low(values, constants):
        """The hand is before 0.5 m."""
        return (values[constants[0].variable("position")][..., 0] < 0.5).double()

    def constant(value):
        return lambda ctx, cs: {"a": torch.full((ctx.situations.n, 1), value, dtype=torch.float64)}

    sig.add_action(fixed_action_term("push", ("body_part",), ("a",), constant(0.5)))
    sig.add_action(fixed_action_term("stay", ("body_part",), ("a",), constant(0.0)))
    return model, sig


def _situations(x0):
    return Situations({"x": torch.tensor(x0, dtype=torch.float64)[:, None]})


def test_interventional_probability_and_its_standard_error_match_the_closed_form():
    model, sig = _setup()
    q = Query((Literal(atom("high", "hand")),), (), (atom("push", "hand"),))
    ans = evaluate(q, sig, ModelWorld(model), _situations([0.0] * 8), samples=1000, seed=0)
    truth = 1 - phi(0.6)
    binomial = math.sqrt(truth * (1 - truth) / 8000)
    assert isinstance(ans, Answer) and ans.n_situations == 8 and ans.samples == 1000
    assert abs(ans.p - truth) < 4 * binomial
    assert 0.5 * binomial < ans.se < 2.0 * binomial
    assert ans.interval[0] < truth < ans.interval[1]
    assert ans.to_dict()["p"] == ans.p


def test_evidence_selects_the_situations_it_holds_in():
    model, sig = _setup()
    # half the situations start at 1.0, where low@start is false; the answer is that of x0 = 0
    q = Query(
        (Literal(atom("high", "hand")),),
        (Literal(atom("low", "hand"), time="start"),),
        (atom("push", "hand"),),
    )
    ans = evaluate(q, sig, ModelWorld(model), _situations([0.0, 1.0] * 4), samples=1000, seed=1)
    assert abs(ans.p - (1 - phi(0.6))) < 4 * math.sqrt(0.2 / 4000)
    assert ans.ess == pytest.approx(4000, rel=1e-9)


def test_counterfactual_shares_the_noise_of_the_factual_world():
    model, sig = _setup()
    q = Query(
        (Literal(atom("high", "hand")),),
        (Literal(atom("high", "hand"), time="end"),),
        (atom("push", "hand"),),
        (atom("stay", "hand"),),
    )
    ans = evaluate(q, sig, ModelWorld(model), _situations([0.0] * 8), samples=2000, seed=2)
    truth = (1 - phi(1.6)) / (1 - phi(0.6))
    assert abs(ans.p - truth) < 4 * ans.se and ans.se < 0.02
    # the interventional answer under do(stay) alone is different: P(u > 0.8)
    plain = evaluate(
        Query((Literal(atom("high", "hand")),), (), (atom("stay", "hand"),)),
        sig,
        ModelWorld(model),
        _situations([0.0] * 8),
        samples=2000,
        seed=2,
    )
    assert abs(plain.p - (1 - phi(1.6))) < 4 * plain.se


def test_the_same_plans_answer_in_another_world():
    model, sig = _setup()
    q = Query((Literal(atom("high", "hand")),), (), (atom("push", "hand"),))
    sit = _situations([0.0] * 4)
    from pal.language.actions import CompileContext

    plans = compile_plans(q, sig, CompileContext(model, sit, torch.Generator().manual_seed(0)))
    assert plans[0].shape == (4, 1, 1) and torch.all(plans[0] == 0.5)
    noiseless = WorldModel(
        model.graph, {"x": LinearMechanism.from_coefficients([[1.0, 1.0]], 0.0, 1e-9)}
    ).double()
    ans = answer(q, sig, ModelWorld(noiseless), sit, plans, samples=3)
    assert ans.p == 0.0  # x1 = 0.5 < 0.8 everywhere


def test_bad_queries_and_grounding_maps_get_their_errors():
    model, sig = _setup()
    world, sit = ModelWorld(model), _situations([0.0] * 4)
    never = Query(
        (Literal(atom("high", "hand")),),
        (Literal(atom("high", "hand"), time="start"),),
        (atom("push", "hand"),),
    )
    with pytest.raises(EvidenceError, match="almost"):
        evaluate(never, sig, world, sit, samples=10)
    with pytest.raises(NotAnActionError, match="do\\(high"):
        evaluate(Query((Literal(atom("high", "hand")),), (), (atom("high", "hand"),)), sig, world, sit)

    @predicate(sorts=("body_part",), support="position", signature=sig)
    def broken(values, constants):
        """Returns 1.5."""
        return torch.full(values["x"].shape[:-1], 1.5, dtype=torch.float64)

    with pytest.raises(GroundingRangeError, match="broken"):
        evaluate(
            Query((Literal(atom("broken", "hand")),), (), (atom("push", "hand"),)), sig, world, sit, samples=2
        )
