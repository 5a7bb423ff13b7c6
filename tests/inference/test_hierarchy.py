"""The hierarchy (Eq. 6.3): nested top-down queries on an analytic example, bottom-up evidence, contextualisation."""

import pytest
import torch

from inference import ActionOptions
from inference.hierarchy import Hierarchy, Layer, LevelQuery
from inference.hierarchy_count import count_evaluations
from models import (
    BernoulliMechanism,
    CausalGraph,
    EnsembleMechanism,
    GatedMechanism,
    LinearMechanism,
    Variable,
    WorldModel,
)
from models.abstraction import Abstraction, ContactOnset, Displacement, WindowError

GAIN = 2.0  # body: q = q_prev + GAIN * act


def _lin(*w: float) -> LinearMechanism:
    return LinearMechanism.from_coefficients([list(w)], sigma=1e-3)


def _layers(objects: tuple[str, ...] = ("box",)) -> tuple[Layer, Layer, Layer]:
    body_g = CausalGraph(
        [
            Variable("act", "action", 1, bounds=(-2, 2)),
            Variable("q_prev", "observed", 1, lag=1, lag_of="q"),
            Variable("q", "latent", 1),
            Variable("touch", "observed", 1),
        ],
        [("q_prev", "q"), ("act", "q")],
    )
    body = WorldModel(body_g, {"q": _lin(GAIN, 1.0)})  # parents in declaration order: act, q_prev
    event_g = CausalGraph(
        [Variable(f"extent.{o}", "observed", 1) for o in objects] + [Variable("onset", "observed", 1)]
    )
    events = [
        Abstraction(f"extent.{o}", ("q",), 2, Displacement("q"), Variable(f"extent.{o}", "observed", 1))
        for o in objects
    ]
    events.append(
        Abstraction("onset", ("touch",), 2, ContactOnset("touch"), Variable("onset", "observed", 1))
    )
    variables, edges, mechs = [], [], {}
    for o in objects:
        variables += [
            Variable(f"extent.{o}", "action", 1, bounds=(-1, 1)),
            Variable(f"pos_prev.{o}", "observed", 1, lag=1, lag_of=f"pos.{o}"),
            Variable(f"dpos.{o}", "latent", 1),
            Variable(f"pos.{o}", "latent", 1),
        ]
        edges += [(f"extent.{o}", f"dpos.{o}"), (f"pos_prev.{o}", f"pos.{o}"), (f"dpos.{o}", f"pos.{o}")]
        mechs |= {f"dpos.{o}": _lin(1.0), f"pos.{o}": _lin(1.0, 1.0)}
    obj = WorldModel(CausalGraph(variables, edges), mechs)
    moved = [
        Abstraction(
            f"dpos.{o}", (f"pos.{o}",), 2, Displacement(f"pos.{o}"), Variable(f"dpos.{o}", "latent", 1)
        )
        for o in objects
    ]
    return (
        Layer("body", body),
        Layer("event", WorldModel(event_g), tuple(events)),
        Layer("object", obj, tuple(moved)),
    )


def _realise(events, state):
    """Push extent e of the targeted object is a joint displacement: q^tar = q_prev + e."""
    (name,) = [k for k in events if k.startswith("extent.")]
    return [{"q": state["q_prev"] + events[name]}]


def _hierarchy(objects: tuple[str, ...] = ("box",)) -> Hierarchy:
    q = LevelQuery(300, ActionOptions(scale=0.01, lr=0.05))
    return Hierarchy(*_layers(objects), _realise, object_query=q, body_query=q, context_samples=64)


def test_nested_query_closed_form() -> None:
    h = _hierarchy()
    state = {"q_prev": torch.tensor([[0.3], [-0.2]]), "pos_prev.box": torch.tensor([[0.1], [0.0]])}
    target = torch.tensor([[0.5], [-0.3]])
    p = h.plan({"pos.box": target}, state)
    extent = target - state["pos_prev.box"]  # object displacement = 1.0 * extent
    assert torch.allclose(p.event_targets["extent.box"], extent, atol=1e-3)
    assert torch.allclose(p.body_targets[0]["q"], state["q_prev"] + extent, atol=1e-3)
    assert torch.allclose(p.actions["act"], extent / GAIN, atol=1e-3)  # q = q_prev + GAIN act
    with pytest.raises(ValueError, match="phase 1 does not exist"):
        h.plan({"pos.box": target}, state, phase=1)


