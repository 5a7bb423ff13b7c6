"""Smoke tests of ``pal bench``: quick configurations run and report sane figures.

Speed is never asserted here (see DESIGN.md); only keys, finiteness and positivity, and
that the peer libraries compute the same counterfactuals as pal.
"""

from __future__ import annotations

import json
import math

import pytest
import torch

from inference import counterfactual
from pal.experiments import BENCHMARKS, bench_action, bench_counterfactual, bench_svi, load_module
from pal.experiments.counterfactual_peers import available
from pal.experiments.output import jsonable

FIGURES = {"chain_unit_ms", "mlp50_unit_ms", "units_per_s", "scenarios_ms"}


def _positive(value: object) -> bool:
    return isinstance(value, float) and math.isfinite(value) and value > 0


def _check_figures(figs: dict, extra: set[str] = frozenset()) -> None:
    assert set(figs) == FIGURES | extra
    for key in FIGURES - {"scenarios_ms"}:
        assert _positive(figs[key]), (key, figs[key])
    assert set(figs["scenarios_ms"]) == {"1", "2", "4", "8"}
    assert all(_positive(v) for v in figs["scenarios_ms"].values())


def test_registry_modules_follow_the_contract():
    for name in ("counterfactual", "svi", "action"):
        module = load_module("bench", name)
        assert module.__name__ == BENCHMARKS[name]
        assert isinstance(module.Config.quick(), module.Config)
        assert callable(module.run)


def test_counterfactual_quick():
    result = bench_counterfactual.run(bench_counterfactual.Config.quick())
    data = result.to_dict()
    assert set(data) == FIGURES | {"chirho", "dowhy", "ratios"}
    _check_figures({k: data[k] for k in FIGURES})
    for peer in ("chirho", "dowhy"):
        if not available(peer):
            assert data[peer] is None and data["ratios"][peer] is None
            continue
        _check_figures(data[peer], extra={"notes"})
        assert all(isinstance(n, str) for n in data[peer]["notes"])
        ratios = data["ratios"][peer]
        assert _positive(ratios["chain_unit_ms"]) and _positive(ratios["units_per_s"])
        assert all(_positive(v) for v in ratios["scenarios_ms"].values())
        assert result.agreement[peer] <= bench_counterfactual.TOLERANCE
    json.dumps(jsonable(data))
    assert "< 1 means pal is faster" in result.to_markdown()
    assert set(result.figures()) == {"scenarios"}


def _chain_factual(n: int) -> dict[str, torch.Tensor]:
    chain = bench_counterfactual.chain_model()
    sample = chain.sample(n, torch.Generator().manual_seed(1))
    unit = bench_counterfactual.CHAIN_UNIT
    return {k: torch.cat([torch.tensor([[unit[k]]]), v]) for k, v in sample.items()}


@pytest.mark.parametrize("peer_name", ["chirho", "dowhy"])
def test_peer_chain_counterfactual_agrees_with_pal(peer_name):
    pytest.importorskip(peer_name)
    from pal.experiments.counterfactual_peers import make_peer

    chain = bench_counterfactual.chain_model()
    mlp = bench_counterfactual.mlp_model(5, seed=0)
    peer = make_peer(peer_name, chain, bench_counterfactual.CHAIN_WEIGHTS, mlp)
    factual = _chain_factual(64)
    n = factual["x"].shape[0]
    ours = counterfactual(chain, factual, {"x": bench_counterfactual.CHAIN_DO}).samples
    theirs = peer.to_tensors(
        peer.run("chain", peer.native(factual), "x", [bench_counterfactual.CHAIN_DO]), "x", 1, n
    )
    for name in ("x", "y", "z"):
        torch.testing.assert_close(theirs[name], ours[name][0], atol=1e-4, rtol=0)
    # analytic oracle for the unit (1, 2.5, -3) under do(X = 0): u_y = 0.5, u_z = 0.75
    assert theirs["y"][0, 0, 0].item() == pytest.approx(0.5, abs=1e-5)
    assert theirs["z"][0, 0, 0].item() == pytest.approx(0.0, abs=1e-5)


def test_svi_quick():
    result = bench_svi.run(bench_svi.Config.quick())
    data = result.to_dict()
    assert set(data) == {"steps_per_s", "steps_per_s_loop", "ratio"}
    for key in ("steps_per_s", "steps_per_s_loop"):
        assert set(data[key]) == {"infer_state", "plain_pyro"}
        assert all(_positive(v) for v in data[key].values()), data[key]
    assert _positive(data["ratio"])
    # same seed and settings: the same optimisation trajectory
    assert result.final_loss["infer_state"] == pytest.approx(result.final_loss["plain_pyro"], rel=1e-3)
    assert "plain" in result.to_markdown() and result.figures() == {}


def test_action_quick():
    result = bench_action.run(bench_action.Config.quick())
    data = result.to_dict()
    assert set(data) == {"seconds", "baseline_seconds", "ratio"}
    assert all(_positive(v) for v in data.values()), data
    assert result.max_action_diff <= 1e-4
    assert "infer_action" in result.to_markdown() and result.figures() == {}
