"""Edge confidence on CausalGraph (what structure learning returns)."""

from __future__ import annotations

import pytest

from models import CausalGraph, chain_graph


def test_confidence_travels_with_the_graph_but_not_its_identity():
    g = chain_graph().with_confidence({("x", "y"): 0.9, ("y", "z"): 0.6})
    assert g == chain_graph() and g.fingerprint() == chain_graph().fingerprint()
    assert g.edge_confidence("x", "y") == 0.9 and chain_graph().edge_confidence("x", "y") is None
    back = CausalGraph.from_json(g.to_json())
    assert back.confidence == g.confidence
    assert g.with_edges(remove=[("y", "z")]).confidence == {("x", "y"): 0.9}
    assert g.nx.edges["x", "y"]["confidence"] == 0.9
    assert "confidence" not in chain_graph().to_dict()  # old files are unchanged


def test_confidence_is_validated():
    with pytest.raises(ValueError, match="confidence given for \\('x', 'z'\\)"):
        chain_graph().with_confidence({("x", "z"): 0.5})
    with pytest.raises(ValueError, match="is 1.5, expected \\[0, 1\\]"):
        chain_graph().with_confidence({("x", "y"): 1.5})
    with pytest.raises(ValueError, match="is not an edge"):
        chain_graph().edge_confidence("z", "x")