def test_contextualisation_picks_the_targeted_object() -> None:
    h = _hierarchy(("box", "ball"))
    state = {
        "q_prev": torch.tensor([[0.0]]),
        "pos_prev.box": torch.tensor([[0.1]]),
        "pos_prev.ball": torch.tensor([[0.4]]),
    }
    p = h.plan({"pos.ball": torch.tensor([[0.2]])}, state)
    names = set(p.contexts["object"].graph.names)
    assert names == {"extent.ball", "pos_prev.ball", "dpos.ball", "pos.ball"}
    assert set(p.contexts["object"].dropped) == {"extent.box", "pos_prev.box", "dpos.box", "pos.box"}
    assert set(p.contexts["body"].graph.names) == {"act", "q_prev", "q"}  # touch is not on a path to q
    assert p.event_targets == {"extent.ball": pytest.approx(torch.tensor([[-0.2]]), abs=1e-3)}


def test_bottom_up_evidence_shapes() -> None:
    h = _hierarchy()
    t = 7
    touch = torch.zeros(t, 1)
    touch[4:] = 1
    history = {"q": torch.linspace(0, 0.6, t)[:, None], "touch": touch, "pos.box": torch.zeros(t, 1)}
    ev = h.evidence(history)
    assert ev["event"]["extent.box"].shape == (t - 1, 1)
    assert torch.allclose(ev["event"]["extent.box"], torch.full((t - 1, 1), 0.1, dtype=torch.float64))
    assert ev["event"]["onset"][:, 0].tolist() == [0, 0, 0, 1, 0, 0]
    assert ev["object"]["dpos.box"].shape == (t - 2, 1)  # over the T - 1 rows aligned with the event values
    with pytest.raises(WindowError):
        h.evidence({k: v[:1] for k, v in history.items()})


def test_counting_is_per_row_and_outermost() -> None:
    body, _, _ = _layers()
    with count_evaluations(body.model, body.model) as count:
        body.model.predict(
            {"act": torch.zeros(5, 1), "q_prev": torch.zeros(5, 1), "touch": torch.zeros(5, 1)}
        )
    assert count.total == 5 and count.by_site == {"q": 5}
    body.model.predict(
        {"act": torch.zeros(5, 1), "q_prev": torch.zeros(5, 1), "touch": torch.zeros(5, 1)}
    )  # unwrapped again
    assert count.total == 5


def test_a_switch_and_its_gated_mixture_are_counted_once_per_row_and_member() -> None:
    graph = CausalGraph(
        [Variable("a", "action", 1, bounds=(-2, 2)), Variable("c", "latent"), Variable("x", "latent")],
        [("a", "c"), ("a", "x"), ("c", "x")],
    )
    on = EnsembleMechanism([_lin(1.0, 0.0), _lin(2.0, 0.0), _lin(3.0, 0.0)])
    model = WorldModel(
        graph, {"c": BernoulliMechanism.from_coefficients([1.0]), "x": GatedMechanism("c", on)}
    )
    a = {"a": torch.zeros(4, 1)}
    with count_evaluations(model) as count:
        model.predict(a)  # the mode's logits on 4 rows; the mixture evaluates the 3 members on 4 rows
    assert count.by_site == {"c": 4, "x": 12}
    with count_evaluations(model) as count:
        model.predict(a, members=True)  # paired: the 3 x 4 member rows once each
    assert count.by_site == {"c": 12, "x": 12}


def test_bad_layers() -> None:
    body, event, obj = _layers()
    with pytest.raises(ValueError, match="the body layer must be a Layer named 'body'"):
        Hierarchy(event, event, obj, _realise)
    empty = Layer("event", WorldModel(CausalGraph([Variable("other", "observed", 1)])))
    with pytest.raises(ValueError, match=r"missing from the event layer: \['extent.box'\]"):
        Hierarchy(body, empty, obj, _realise)
    with pytest.raises(ValueError, match="layer name 'middle' unknown"):
        Layer("middle", body.model)
