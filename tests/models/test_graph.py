import json

import pytest
import torch

from models import CausalGraph, Role, Variable, chain_graph, finger_graph, random_graph


def v(name, role="latent", **kw):
    return Variable(name, role, **kw)


def test_topological_order_is_deterministic_and_respects_edges():
    g = CausalGraph([v("c"), v("a", "observed"), v("b")], [("a", "b"), ("b", "c")])
    assert g.topological_order() == ("a", "b", "c")
    assert g.parents("c") == ("b",)
    assert g.roots == ("a",)
    assert g.non_roots == ("b", "c")


def test_parents_follow_declaration_order():
    g = CausalGraph([v("z", "observed"), v("a", "observed"), v("y")], [("a", "y"), ("z", "y")])
    assert g.parents("y") == ("z", "a")


def test_rejects_cycle_naming_it():
    with pytest.raises(ValueError, match="cycle: .*a.*b"):
        CausalGraph([v("a"), v("b")], [("a", "b"), ("b", "a")])


def test_rejects_parent_of_action():
    with pytest.raises(ValueError, match="action 'act' has parent 'x'"):
        CausalGraph([v("x", "observed"), Variable("act", "action", bounds=(0, 1))], [("x", "act")])


def test_rejects_edge_from_lag0_to_lag1():
    with pytest.raises(ValueError, match="'q' \\(lag 0\\) -> 'q_prev' \\(lag 1\\)"):
        CausalGraph([v("q"), v("q_prev", "observed", lag=1)], [("q", "q_prev")])


@pytest.mark.parametrize("edge", [("a", "nope"), ("nope", "a")])
def test_rejects_unknown_names(edge):
    with pytest.raises(ValueError, match="unknown variable 'nope'"):
        CausalGraph([v("a")], [edge])


def test_rejects_duplicates_and_self_loops():
    with pytest.raises(ValueError, match="duplicate variable name 'a'"):
        CausalGraph([v("a"), v("a")])
    with pytest.raises(ValueError, match="self-loop on 'a'"):
        CausalGraph([v("a")], [("a", "a")])


def test_rejects_bad_lag_of():
    with pytest.raises(ValueError, match="lag_of names unknown variable 'q'"):
        CausalGraph([v("q_prev", "observed", lag=1, lag_of="q")])
    with pytest.raises(ValueError, match="must be a lag-0 variable of dim 1"):
        CausalGraph([v("q", dim=2), v("q_prev", "observed", lag=1, lag_of="q")])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"role": "action"}, "has no bounds"),
        ({"role": "observed", "bounds": (1.0, 1.0)}, "low >= high"),
        ({"role": "observed", "bounds": (2.0, 1.0)}, "low >= high"),
        ({"role": "bogus"}, "role 'bogus' is not one of"),
        ({"role": "latent", "dim": 0}, "dim must be a positive int"),
        ({"role": "latent", "lag": 2}, "lag must be 0 or 1"),
        ({"role": "observed", "dim": 2, "bounds": ([0, 0, 0], [1, 1, 1])}, "expected 2"),
    ],
)
def test_variable_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Variable("x", **kwargs)


@pytest.mark.parametrize("name", ["", " q", "q ", "q\nx", "q\tx", "q\x00"])
def test_variable_name_validation(name):
    with pytest.raises(ValueError, match=f"variable name {name!r} is not valid".replace("\\", "\\\\")):
        Variable(name, "latent")


@pytest.mark.parametrize(
    "name", ["q.finger", "1x", "act.robot:left_fingers", "q.arm/elbow", "q.left-knee", "q.joint 1"]
)
def test_mujoco_names_are_variable_and_site_names(name):
    from models import WorldModel

    assert Variable(name, "latent").name == name
    g = CausalGraph([Variable("a.b", "observed"), Variable(name, "latent")], [("a.b", name)])
    m = WorldModel(g, seed=0, hidden=(2,))
    out = m.predict({"a.b": torch.zeros(2, 1)})
    assert set(out) == {"a.b", name}


def test_module_keys_are_one_per_name():
    from models.values import module_key

    names = ["q.finger", "q:finger", "q%3Afinger", "%q", "keys", "a.b:c", "a:b.c", "q.joint 1"]
    keys = [module_key(n) for n in names]
    assert len(set(keys)) == len(keys) and all("." not in k for k in keys)
    assert module_key("q.finger") == "q:finger"  # the key of every saved model


def test_json_round_trip_and_fingerprint():
    g = finger_graph("state")
    g2 = CausalGraph.from_json(g.to_json())
    assert g2 == g
    assert g2.fingerprint() == g.fingerprint()
    assert g2.edges == g.edges
    assert g2["act.finger"].bounds == ((-1.0,), (0.33,))
    assert finger_graph("thesis") != g
    assert json.loads(g.to_json())["format"] == "pal.causal_graph/1"


def test_from_json_rejects_garbage():
    with pytest.raises(ValueError, match="malformed"):
        CausalGraph.from_json("{not json")
    with pytest.raises(ValueError, match="format"):
        CausalGraph.from_json('{"format": "other"}')


def test_dot_export_lists_nodes_and_edges():
    dot = chain_graph().to_dot()
    assert dot.startswith("digraph")
    assert '"x" -> "y";' in dot and '"y" -> "z";' in dot


def test_plot_returns_figure():
    from matplotlib.figure import Figure

    fig = finger_graph().plot()
    assert isinstance(fig, Figure)


def test_with_edges_validates_the_result():
    g = finger_graph("thesis")
    g2 = g.with_edges(add=[("q_prev.finger", "dq.finger")])
    assert g2 == finger_graph("state")
    assert g2.with_edges(remove=[("q_prev.finger", "dq.finger")]) == g
    with pytest.raises(ValueError, match="not in the graph"):
        g.with_edges(remove=[("q.finger", "dq.finger")])
    with pytest.raises(ValueError, match="cycle"):
        g.with_edges(add=[("q.finger", "dq.finger")])


def test_presets():
    g = finger_graph("thesis")
    assert set(g.edges) == {
        ("act.finger", "dq.finger"),
        ("dq.finger", "q.finger"),
        ("q_prev.finger", "q.finger"),
    }
    assert g.by_role(Role.ACTION) == ("act.finger",)
    assert g.by_role("observed") == ("q_prev.finger",)
    assert set(g.by_role("latent")) == {"dq.finger", "q.finger"}
    assert g.lagged == {"q_prev.finger": "q.finger"}
    with pytest.raises(ValueError, match="variant 'x' unknown"):
        finger_graph("x")


def test_random_graph_is_a_seeded_dag():
    a, b = random_graph(20, seed=3), random_graph(20, seed=3)
    assert a == b and len(a) == 20
    assert random_graph(20, seed=4) != a
