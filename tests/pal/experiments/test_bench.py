"""Smoke tests of ``pal bench``: quick configurations run and report sane figures.

Speed is never asserted here (see DESIGN.md); only keys, finiteness and positivity, the
ratios' definitions, and that the peer libraries compute the same counterfactuals as pal.
"""

from __future__ import annotations

import math

import pytest
import torch

from inference import counterfactual
from pal.baselines.counterfactual_peers import available
from pal.experiments.bench import action as bench_action
from pal.experiments.bench import babble as bench_babble
from pal.experiments.bench import counterfactual as bench_counterfactual
from pal.experiments.bench import svi as bench_svi
from pal.lab import registry

FIGURES = {"chain_unit_ms", "mlp50_unit_ms", "units_per_s", "scenarios_ms"}


def _positive(value: object) -> bool:
    return isinstance(value, float) and math.isfinite(value) and value > 0


def _check_figures(figs: dict, ks: set[str]) -> None:
    for key in FIGURES - {"scenarios_ms"}:
        assert _positive(figs[key]), (key, figs[key])
    assert set(figs["scenarios_ms"]) == ks
    assert all(_positive(v) for v in figs["scenarios_ms"].values())


def test_benchmarks_are_registered():
    names = {e.name for e in registry.entries("bench")}
    assert {"counterfactual", "svi", "action", "babble", "discovery", "perception"} <= names


def test_counterfactual_quick():
    config = registry.get("bench", "counterfactual").quick
    rep = bench_counterfactual.run(config)
    m = rep.metrics
    assert {
        "pal",
        "chirho",
        "dowhy",
        "ratios",
        "agreement",
        "scenario_growth",
        "compute_growth_bound",
        "intervened",
    } == set(m)
    ks = {"1", "2", "8", "32"}
    _check_figures(m["pal"], ks)
    assert set(m["pal"]["scenarios_cpu_ms"]) == ks and all(
        _positive(v) for v in m["pal"]["scenarios_cpu_ms"].values()
    )
    growth = m["scenario_growth"]["pal"]
    assert growth["wall"]["8"] == pytest.approx(m["pal"]["scenarios_ms"]["8"] / m["pal"]["scenarios_ms"]["1"])
    assert growth["cpu"]["8"] == pytest.approx(
        m["pal"]["scenarios_cpu_ms"]["8"] / m["pal"]["scenarios_cpu_ms"]["1"]
    )
    assert rep.target("scenarios_8_vs_1").value == pytest.approx(growth["cpu"]["8"])
    added = (m["pal"]["scenarios_cpu_ms"]["8"] - m["pal"]["scenarios_cpu_ms"]["1"]) / 7
    assert growth["cpu_ms_per_added_scenario"]["8"] == pytest.approx(added)
    assert m["compute_growth_bound"]["1"] == 1.0 and 1.0 < m["compute_growth_bound"]["8"] < 8.0
    vs_chirho = m["scenario_growth"]["pal_over_chirho_cpu"]
    assert (vs_chirho is None) == (not available("chirho"))
    if vs_chirho is not None:
        assert set(vs_chirho) == {"2", "8", "32"}
        assert vs_chirho["8"] == pytest.approx(rep.target("scenarios_8_vs_1_vs_chirho").value)
    for peer in ("chirho", "dowhy"):
        if not available(peer):
            assert m[peer] is None and m["ratios"][peer] is None and m["scenario_growth"][peer] is None
            continue
        _check_figures(m[peer], ks)
        ratios = m["ratios"][peer]
        assert _positive(ratios["chain_unit_ms"]) and _positive(ratios["units_per_s"])
        assert m["agreement"][peer] <= bench_counterfactual.TOLERANCE
    chirho = rep.target("scenarios_8_vs_1_vs_chirho")
    assert chirho.threshold == 1.0 and (chirho.value is None) == (not available("chirho"))
    table = rep.tables[0]
    # 3 unit figures, 4 scenario times, 3 growths each by wall and CPU time, 3 costs per added scenario
    assert table.columns[:4] == ("figure", "pal", "chirho", "dowhy") and len(table.rows) == 3 + 4 + 6 + 3
    per_unit = {f"{f}_vs_{n}" for f in ("chain_unit_ms", "mlp50_unit_ms") for n in ("chirho", "dowhy")}
    growth_targets = {"scenarios_8_vs_1", "scenarios_8_vs_1_vs_chirho"}
    assert {t.name for t in rep.targets} == {"chain_unit_ms", "units_per_s"} | growth_targets | per_unit
    assert rep.target("scenarios_8_vs_1").threshold == 1.5
    for name in per_unit:
        peer = name.rsplit("_vs_", 1)[1]
        t = rep.target(name)
        assert t.value == (
            None if m["ratios"][peer] is None else m["ratios"][peer][name.rsplit("_vs_", 1)[0]]
        )
    ax = rep.figures["scenarios"].axes[0]
    assert ax.get_xlabel() == "scenarios K" and list(ax.get_lines()[0].get_xdata()) == [1, 2, 8, 32]


def _chain_factual(n: int) -> dict[str, torch.Tensor]:
    chain = bench_counterfactual.chain_model()
    sample = chain.sample(n, torch.Generator().manual_seed(1))
    unit = bench_counterfactual.CHAIN_UNIT
    return {k: torch.cat([torch.tensor([[unit[k]]]), v]) for k, v in sample.items()}


