"""Experiments B1-B3 and online exploration on MuJoCo bodies, at tiny sizes (seeded)."""

import json
from pathlib import Path

import numpy as np
import pytest

from pal.cli import main
from pal.experiments import b1, b2, b3, explore
from pal.experiments.wm_data import DataConfig, JointData, Realizer, babble_or_load, pick_rows
from pal.experiments.wm_setup import ProtocolConfig, build_model, infer_actions
from pal.sim.babbling import BabbleConfig, collect

TINY = {"steps": 3000, "epochs": 15, "batch_size": 256}


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
    cfg = DataConfig(steps=200, seed=0, cache_dir=cache_dir)
    first = babble_or_load(cfg)
    (path,) = [p for p in (Path(cache_dir) / "babble").iterdir() if "-n200-" in p.name]
    stamp = (path / "chunk_000000.npz").stat().st_mtime_ns
    again = babble_or_load(cfg)
    assert (path / "chunk_000000.npz").stat().st_mtime_ns == stamp  # loaded, not babbled again
    np.testing.assert_array_equal(first.states, again.states)
    other = babble_or_load(DataConfig(steps=200, seed=1, cache_dir=cache_dir))
    assert not np.array_equal(other.ctrl, first.ctrl)
    np.testing.assert_array_equal(collect(BabbleConfig(steps=200, seed=0)).ctrl, first.ctrl)


def test_b1_reports_table_5_7_keys_and_the_state_graph_wins(cache_dir):
    result = b1.run(b1.Config(**TINY, cache_dir=cache_dir))
    d = result.to_dict()
    assert set(d) == {"thesis", "state", "persistence"}
    for graph in ("thesis", "state"):
        assert set(d[graph]) == {"dq_mse", "dq_mae", "q_mse", "q_mae"}
    assert set(d["persistence"]) == {"q_mse", "q_mae"}
    # q_prev -> dq is a real parent: the state graph predicts far better, both beat persistence
    assert d["state"]["q_mse"] < 0.25 * d["thesis"]["q_mse"] < 0.25 * d["persistence"]["q_mse"]
    md = result.to_markdown()
    assert "| Post-action position | 0.506 | 0.554 |" in md and "Persistence baseline" in md
    assert set(result.figures()) == {"training", "prediction"}


def test_b2_realized_errors_and_keys(cache_dir):
    result = b2.run(b2.Config(**TINY, targets=24, cache_dir=cache_dir))
    d = result.to_dict()
    assert set(d) == {"thesis", "state"}
    for graph in d:
        assert set(d[graph]) == {"random", "inferred"}
        assert set(d[graph]["random"]) == {"mae_model", "mae_real"}
        assert set(d[graph]["inferred"]) == {"mae_model", "mae_real", "within_005_real", "within_010_real"}
        inf = d[graph]["inferred"]
        assert 0 <= inf["within_005_real"] <= inf["within_010_real"] <= 1
        assert inf["mae_model"] < d[graph]["random"]["mae_model"]
    # the random actions are executed once: their realized error does not depend on the graph
    assert d["thesis"]["random"]["mae_real"] == d["state"]["random"]["mae_real"]
    assert d["state"]["inferred"]["mae_real"] < d["state"]["random"]["mae_real"]
    assert "79.7 %" in result.to_markdown() and set(result.figures()) == {"fig5_6"}


def test_b3_keys_and_curiosity_targets(cache_dir):
    result = b3.run(b3.Config(**TINY, targets=40, graphs=("state",), cache_dir=cache_dir))
    d = result.to_dict()
    assert set(d) == {"state", "target_entropy"}
    assert set(d["state"]) == {"random", "inferred"}
    for cond in ("random", "inferred"):
        assert set(d["state"][cond]) == {"occupancy_real", "entropy_real", "target_mae_real"}
        assert 0 < d["state"][cond]["occupancy_real"] <= 1
    # curiosity targets favour rare bins: spread wider than the training data's outcomes
    assert d["target_entropy"] > result.training["entropy"]
    assert d["state"]["inferred"]["target_mae_real"] < d["state"]["random"]["target_mae_real"]
    assert "| training outcomes | entropy H | 0.84 |" in result.to_markdown()
    assert set(result.figures()) == {"fig5_7"}


def test_explore_runs_both_conditions_and_reports_the_keys():
    cfg = explore.Config(seeds=(0,), initial=5, budget=12, refit_every=6, epochs=20, action_steps=10)
    result = explore.run(cfg)
    d = result.to_dict()
    assert set(d) == {"steps_to_full_occupancy", "entropy_at_budget"}
    for key in d:
        assert set(d[key]) == {"curiosity", "random"}
    assert result.occupancy["curiosity"].shape == (1, 13)
    assert np.all(np.diff(result.occupancy["random"][0]) >= 0)  # coverage never shrinks
    assert len(result.visited["curiosity"]) == 17
    assert "curiosity" in result.to_markdown() and set(result.figures()) == {"coverage"}


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
    q_prev, target = np.array([-2.0, -1.0]), np.array([-1.5, -0.5])
    one = infer_actions(model, finger, q_prev, target, steps=5, lr=0.05)
    three = infer_actions(model, finger, q_prev, target, steps=5, lr=0.05, starts=3)
    assert np.all(np.abs(three[1] - target) <= np.abs(one[1] - target) + 1e-6)
    assert np.all((three[0] >= -1.0) & (three[0] <= 0.33))
    with pytest.raises(ValueError, match="starts must be a positive int"):
        infer_actions(model, finger, q_prev, target, steps=5, lr=0.05, starts=0)


def test_bad_input_names_the_value():
    with pytest.raises(ValueError, match="unknown body 'hand'"):
        b1.Config(body="hand")
    with pytest.raises(ValueError, match=r"graphs \['thesis', 'fancy'\] invalid"):
        b2.Config(graphs=("thesis", "fancy"))
    with pytest.raises(ValueError, match="joint must be one name"):
        ProtocolConfig(joint=("finger", "elbow"))
    with pytest.raises(ValueError, match="steps must be an int >= 10"):
        b3.Config(steps=5)
    with pytest.raises(ValueError, match="graph 'fancy' unknown"):
        explore.Config(graph="fancy")
    data = collect(BabbleConfig(steps=20, seed=0))
    with pytest.raises(ValueError, match="unknown joint 'elbow'"):
        JointData.select(data, "elbow")
    with pytest.raises(ValueError, match="at least 1|>= 1"):
        pick_rows(10, 0, seed=0)


def test_cli_runs_b1_on_the_arm_and_writes_outputs(tmp_path, capsys, cache_dir):
    argv = ["experiment", "b1", "--json", "--body", "arm", "--out", str(tmp_path)]
    argv += ["--set", "steps=2000", "--set", "epochs=5", "--set", f"cache_dir={cache_dir}"]
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out)
    assert set(printed) == {"thesis", "state", "persistence"}
    stored = json.loads((tmp_path / "b1.json").read_text())
    assert stored["result"] == printed and stored["config"]["body"] == "arm"
    assert (
        "Body `arm`, joint `finger` (action: actuator `finger`, 8 actuator(s) babbling)"
        in (tmp_path / "b1.md").read_text()
    )
    assert (tmp_path / "b1_prediction.png").stat().st_size > 0
