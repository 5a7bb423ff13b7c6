"""Structure learning where data are weak: normal scores, the calibrated edge test, screening, shuffled columns."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inference import DiscoveryOptions, discover, shd
from inference.admissible import StructureData
from inference.crossfit import CrossFitScorer
from inference.marginals import normal_scores, skewed, transform_columns
from inference.prune import prune
from inference.search import LocalScores
from models import Variable
from pal.experiments.structure.measurement import measurement_data, shuffled
from pal.experiments.structure.scm import standardised


def test_normal_scores_keep_the_order_and_make_the_marginal_gaussian():
    rng = np.random.default_rng(0)
    x = np.exp(rng.normal(size=(2000, 1)) * 1.5)  # log-normal: skewness about 30
    z = normal_scores(x)
    assert np.array_equal(np.argsort(z[:, 0]), np.argsort(x[:, 0]))
    assert abs(z.mean()) < 1e-9 and z.std() == pytest.approx(1.0, abs=0.02)
    gauss = rng.normal(size=(2000, 1))
    assert skewed(x).tolist() == [True] and skewed(gauss).tolist() == [False]
    t2 = rng.standard_t(2, size=(2000, 1))  # heavy tails: excess kurtosis far above 6
    assert skewed(t2).tolist() == [True]
    out, changed = transform_columns({"a": x, "b": gauss}, "auto")
    assert changed == ("a",) and out["b"] is gauss
    assert transform_columns({"a": x, "b": gauss}, "rank")[1] == ("a", "b")
    assert transform_columns({"a": x}, "none")[1] == ()


def _scores(rows):
    vs = [Variable(v, "observed") for v in ("a", "b", "c")]
    return LocalScores(CrossFitScorer(StructureData.build(vs, rows), seed=0)), {"a": 0, "b": 1, "c": 2}


def test_the_calibrated_test_drops_a_parent_whose_gain_is_noise():
    rng = np.random.default_rng(1)
    n = 300
    a, b = rng.normal(size=n), rng.normal(size=n)  # b is independent of everything
    c = a + 0.5 * rng.normal(size=n)
    scores, index = _scores({"a": a[:, None], "b": b[:, None], "c": c[:, None]})
    loose = {"a": [], "b": [], "c": ["a", "b"]}
    ratios, z, _ = prune(scores, loose, index, prune_nats=-100.0, required=set(), min_z=0.0)
    assert loose["c"] == ["a", "b"] and abs(ratios["b", "c"]) < 10  # a nats threshold below 0 keeps it
    strict = {"a": [], "b": [], "c": ["a", "b"]}
    ratios, z, _ = prune(scores, strict, index, prune_nats=-100.0, required=set(), min_z=2.0)
    assert strict["c"] == ["a"] and z["a", "c"] > 10  # the real parent passes by far
    kept = {"a": [], "b": [], "c": ["a", "b"]}
    _, z, _ = prune(scores, kept, index, prune_nats=-100.0, required={("b", "c")}, min_z=2.0)
    assert kept["c"] == ["a", "b"] and math.isinf(z["b", "c"])  # a required edge stays


def test_shuffled_columns_give_no_edges():
    # small d and n; the full-size check (d = 10, n = 1000, 10 seeds) is `pal bench discovery`
    found = []
    for seed in range(3):
        graph, data = measurement_data(5, 200, seed)
        found.append(len(discover(graph, standardised(shuffled(data, seed)), seed=seed).graph.edges))
    assert sum(found) <= 1, found


def test_measurement_like_data_beat_the_empty_graph_and_record_the_transform():
    graph, data = measurement_data(6, 400, 3)
    result = discover(graph, standardised(data), seed=0)
    assert shd(result.graph, graph) < len(graph.edges)  # better than no edges at all
    assert result.settings["transformed"]  # some columns were skewed or saturated
    assert all(result.z[e] >= 2.0 for e in result.graph.edges)
    assert result.to_dict()["edges"][0]["z"] is None or result.to_dict()["edges"][0]["z"] >= 2.0


def test_screening_gives_the_graph_of_the_full_search_on_a_clear_chain():
    rng = np.random.default_rng(2)
    a = rng.normal(size=400)
    b = np.tanh(2 * a) + 0.3 * rng.normal(size=400)
    c = b**2 + 0.3 * rng.normal(size=400)
    d = rng.normal(size=400)
    rows = {k: v[:, None] for k, v in zip("abcd", (a, b, c, d), strict=True)}
    vs = [Variable(v, "observed") for v in "abcd"]
    full = discover(vs, rows, options=DiscoveryOptions(screen=None), seed=0)
    screened = discover(vs, rows, options=DiscoveryOptions(screen=1), seed=0)
    skeleton = lambda g: {frozenset(e) for e in g.edges}  # noqa: E731
    assert skeleton(screened.graph) == skeleton(full.graph) == {frozenset("ab"), frozenset("bc")}
    assert screened.evaluations < full.evaluations


@pytest.mark.parametrize(
    ("kwargs", "text"),
    [
        ({"transform": "log"}, "transform"),
        ({"min_z": -1.0}, "min_z"),
        ({"screen": 0}, "screen"),
    ],
)
def test_bad_options_name_the_value(kwargs, text):
    with pytest.raises(ValueError, match=text):
        DiscoveryOptions(**kwargs)


def test_heavy_tailed_columns_do_not_break_the_scorer():
    gen = torch.Generator().manual_seed(0)
    x = torch.distributions.StudentT(2.0).sample((300, 1))
    y = x + torch.randn(300, 1, generator=gen)
    result = discover([Variable("x", "observed"), Variable("y", "observed")], {"x": x, "y": y}, seed=0)
    assert {frozenset(e) for e in result.graph.edges} == {frozenset("xy")}