@pytest.mark.parametrize("peer_name", ["chirho", "dowhy"])
def test_peer_chain_counterfactual_agrees_with_pal(peer_name):
    pytest.importorskip(peer_name)
    from pal.baselines.counterfactual_peers import make_peer

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


def test_svi_tiny_reports_its_figures_and_refuses_a_guide_that_pal_warns_about():
    rep = bench_svi.run(registry.get("bench", "svi").tiny)  # 6 steps: the guide has not fitted
    m = rep.metrics
    for key in ("steps_per_s", "steps_per_s_loop", "cpu_seconds"):
        assert set(m[key]) == {"infer_state", "plain_pyro"}
    assert all(_positive(v) for v in m["steps_per_s"].values())
    assert m["ratio"] == pytest.approx(m["steps_per_s"]["infer_state"] / m["steps_per_s"]["plain_pyro"])
    assert m["ratio_cpu"] == pytest.approx(m["cpu_seconds"]["plain_pyro"] / m["cpu_seconds"]["infer_state"])
    # same seed and settings: the same optimisation trajectory
    assert m["final_loss"]["infer_state"] == pytest.approx(m["final_loss"]["plain_pyro"], rel=1e-3)
    assert m["pal_warnings"] and "6 steps" in m["pal_warnings"][-1]
    for name in ("ratio", "ratio_cpu"):
        target = rep.target(name)
        assert target.threshold == pytest.approx(1 / 1.3) and target.verdict == "not evaluated"


# the benchmark times SVI steps; its budgets are not meant to converge
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
def test_bench_svi_leaves_the_global_rngs_alone():
    import random

    import numpy as np

    before = (random.getstate(), np.random.get_state()[1].copy(), torch.get_rng_state())
    bench_svi.run(registry.get("bench", "svi").tiny)
    assert random.getstate() == before[0]
    assert np.array_equal(np.random.get_state()[1], before[1])
    assert torch.equal(torch.get_rng_state(), before[2])


def test_action_quick():
    rep = bench_action.run(registry.get("bench", "action").quick)
    m = rep.metrics
    for figures in (m, m["planner"]):
        assert all(_positive(figures[k]) for k in ("seconds", "baseline_seconds", "ratio")), figures
        assert figures["ratio"] == pytest.approx(figures["seconds"] / figures["baseline_seconds"])
        assert figures["max_action_diff"] <= 1e-4
    assert rep.target("max_action_diff").met is True and rep.target("planner_max_action_diff").met is True
    assert rep.target("planner_ratio").value == m["planner"]["ratio"]
    assert [r[0] for r in rep.tables[0].rows] == ["infer_action", "bare Adam", "planner", "bare CEM + Adam"]
    reached = m["reached"]
    assert (
        reached["planner"] == reached["bare CEM + Adam"] and reached["infer_action"] == reached["bare Adam"]
    )
    assert reached["infer_action"] < reached["planner"] <= m["reachable"] + 1 / 32


@pytest.mark.slow
def test_babble_quick_on_the_arm():
    config = bench_babble.Config(body=bench_babble.BodyChoice("arm", frame_skip=5), steps=60, repeats=1)
    rep = bench_babble.run(config)
    m = rep.metrics
    assert m["body"] == "arm" and _positive(m["transitions_per_s"]) and _positive(m["raw_steps_per_s"])
    assert m["ratio"] == pytest.approx(m["transitions_per_s"] / m["raw_steps_per_s"])
    assert [r[0] for r in rep.tables[0].rows] == ["source", "raw_loop", "raw_nstep", "recorded"]


def test_planner_agreement_compares_continuous_sites_where_no_switch_flips():
    from types import SimpleNamespace

    from pal.experiments.bench.planner import _agreement

    model = SimpleNamespace(discrete={"contact": 2})
    contact = torch.zeros(2, 3, 4, 1)
    pos = torch.zeros(2, 3, 4, 2)
    flipped, moved = contact.clone(), pos.clone()
    flipped[1, 2, 3] = 1.0  # member 1, candidate 2 flips at its last step
    moved[1, 2] += 5.0  # ... and parts from there
    moved[0, 0, 0, 0] += 3e-5  # rounding elsewhere
    got = _agreement(model, {"contact": contact, "pos": pos}, {"contact": flipped, "pos": moved})
    assert got["discrete_flipped"] == pytest.approx(1 / 6)
    assert got["max_abs_diff"] == pytest.approx(3e-5, rel=1e-3)
    everything = _agreement(model, {"contact": contact, "pos": pos}, {"contact": 1 - contact, "pos": pos})
    assert everything == {"max_abs_diff": float("inf"), "discrete_flipped": 1.0}


@pytest.mark.slow
def test_bench_planner_tiny_rolls_the_body_first_with_the_same_values(tiny_run):
    rep = tiny_run("bench", "planner").report
    m = rep.metrics
    assert m["driven_max_abs_diff"] < 1e-6
    assert m["driven_speedup"] == pytest.approx(
        m["rollout_seconds"]["step_loop"] / m["rollout_seconds"]["stacked"]
    )
    assert rep.target("driven_speedup").verdict in ("met", "not met")  # its precondition holds
    assert [r[0] for r in rep.tables[1].rows][-1] == "stacked, the body in the step loop (driven=False)"
    lock = m["lockstep"]
    assert lock["units"] == 3 and m["lockstep_speedup"] == pytest.approx(lock["single"] / lock["batched"])
    assert rep.target("lockstep_speedup").verdict in ("met", "not met")
