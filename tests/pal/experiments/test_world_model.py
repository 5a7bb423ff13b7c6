"""Experiments B1-B3 and online exploration on MuJoCo bodies, at tiny sizes (seeded)."""

import json
from pathlib import Path

import numpy as np
import pytest

from inference import ActionOptions, FitSchedule, SamplingConfig
from pal.cli import main
from pal.experiments.world_model import b1, b2, b3, explore
from pal.experiments.world_model.data import (
    BodyChoice,
    DataConfig,
    JointData,
    Realizer,
    babble_or_load,
    pick_rows,
)
from pal.experiments.world_model.setup import (
    ActionConfig,
    FitConfig,
    ProtocolConfig,
    build_model,
    infer_actions,
)
from pal.sim.babbling import BabbleConfig, collect


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return str(tmp_path_factory.mktemp("pal-cache"))


def test_realizer_replays_recorded_transitions_and_counterfactual_commands():
    data = collect(BabbleConfig(body="arm", steps=60, seed=1))
    finger = JointData.select(data)
    assert (finger.joint, finger.actuator, finger.action_range) == ("finger", "finger", (-1.0, 0.33))
    realizer = Realizer(data, finger, "arm")
    rows = np.arange(5, 60, 6)
    recorded = data.columns["q.finger"][rows, 0]
    # the recorded command, with the 7 other motors' recorded commands, reproduces q(t) (float32 storage)
    np.testing.assert_allclose(
        realizer.outcomes(rows, data.ctrl[rows, finger.actuator_index]), recorded, atol=1e-6
    )
    # another command for the finger gives another outcome: the replay really executes it
    moved = realizer.outcomes(rows, np.full(len(rows), 0.33))
    assert np.all(moved > recorded - 1e-6) and np.abs(moved - recorded).max() > 0.1
    with pytest.raises(ValueError, match="one per row"):
        realizer.outcomes(rows, np.zeros(3))


def test_dataset_is_cached_by_body_steps_and_seed(cache_dir):
    cfg = DataConfig(steps=200, cache_dir=cache_dir)
    first = babble_or_load(cfg, 0)
    (path,) = [p for p in (Path(cache_dir) / "babble").iterdir() if "-n200-" in p.name]
    stamp = (path / "chunk_000000.npz").stat().st_mtime_ns
    again = babble_or_load(cfg, 0)
    assert (path / "chunk_000000.npz").stat().st_mtime_ns == stamp  # loaded, not babbled again
    np.testing.assert_array_equal(first.states, again.states)
    other = babble_or_load(cfg, 1)
    assert not np.array_equal(other.ctrl, first.ctrl)
    np.testing.assert_array_equal(collect(BabbleConfig(steps=200, seed=0)).ctrl, first.ctrl)


def _protocol(cache_dir, graphs=("thesis", "state", "dynamics"), body="finger"):
    return ProtocolConfig(
        DataConfig(BodyChoice(body), steps=3000, cache_dir=cache_dir),
        graphs=graphs,
        fit=FitConfig(schedule=FitSchedule(epochs=15, batch_size=256)),
    )


@pytest.mark.slow
def test_b1_reports_table_5_7_and_the_state_graph_wins(cache_dir):
    rep = b1.run(b1.Config(protocol=_protocol(cache_dir)))
    err = rep.metrics["error"]
    assert set(err) == {"thesis", "state", "dynamics", "persistence"}
    for graph in ("thesis", "state", "dynamics"):
        assert set(err[graph]) == {"dq_mse", "dq_mae", "q_mse", "q_mae"}
    # q_prev -> dq is a real parent: the state graph predicts far better, both beat persistence;
    # the previous step's displacement (the finger still moving) improves it again
    assert err["state"]["q_mse"] < 0.25 * err["thesis"]["q_mse"] < 0.25 * err["persistence"]["q_mse"]
    assert err["dynamics"]["q_mse"] < 0.9 * err["state"]["q_mse"]
    cal = rep.metrics["calibration"]
    assert set(cal) == {"thesis", "state", "dynamics"} and set(cal["state"]) == {"dq.finger", "q.finger"}
    for sites in cal.values():
        for c in sites.values():
            assert 0.8 < c["coverage"] <= 1.0 and c["n"] == 600  # sigma estimated on held-out rows
            nominal, observed = zip(*c["reliability"], strict=True)
            assert nominal[0] == 0.1 and nominal[-1] == 0.9 and list(observed) == sorted(observed)
    assert {"coverage_gap.thesis", "coverage_gap.state", "coverage_gap.dynamics"} <= {
        t.name for t in rep.targets
    }
    assert rep.target("q_mse_ratio").value == pytest.approx(err["state"]["q_mse"] / err["thesis"]["q_mse"])
    assert rep.target("q_mse_over_persistence").met is True
    table = rep.tables[0]
    assert (
        table.rows[1][:3] == ("Post-action position", 0.506, 0.554)
        and table.rows[2][0] == "Persistence baseline"
    )
    first, last = rep.metrics["train_loss"]["state"]["q"]
    assert last < first
    assert set(rep.figures) == {"training", "prediction", "reliability"}
    rel = rep.figures["reliability"].axes
    assert len(rel) == 3 and rel[0].get_xlabel() == "nominal coverage" and len(rel[0].get_lines()) == 3
    ax = rep.figures["prediction"].axes[0]
    assert ax.get_xlabel() == "recorded dq [rad]" and len(ax.collections[0].get_offsets()) == 600


