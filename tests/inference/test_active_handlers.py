"""Which handlers are active, read without Pyro's private stack (inference.active).

The fast paths of the queries bypass the Pyro program, so they run only when no handler at
all is active: a foreign handler (poutine.trace, poutine.condition, ...) or one of pal's sends
the query through the program. Oracle: the chain X -> Y -> Z, Y = 2X + U_y, Z = -1.5Y + U_z;
from X = 1, Y = 2.5, Z = -4 the exact counterfactual under do(X = 0) is Y' = 0.5, Z' = -1.5 Y' + U_z = -1.
"""

import importlib

import pytest
import torch
from pyro import poutine

from inference import (
    ActionOptions,
    Intervene,
    MeasurementScale,
    ReplayNoise,
    SamplingConfig,
    counterfactual,
    infer_action,
)
from inference.active import active_handlers, no_handler_active
from models import CausalGraph, LinearMechanism, Variable, WorldModel

# the modules, not the functions of the same names that the package exports
action_module = importlib.import_module("inference.action")
cf_module = importlib.import_module("inference.counterfactual")

FACTUAL = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-4.0]])}


@pytest.fixture
def paths(monkeypatch):
    """Record which counterfactual path ran: 'fast' (torch twin) or 'general' (the program)."""
    taken = []
    fast, general = cf_module._fast, cf_module._general

    def spy_fast(*args, **kwargs):
        taken.append("fast")
        return fast(*args, **kwargs)

    def spy_general(*args, **kwargs):
        taken.append("general")
        return general(*args, **kwargs)

    monkeypatch.setattr(cf_module, "_fast", spy_fast)
    monkeypatch.setattr(cf_module, "_general", spy_general)
    return taken


def _check(cf):
    torch.testing.assert_close(cf.samples["y"][0, 0], torch.tensor([[0.5]]), atol=1e-5, rtol=0)
    torch.testing.assert_close(cf.samples["z"][0, 0], torch.tensor([[-1.0]]), atol=1e-5, rtol=0)


def test_pal_handlers_register_while_active_and_leave_on_exit():
    assert active_handlers() == () and no_handler_active()
    outer, inner = Intervene({"x": 1.0}), MeasurementScale({"z": torch.ones(1)})
    with outer:
        assert active_handlers() == (outer,) and not no_handler_active()
        with inner:
            assert active_handlers() == (inner, outer)  # innermost first
        assert active_handlers() == (outer,)
    assert active_handlers() == () and no_handler_active()


def test_the_registry_is_cleared_when_the_block_raises():
    with pytest.raises(ZeroDivisionError), Intervene({"x": 1.0}), ReplayNoise({}, default="expected"):
        assert len(active_handlers()) == 2
        _ = 1 / 0
    assert active_handlers() == () and no_handler_active()


def test_a_foreign_handler_is_seen_through_the_public_api():
    with poutine.trace():
        assert active_handlers() == ()  # not pal's
        assert not no_handler_active()  # but a handler is active
    assert no_handler_active()


def test_no_handler_takes_the_fast_path(chain, paths):
    _check(counterfactual(chain, FACTUAL, {"x": 0.0}))
    assert paths == ["fast"]


def test_a_foreign_handler_takes_the_program_path(chain, paths):
    # a foreign handler acts on the program, which the torch twin would bypass; poutine.scale
    # changes no value, so the answer is the same
    with poutine.scale(scale=2.0):
        cf = counterfactual(chain, FACTUAL, {"x": 0.0})
    _check(cf)
    assert paths == ["general"]


def test_a_pal_handler_takes_the_program_path(chain, paths):
    with MeasurementScale({"z": torch.ones(1)}):  # sigma_z = 1 as in the model: same answer
        cf = counterfactual(chain, FACTUAL, {"x": 0.0})
    _check(cf)
    assert paths == ["general"]


def test_infer_action_plans_through_the_twin_only_without_handlers(monkeypatch):
    taken = []
    twin, program = action_module._through_twin, action_module._sampled_program
    monkeypatch.setattr(action_module, "_through_twin", lambda *a, **k: taken.append("twin") or twin(*a, **k))
    monkeypatch.setattr(
        action_module, "_sampled_program", lambda *a, **k: taken.append("program") or program(*a, **k)
    )
    # y = 1.5 a + 0.5 u_y, expected residual 0: a* = y* / 1.5
    graph = CausalGraph(
        [Variable("a", "action", bounds=(-2.0, 2.0)), Variable("y", "observed")], [("a", "y")]
    )
    model = WorldModel(graph, {"y": LinearMechanism.from_coefficients([[1.5]], 0.0, 0.5)})
    options = ActionOptions(sampling=SamplingConfig(population=64, elites=8))
    target = {"y": torch.tensor([[0.75], [-1.5]])}
    plain = infer_action(model, None, target, num_steps=50, options=options)
    with poutine.scale(scale=2.0):
        scaled = infer_action(model, None, target, num_steps=50, options=options)
    assert taken == ["twin", "program"]
    torch.testing.assert_close(plain.actions["a"], torch.tensor([[0.5], [-1.0]]), atol=1e-2, rtol=0)
    torch.testing.assert_close(scaled.actions["a"], plain.actions["a"], atol=1e-2, rtol=0)
    with poutine.scale(scale=2.0), pytest.raises(ValueError, match="torch twin of a plain WorldModel"):
        infer_action(model, None, target, options=ActionOptions(horizon=2))
