"""Tables as data: DataFrames, dicts of 1-d columns, arrays with column names, and the name rule."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inference import counterfactual, discover, fit, infer_state
from inference.discovery import DiscoveryOptions
from models import CausalGraph, Variable, WorldModel
from models.tables import Table, as_table, is_table
from models.variables import column_label, site_name, valid_name

pd = pytest.importorskip("pandas")


def chain_rows(n=400, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=n)
    y = 2.0 * x + 0.5 * rng.normal(size=n)
    z = -y + 0.5 * rng.normal(size=n)
    return {"p44/42": x, "y [kg]": y, " z": z}


@pytest.mark.parametrize(
    ("label", "name"),
    [
        ("p44/42", "p44/42"),
        ("weight (kg)", "weight (kg)"),
        (" age", "%20age"),
        ("age ", "age%20"),
        ("50%", "50%25"),
        ("units", "%75nits"),
        ("_x", "%5Fx"),
        ("a\nb", "a%0Ab"),
        ("a\tb", "a%09b"),
        (7, "7"),
    ],
)
def test_site_name_is_valid_and_reversible(label, name):
    assert site_name(label) == name
    assert valid_name(name)
    assert column_label(name) == str(label)


def test_site_name_is_injective_on_tricky_labels():
    labels = ["a%0Ab", "a\nb", "a%", "a%25", "units", "%75nits", " x", "%20x", "_", "%5F"]
    names = [site_name(lab) for lab in labels]
    assert len(set(names)) == len(labels)
    assert [column_label(n) for n in names] == labels


def test_reserved_names_are_refused_with_the_rule_in_the_message():
    for bad in ("units", "_hidden"):
        with pytest.raises(ValueError, match="site_name maps any text"):
            Variable(bad, "observed")
    for bad in ("", None, 1.5):
        with pytest.raises(ValueError, match="column label"):
            site_name(bad)


def test_every_table_form_gives_the_same_columns():
    rows = chain_rows(50)
    arr = np.stack(list(rows.values()), 1)
    structured = np.zeros(50, dtype=[("p44/42", float), ("y [kg]", float), (" z", float)])
    for k, v in rows.items():
        structured[k] = v
    forms = [pd.DataFrame(rows), rows, as_table(arr, columns=list(rows)), structured]
    tables = [as_table(f) for f in forms]
    for t in tables:
        assert t.names == ("p44/42", "y [kg]", "%20z")
        assert t.labels["%20z"] == " z"
        assert t.n == 50 and t["p44/42"].shape == (50, 1) and t["p44/42"].dtype == np.float64
        np.testing.assert_array_equal(t["y [kg]"][:, 0], rows["y [kg]"])
    assert tables[0].site(" z") == "%20z"
    assert is_table(forms[0]) and is_table(structured) and not is_table(rows)


def test_bool_and_category_columns_become_codes():
    frame = pd.DataFrame(
        {"b": [True, False, True], "c": pd.Categorical(["lo", "hi", "lo"], categories=["lo", "hi"])}
    )
    t = as_table(frame)
    np.testing.assert_array_equal(t["b"][:, 0], [1.0, 0.0, 1.0])
    np.testing.assert_array_equal(t["c"][:, 0], [0.0, 1.0, 0.0])
    assert t.categories == {"c": ("lo", "hi")}


@pytest.mark.parametrize(
    ("frame", "match"),
    [
        (
            lambda: pd.DataFrame({"x": [1.0, np.nan, 2.0]}),
            r"column 'x' has 1 rows with NaN or inf \(first row 1\)",
        ),
        (lambda: pd.DataFrame({"x": ["a", "b"]}), r"column 'x' is not numeric"),
        (lambda: pd.DataFrame({"c": pd.Categorical(["a", None])}), r"column 'c' has 1 missing values"),
        (lambda: pd.DataFrame([[1.0, 2.0]], columns=["a", "a"]), "repeat a label"),
        (lambda: pd.DataFrame({"a\nb": [1.0], "a%0Ab": [2.0]}), "both map to the site name"),
        (lambda: pd.DataFrame({"x": []}), "no rows"),
    ],
)
def test_bad_tables_get_specific_errors(frame, match):
    with pytest.raises(ValueError, match=match):
        as_table(frame())


def test_arrays_without_names_and_bad_columns_are_refused():
    with pytest.raises(ValueError, match=r"has no column names; pass columns="):
        as_table(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="data has 2 columns but 3 labels"):
        as_table(np.zeros((4, 2)), columns=["a", "b", "c"])


def test_from_edges_names_free_text_like_the_table():
    g = CausalGraph.from_edges([("p44/42", "y [kg]"), ("y [kg]", " z")], nodes=["w"], roles={"w": "latent"})
    assert g.names == ("w", "p44/42", "y [kg]", "%20z")
    assert g.edges == (("p44/42", "y [kg]"), ("y [kg]", "%20z"))
    assert g["w"].role == "latent"
    with pytest.raises(ValueError, match="roles name"):
        CausalGraph.from_edges([("a", "b")], roles={"c": "latent"})
    with pytest.raises(ValueError, match="graph has a cycle"):
        CausalGraph.from_edges([("a", "b"), ("b", "a")])


def test_fit_and_queries_take_a_dataframe_with_extra_columns():
    rows = chain_rows()
    frame = pd.DataFrame({**rows, "unused (has NaN)": np.r_[np.nan, np.zeros(399)]})
    g = CausalGraph.from_edges([("p44/42", "y [kg]"), ("y [kg]", " z")])
    model = WorldModel(g, seed=0, kind="linear")
    r = fit(model, frame, seed=0)
    assert r.trained == ("y [kg]", "%20z")
    with torch.no_grad():
        slope = model.loc("y [kg]", {"p44/42": torch.ones(1, 1)}) - model.loc(
            "y [kg]", {"p44/42": torch.zeros(1, 1)}
        )
    assert float(slope) == pytest.approx(2.0, abs=0.1)
    cf = counterfactual(model, frame.head(3), {"p44/42": 0.0})
    assert cf.mean["%20z"].shape == (1, 3, 1)
    post = infer_state(model, frame.head(4)[["p44/42", " z"]], guide="grid", num_samples=8)
    assert post.latent == ("y [kg]",)


def test_unseen_category_and_half_bernoulli_are_refused():
    g = CausalGraph.from_edges([("c", "y")])
    model = WorldModel(g, seed=0, kind="linear", discrete={"c": 2})
    frame = pd.DataFrame({"c": pd.Categorical(["a", "b", "c"]), "y": [0.0, 1.0, 2.0]})
    with pytest.raises(ValueError, match=r"data\['c'\]"):
        fit(model, frame)
    with pytest.raises(ValueError, match=r"data\['c'\]"):
        fit(model, pd.DataFrame({"c": [0.0, 0.5, 1.0], "y": [0.0, 1.0, 2.0]}))


def test_discover_takes_a_table_with_progress_stability_and_cpdag(capsys):
    rows = chain_rows(300)
    res = discover(pd.DataFrame(rows), options=DiscoveryOptions(bootstrap=2), seed=0, progress_bar=True)
    assert {frozenset(e) for e in res.graph.edges} == {
        frozenset(("p44/42", "y [kg]")),
        frozenset(("y [kg]", "%20z")),
    }
    # a chain has no v-structure: its class leaves both edges undirected
    assert res.cpdag.directed == () and len(res.cpdag.undirected) == 2
    assert set(res.stability) >= set(res.graph.edges)
    assert all(0.0 <= v <= 1.0 for v in res.stability.values())
    assert res.adjacency_stability[("p44/42", "y [kg]")] == 1.0
    assert "discover" in capsys.readouterr().err
    d = res.to_dict()
    assert d["cpdag"]["undirected"] and d["edges"][0]["stability"] is not None


def test_discover_takes_variables_with_a_table_and_refuses_unknown_keywords():
    rows = chain_rows(200)
    g = CausalGraph.from_edges([("p44/42", "y [kg]"), ("y [kg]", " z")])
    res = discover(g, pd.DataFrame(rows), options=DiscoveryOptions(min_gain=12.0))
    assert res.settings["min_gain"] == 12.0
    with pytest.raises(ValueError, match="no columns for variables"):
        discover(g, pd.DataFrame({"p44/42": rows["p44/42"]}))
    with pytest.raises(ValueError, match="data is missing"):
        discover(g)
    with pytest.raises(TypeError, match="unexpected keyword"):
        discover(g, rows, nonsense=1)
    with pytest.raises(TypeError, match="unexpected keyword argument 'min_gain'"):
        discover(g, rows, min_gain=12.0)


def test_table_variables_and_select():
    t = as_table(chain_rows(10))
    vs = t.variables(roles={"p44/42": "latent"})
    assert [v.role for v in vs] == ["latent", "observed", "observed"]
    assert vs[2].description == " z"
    assert t.select([" z", "p44/42"]).names == ("%20z", "p44/42")
    assert isinstance(t.select(["y [kg]"]), Table)
