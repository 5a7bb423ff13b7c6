"""The structure-learning experiments and benchmark on their tiny configurations (seeded)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pal.baselines import discovery_peers as peers
from pal.cli import main
from pal.experiments.bench import discovery as bench_discovery
from pal.experiments.structure import active_design
from pal.experiments.structure import body as discovery_body
from pal.experiments.structure import synthetic as discovery_synthetic
from pal.experiments.structure.scm import SCMConfig, random_scm
from pal.experiments.world_model.data import JointData, Realizer
from pal.lab import registry
from pal.sim.babbling import BabbleConfig, collect


def test_registered_entries():
    for kind, name, module in (
        ("experiment", "discovery", discovery_synthetic),
        ("experiment", "discovery_body", discovery_body),
        ("experiment", "active_design", active_design),
        ("bench", "discovery", bench_discovery),
    ):
        entry = registry.get(kind, name)
        assert entry.run is module.run and entry.config is module.Config
        assert entry.summary and not entry.summary.startswith("``")


def test_synthetic_scm_interventions_cut_the_mechanism():
    scm = random_scm(6, seed=3)
    child = scm.graph.non_roots[0]
    data, masks = scm.intervene([child] * 5, seed=0)
    assert masks[child].all() and not any(m.any() for k, m in masks.items() if k != child)
    assert np.all(np.abs(data[child] - scm.loc[child]) <= 2 * scm.scale[child] + 1e-6)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: SCMConfig(dims=()), "dims is empty"),
        (lambda: SCMConfig(dims=(1,)), "dims must be an int >= 2, got 1"),
        (lambda: discovery_synthetic.Config(regimes=("bogus",)), "regime 'bogus' unknown"),
        (lambda: discovery_synthetic.Config(regimes=("observational",) * 2), "distinct names"),
        (lambda: discovery_synthetic.InterventionConfig(count=0), "count must be a positive int, got 0"),
        (lambda: discovery_synthetic.GatedConfig(max_d=-1), "max_d must be a non-negative int"),
        (lambda: discovery_body.Config(replicates=0), "replicates must be a positive int"),
        (lambda: active_design.Config(budget=10, agents=20), "budget 10 is smaller than one round"),
        (lambda: active_design.Config(strategies=("active",)), "expected 'random' plus"),
        (lambda: active_design.EnsembleConfig(members=1), "members must be an int >= 2"),
        (lambda: bench_discovery.Config(threads=0), "threads must be a positive int"),
    ],
)
def test_configs_refuse_bad_values(make, message):
    with pytest.raises(ValueError, match=message):
        make()


@pytest.mark.slow
def test_synthetic_report_shd_per_d_method_regime(tiny_run):
    rep = tiny_run("experiment", "discovery").report
    shd = rep.metrics["shd"]["5"]
    assert set(shd) == set(discovery_synthetic.METHODS)
    assert set(shd["pal"]) == set(discovery_synthetic.REGIMES)
    # the agent's interventions orient edges the observational rows leave wrong
    assert shd["pal"]["interventional"] < shd["pal"]["observational"]
    assert shd["pal_gated"]["interventional"] < shd["pal_gated"]["observational"]
    assert len(rep.metrics["rows"]) == len(discovery_synthetic.METHODS) * len(discovery_synthetic.REGIMES)
    for method in peers.PEERS:
        assert all((v is None) != peers.available() for v in shd[method].values())
    names = [t.name for t in rep.targets]
    assert names == ["shd_minus_grasp.observational.d5", "shd_minus_grasp.interventional.d5"]
    assert all((t.value is None) != peers.available() for t in rep.targets)
    summary, per_seed = rep.tables
    assert len(summary.rows) == 12 and summary.columns[3] == "SHD"
    assert [r[2] for r in per_seed.rows] == list(discovery_synthetic.REGIMES)
    ax = rep.figures["shd"].axes
    assert [a.get_title() for a in ax] == list(discovery_synthetic.REGIMES)
    assert ax[0].get_ylabel() == "SHD [edges]" and len(ax[0].patches) == len(discovery_synthetic.METHODS)
    json.dumps(rep.metrics, allow_nan=False)


def test_peer_cpdag_shd_counts_undirected_edges():
    truth = [("a", "b"), ("b", "c")]
    assert peers.cpdag_shd([("a", "b")], [("b", "c")], truth) == 1
    assert peers.cpdag_shd([("b", "a")], [], truth) == 2
    assert peers.cpdag_shd([("a", "b")], [("b", "c")], truth, undirected_cost=0.0) == 0


@pytest.mark.skipif(not peers.available(), reason="causal-learn is not installed")
def test_peers_compare_on_a_strong_chain():
    scm, data = SCMConfig(dims=(4,), n=2000).draw(4, 0)
    out = peers.compare("grasp", data, scm.graph, seed=0)
    assert out["shd_undirected_free"] <= out["shd"] and out["edges"] >= out["undirected"]


@pytest.mark.slow
def test_body_report_on_two_arm_joints(tiny_run):
    rep = tiny_run("experiment", "discovery_body").report
    m = rep.metrics
    assert m["body"] == "arm" and m["joint"] == "finger" and m["body_graph"]["joints"] == ["elbow", "finger"]
    assert [r["seed"] for r in m["replicates"]] == [0, 1]
    assert ["q_prev.finger", "dq.finger"] in [e[:2] for e in m["learned_edges"]]
    assert set(m["b1"]) == {"thesis", "state", "dynamics", "learned", "persistence"}
    assert m["b1"]["learned"]["q_mse"] < m["b1"]["persistence"]["q_mse"]
    assert rep.target("q_prev_to_dq").value == 1.0
    assert rep.target("unjustified_cross_joint_transition_edges").value == 0
    effects = m["physics_effects"]
    assert len(effects) == 12  # q_prev, dq_prev and act of 2 joints -> dq of 2 joints
    assert effects["act.finger->dq.finger"] > discovery_body.JUSTIFIED > effects["act.finger->dq.elbow"]
    # the finger still moving at t-1 keeps moving: the simulator justifies dq_prev -> dq
    assert (
        effects["dq_prev.finger->dq.finger"] > discovery_body.JUSTIFIED > effects["dq_prev.finger->dq.elbow"]
    )
    assert ["dq_prev.finger", "dq.finger"] in m["physics_graph"]
    assert rep.target("shd_to_physics_graph").value == max(r["shd_to"]["physics"] for r in m["replicates"])
    counts = m["body_graph"]["counts"]
    assert counts["cross_joint_transition"] == 0
    titles = [t.title for t in rep.tables]
    assert "Test-set prediction error (thesis Table 5.7)" in titles
    b1_table = rep.tables[titles.index("Test-set prediction error (thesis Table 5.7)")]
    assert b1_table.rows[0][1] == 0.528 and "learned graph MSE" in b1_table.columns
    assert set(rep.figures) == {"graph", "body_graph"}
    ax = rep.figures["graph"].axes[0]
    assert len(ax.patches) == len(m["learned_edges"])
    assert {"act.finger", "dq.finger"} <= {t.get_text() for t in ax.texts}


def test_physics_effects_of_the_finger():
    data = collect(BabbleConfig(body="finger", steps=20, seed=0))
    effects = discovery_body.physics_effects(Realizer(data, JointData.select(data), "finger"), np.arange(4))
    assert set(effects) == {"q_prev.finger->dq.finger", "dq_prev.finger->dq.finger", "act.finger->dq.finger"}
    assert effects["act.finger->dq.finger"] > discovery_body.JUSTIFIED
    truth = discovery_body.physics_graph("finger", effects)
    assert ("act.finger", "dq.finger") in truth and ("q_prev.finger", "q.finger") in truth


def test_finger_quick_learns_the_graph_the_physics_justifies():
    rep = discovery_body.run(discovery_body.QUICK)
    m = rep.metrics
    assert ["dq_prev.finger", "dq.finger"] in m["physics_graph"]
    assert rep.target("shd_to_physics_graph").met and rep.target("b1_q_mse_learned_over_best_preset").met
    # the previous step's displacement roughly halves the one-step error of the state graph
    assert m["b1"]["dynamics"]["q_mse"] < 0.7 * m["b1"]["state"]["q_mse"] < 0.7 * m["b1"]["thesis"]["q_mse"]


def test_body_flags_reach_the_nested_body_choice(capsys):
    args = ["experiment", "discovery_body", "--json", "--quick", "--body", "arm"]
    args += ["--actuator", "elbow", "--actuator", "finger"]
    settings = ("protocol.data.body.joint=elbow", "protocol.data.steps=300", "protocol.data.cache=false")
    for setting in (*settings, "protocol.fit.schedule.epochs=2", "physics_rows=3"):
        args += ["--set", setting]
    assert main(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["config"]["protocol"]["data"]["body"] == {
        "body": "arm",
        "mjcf": None,
        "joint": "elbow",
        "actuator": ["elbow", "finger"],
        "frame_skip": 50,
        "action_range": [],
        "name": None,
        "effective_range": False,
    }
    assert doc["metrics"]["joint"] == "elbow" and doc["metrics"]["info"]["n_train"] == 240
    assert {t["name"]: t["met"] for t in doc["targets"]}["q_prev_to_dq"] is True


def test_body_cli_refuses_a_bad_setting_in_one_line(capsys):
    assert main(["experiment", "discovery_body", "--quick", "--set", "replicates=0"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "replicates must be a positive int, got 0" in err


@pytest.mark.slow
def test_active_design_tiny(tiny_run):
    rep = tiny_run("experiment", "active_design").report
    m = rep.metrics
    assert m["transitions"] == [20, 40] and m["seeds"] == [10]
    assert set(m["mechanism_mse"]) == set(active_design.STRATEGIES)
    assert m["fraction_to_random_final"]["random"] == 1.0
    # the first round is random babbling for every strategy on the same seed
    assert len({c[0] for c in m["mechanism_mse"].values()}) == 1
    assert m["mechanism_mse"]["random"][-1] < m["mechanism_mse"]["random"][0]
    assert [t.name for t in rep.targets] == [
        "share_to_random_final.curiosity",
        "share_to_random_final.active",
    ]
    for t in rep.targets:
        share = m["fraction_to_random_final"][t.name.rsplit(".", 1)[1]]
        assert t.value == (1.5 if share is None else share) and t.met == (t.value <= active_design.TARGET)
    assert [r[0] for r in rep.tables[0].rows] == list(active_design.STRATEGIES)
    ax = rep.figures["curves"].axes[0]
    assert ax.get_xlabel() == "transitions" and len(ax.lines) == len(active_design.STRATEGIES) + 1


@pytest.mark.slow
def test_bench_discovery_tiny(tiny_run):
    rep = tiny_run("bench", "discovery").report
    ctx = rep.metrics["context"]
    assert ctx["subgraph_variables"] == 4 and ctx["variables"] == 12
    assert rep.target("context.max_action_diff").met
    row = rep.metrics["discovery"]["5"]
    assert (row["ratio_grasp"] is None) != peers.available()
    assert row["shd"] == rep.tables[0].rows[0][2]
    assert rep.tables[1].rows[0][:2] == (12, 4)
