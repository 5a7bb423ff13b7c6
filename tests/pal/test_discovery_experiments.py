"""Smoke tests of the structure-learning experiments and benchmark (tiny sizes)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pal.cli import main
from pal.experiments import BENCHMARKS, EXPERIMENTS, active_design, bench_discovery, discovery
from pal.experiments import discovery_peers as peers
from pal.experiments.discovery_body import physics_effects
from pal.experiments.discovery_scm import random_scm
from pal.sim.babbling import BabbleConfig, collect


def test_registered():
    assert EXPERIMENTS["discovery"] == "pal.experiments.discovery"
    assert EXPERIMENTS["active_design"] == "pal.experiments.active_design"
    assert BENCHMARKS["discovery"] == "pal.experiments.bench_discovery"


def test_synthetic_scm_interventions_cut_the_mechanism():
    scm = random_scm(6, seed=3)
    child = scm.graph.non_roots[0]
    data, masks = scm.intervene([child] * 5, seed=0)
    assert masks[child].all() and not any(m.any() for k, m in masks.items() if k != child)
    assert np.all(np.abs(data[child] - scm.loc[child]) <= 2 * scm.scale[child] + 1e-6)


def test_synthetic_experiment_reports_shd_per_d_method_regime():
    config = discovery.quick_config(dims=(6,), n=200, interventions=4, rows_per_intervention=5, gated_max_d=0)
    result = discovery.run(config)
    d = result.to_dict()
    shd = d["shd"]["6"]
    assert set(shd["pal"]) == set(discovery.REGIMES)
    assert all(isinstance(v, (int, float)) for v in shd["pal"].values())
    for method in peers.PEERS:
        assert all((v is None) != peers.available() for v in shd[method].values())
    assert "| d | method | regime | SHD | seconds |" in result.to_markdown()
    json.dumps(d)


def test_peer_cpdag_shd_counts_undirected_edges():
    truth = [("a", "b"), ("b", "c")]
    assert peers.cpdag_shd([("a", "b")], [("b", "c")], truth) == 1
    assert peers.cpdag_shd([("b", "a")], [], truth) == 2
    assert peers.cpdag_shd([("a", "b")], [("b", "c")], truth, undirected_cost=0.0) == 0


def test_finger_body_learns_q_prev_to_dq_and_reports_b1(tmp_path, capsys):
    args = ["experiment", "discovery", "--body", "finger", "--json", "--quick"]
    args += [
        "--set",
        "transitions=600",
        "--set",
        "epochs=2",
        "--set",
        "b1_seeds=[0]",
        "--set",
        'extra={"cache": false}',
    ]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert ["q_prev.finger", "dq.finger"] in [e[:2] for e in out["learned_edges"]]
    assert set(out["b1"]) == {"thesis", "state", "learned", "persistence"}
    assert out["targets"]["q_prev_to_dq"] is True


def test_physics_effects_of_the_finger():
    data = collect(BabbleConfig(body="finger", steps=20, seed=0))
    effects = physics_effects(data, np.arange(4), "finger")
    assert set(effects) == {"q_prev.finger->dq.finger", "act.finger->dq.finger"}
    assert effects["act.finger->dq.finger"] > 0.05


def test_active_design_quick():
    config = active_design.Config(budget=40, agents=20, members=2, epochs=2, seeds=(0,))
    d = active_design.run(config).to_dict()
    assert d["transitions"] == [20, 40]
    assert set(d["mechanism_mse"]) == set(active_design.STRATEGIES)
    assert d["fraction_to_random_final"]["random"] == 1.0
    with pytest.raises(ValueError, match="budget 10 is smaller than one round"):
        active_design.run(active_design.Config(budget=10, agents=20))


def test_bench_discovery_quick():
    config = bench_discovery.Config(dims=(5,), n=120, joints=3, targets=4, steps=5, repeats=1)
    d = bench_discovery.run(config).to_dict()
    assert d["context"]["subgraph_variables"] == 4 and d["context"]["variables"] == 12
    assert d["context"]["max_action_diff"] < 1e-5
    assert d["discovery"]["5"]["seconds"] > 0