@pytest.mark.slow
def test_b2_realized_errors_and_keys(cache_dir):
    rep = b2.run(b2.Config(protocol=_protocol(cache_dir), targets=24))
    err = rep.metrics["error"]
    assert set(err) == {"thesis", "state", "dynamics"}
    for graph in err:
        assert set(err[graph]) == {"random", "inferred"}
        assert set(err[graph]["random"]) == {"mae_model", "mae_real"}
        assert set(err[graph]["inferred"]) == {"mae_model", "mae_real", "within_005_real", "within_010_real"}
        inf = err[graph]["inferred"]
        assert 0 <= inf["within_005_real"] <= inf["within_010_real"] <= 1
        assert inf["mae_model"] < err[graph]["random"]["mae_model"]
    # the random actions are executed once: their realized error does not depend on the graph
    assert err["thesis"]["random"]["mae_real"] == err["state"]["random"]["mae_real"]
    assert err["state"]["inferred"]["mae_real"] < err["state"]["random"]["mae_real"]
    # with the sampling stage the state graph no longer stalls on the plateau at the flexion limit
    assert err["state"]["inferred"]["mae_real"] < 0.5 * err["thesis"]["inferred"]["mae_real"]
    thesis_protocol = b2.run(b2.Config(protocol=_protocol(cache_dir), targets=24, action=ActionConfig()))
    plain = thesis_protocol.metrics["error"]["state"]["inferred"]
    assert err["state"]["inferred"]["mae_model"] <= plain["mae_model"] + 1e-6
    assert set(rep.metrics["calibration"]["dynamics"]) == {"dq.finger", "q.finger"}
    assert rep.target("realized_mae.state").value == err["state"]["inferred"]["mae_real"]
    assert rep.tables[0].rows[2][1] == 0.797 and set(rep.figures) == {"fig5_6", "reliability"}
    ax = rep.figures["fig5_6"].axes[1]
    assert "realized in the simulator" in ax.get_title() and len(ax.collections[0].get_offsets()) == 24


def test_b3_keys_and_curiosity_targets(cache_dir):
    rep = b3.run(b3.Config(protocol=_protocol(cache_dir, graphs=("state",)), targets=40))
    assert set(rep.metrics["calibration"]) == {"state"}
    real = rep.metrics["realized"]
    assert set(real) == {"state"} and set(real["state"]) == {"random", "inferred"}
    for cond in ("random", "inferred"):
        assert set(real["state"][cond]) == {"occupancy", "entropy", "target_mae"}
        assert 0 < real["state"][cond]["occupancy"] <= 1
    # curiosity targets favour rare bins: spread wider than the training data's outcomes
    assert rep.metrics["target_entropy"] > rep.metrics["training"]["entropy"]
    assert real["state"]["inferred"]["target_mae"] < real["state"]["random"]["target_mae"]
    assert rep.tables[0].rows[1][:3] == ("training outcomes", "entropy H", 0.84)
    assert [t.name for t in rep.targets] == [
        "occupancy_gain.state",
        "entropy_gain.state",
        "coverage_gap.state",
    ]
    assert set(rep.figures) == {"fig5_7", "reliability"}


def test_explore_runs_both_conditions_and_reports_the_keys():
    cfg = explore.Config(
        runs=1,
        initial=5,
        budget=12,
        refit_every=6,
        fit=FitConfig(schedule=FitSchedule(epochs=20, batch_size=256)),
        action=ActionConfig(num_steps=10, starts=3),
    )
    rep = explore.run(cfg)
    m = rep.metrics
    for key in ("steps_to_full_occupancy", "entropy_at_budget", "occupancy_at_budget", "steps_per_seed"):
        assert set(m[key]) == {"curiosity", "random"}
    assert all(0 < m["occupancy_at_budget"][c] <= 1 for c in ("curiosity", "random"))
    fig = rep.figures["coverage"]
    line = fig.axes[0].get_lines()[1]  # random, mean occupancy over seeds
    assert len(line.get_ydata()) == 13 and np.all(np.diff(line.get_ydata()) >= 0)  # coverage never shrinks
    assert sum(p.get_height() for p in fig.axes[2].patches[: cfg.curiosity.bins]) == 17  # every visited angle counted
    assert rep.tables[0].rows[0][0] == "curiosity"


def test_coverage_curve_counts_bins_in_visiting_order():
    occ, ent = explore.coverage_curve(np.array([0.1, 0.1, 0.6, 0.9, 0.35]), 2, (0.0, 1.0), 4)
    np.testing.assert_allclose(occ, [0.25, 0.5, 0.75, 1.0])
    assert ent[0] == 0.0 and ent[-1] == pytest.approx(
        -(0.4 * np.log(0.4) + 3 * 0.2 * np.log(0.2)) / np.log(4)
    )


def test_multi_start_action_inference_keeps_the_best_start():
    data = collect(BabbleConfig(steps=400, seed=0))
    finger = JointData.select(data)
    model = build_model(finger, "state", (-3.0, 0.3), seed=0)
    q_prev, target = {"q_prev.finger": np.array([-2.0, -1.0])}, np.array([-1.5, -0.5])
    one = infer_actions(model, finger, q_prev, target, ActionConfig(num_steps=5))
    three = infer_actions(model, finger, q_prev, target, ActionConfig(num_steps=5, starts=3))
    assert np.all(np.abs(three[1] - target) <= np.abs(one[1] - target) + 1e-6)
    assert np.all((three[0] >= -1.0) & (three[0] <= 0.33))
    with pytest.raises(ValueError, match="starts must be a positive int"):
        ActionConfig(num_steps=5, starts=0)
    with pytest.raises(ValueError, match="population 8 is smaller than elites 16"):
        ActionConfig(options=ActionOptions(sampling=SamplingConfig(population=8)))
    sampled = infer_actions(
        model,
        finger,
        q_prev,
        target,
        ActionConfig(num_steps=5, options=ActionOptions(sampling=SamplingConfig(population=32, elites=4))),
    )
    # the sampling stage keeps its best candidate, so it is never worse under the model than Adam alone
    assert np.all(np.abs(sampled[1] - target) <= np.abs(one[1] - target) + 1e-6)


def test_bad_input_names_the_value():
    with pytest.raises(ValueError, match="unknown body 'hand'"):
        BodyChoice(body="hand")
    with pytest.raises(ValueError, match=r"graphs \['thesis', 'fancy'\] invalid"):
        ProtocolConfig(graphs=("thesis", "fancy"))
    with pytest.raises(ValueError, match="joint must be one name"):
        BodyChoice(joint=("finger", "elbow"))
    with pytest.raises(ValueError, match=r"steps must be an int in \[10, 100000000\], got 5"):
        DataConfig(steps=5)
    with pytest.raises(ValueError, match=rf"steps must be an int in \[10, 100000000\], got {10**15}"):
        DataConfig(steps=10**15)
    with pytest.raises(ValueError, match="targets must be a positive int, got 0"):
        b2.Config(targets=0)
    with pytest.raises(ValueError, match="graph 'fancy' unknown"):
        explore.Config(graph="fancy")
    data = collect(BabbleConfig(steps=20, seed=0))
    with pytest.raises(ValueError, match="unknown joint 'elbow'"):
        JointData.select(data, "elbow")
    with pytest.raises(ValueError, match="at least 1|>= 1"):
        pick_rows(10, 0, seed=0)


@pytest.mark.slow
def test_cli_runs_b1_on_the_arm_and_writes_outputs(tmp_path, capsys, cache_dir):
    argv = ["experiment", "b1", "--json", "--body", "arm", "--out", str(tmp_path)]
    argv += ["--set", "protocol.data.steps=2000", "--set", "protocol.fit.schedule.epochs=5"]
    argv += ["--set", f"protocol.data.cache_dir={cache_dir}"]
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out)
    assert set(printed["metrics"]["error"]) == {"thesis", "state", "dynamics", "persistence"}
    stored = json.loads((tmp_path / "b1.json").read_text())
    assert (
        stored["metrics"] == printed["metrics"]
        and stored["config"]["protocol"]["data"]["body"]["body"] == "arm"
    )
    assert stored["config"]["protocol"]["fit"]["schedule"]["epochs"] == 5
    assert [t["name"] for t in stored["targets"]][:2] == ["q_mse_ratio", "q_mse_over_persistence"]
    assert all(isinstance(t["met"], bool) for t in stored["targets"])
    md = (tmp_path / "b1.md").read_text()
    assert "Body arm, joint finger (action: actuator finger, 8 actuator(s) babbling)" in md
    assert (tmp_path / "b1_prediction.png").stat().st_size > 0
