"""The closed loop (pal.agent): a seeded end-to-end run, lost objects, measurement sites, bad input."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch

import pal.agent.loop as agent_module
from pal.agent import Agent, AgentConfig, candidate_actions
from pal.agent.curiosity import GridCuriosity, grid_occupancy
from pal.agent.history import History
from pal.agent.perception import Measurement, ObjectSlots, to_table
from pal.sim.pushing import PushingEnv

TINY = AgentConfig(
    epochs=3,
    batch_size=64,
    hidden=(8,),
    state_steps=5,
    action_steps=5,
    action_starts=4,
    reset_every=None,
    refit_every=1000,
)


@pytest.fixture(scope="module")
def env():
    e = PushingEnv()
    yield e
    e.close()


@pytest.fixture(scope="module")
def fitted(env):
    """An agent that babbled 8 steps and fitted its world model."""
    agent = Agent(env, TINY, seed=1)
    agent.run(8, "babble")
    agent.refit()
    return agent


def short_run(env, seed):
    agent = Agent(env, TINY, seed=seed)
    decisions = agent.run(4, "babble")
    agent.refit()
    decisions += agent.run(2, "curious")
    agent.goal = {"box": agent.estimate["box"] + np.array([0.03, 0.0])}
    decisions += agent.run(1, "goal")
    return agent, decisions


def test_seeded_loop_runs_end_to_end_and_repeats_exactly(env):
    a, da = short_run(env, 0)
    b, db = short_run(env, 0)
    assert len(a.history) == 7 and [d.mode for d in da[:4]] == ["babble"] * 4
    assert {d.mode for d in da[4:6]} <= {"curious", "babble"} and da[6].mode in ("goal", "setup", "hold")
    for x, y in zip(da, db, strict=True):
        np.testing.assert_array_equal(x.action, y.action)
    np.testing.assert_array_equal(a.history.array("est"), b.history.array("est"))
    arm, objects = a.history.columns()
    for cols in (arm, *objects.values()):
        assert all(np.isfinite(v).all() for v in cols.values())
    # the truth is recorded for evaluation, and perception saw both objects near it
    meas, truth = a.history.array("meas"), a.history.array("truth")
    seen = np.isfinite(meas[..., 0])
    assert seen.mean() > 0.5 and np.all(np.linalg.norm(meas[seen] - truth[seen], axis=-1) < 0.06)


def test_a_lost_object_is_unobserved_and_no_nan_reaches_the_model(fitted, monkeypatch):
    agent = Agent(fitted.env, replace(TINY, state_steps=200), seed=1, model=fitted.model)
    agent.reset(seed=5)
    prev, est_prev = agent.percept, dict(agent.estimate)
    assert all(e is not None for e in est_prev.values())
    lost = replace(prev, measurements={**prev.measurements, "ball": None})
    seen = {}
    real = agent_module.infer_state

    def spy(model, observed, **kwargs):
        seen["observed"], seen["scale"] = observed, kwargs.get("measurement_scale")
        return real(model, observed, **kwargs)

    monkeypatch.setattr(agent_module, "infer_state", spy)
    est = agent.state_posterior(prev, est_prev, lost, np.zeros(2))
    assert "meas.ball" not in seen["observed"] and "meas.box" in seen["observed"]
    assert set(seen["scale"]) == {"meas.box"}
    assert all(np.isfinite(np.asarray(v)).all() for v in seen["observed"].values())
    assert np.isfinite(est["ball"]).all() and np.isfinite(est["box"]).all()
    # unobserved: the ball's estimate is the model's prediction, not pulled anywhere by perception
    blanket = agent._blanket(("box", "ball"))
    pred = blanket.predict(
        {
            k: torch.as_tensor(np.asarray(v), dtype=torch.float32)
            for k, v in seen["observed"].items()
            if k in blanket.graph.roots
        }
    )
    np.testing.assert_allclose(est["ball"], pred["pos.ball"][0].numpy(), atol=0.01)


def test_history_drops_rows_with_missing_positions():
    h = History(("shoulder", "elbow"), ("box", "ball"))
    nan = np.full(2, np.nan)
    for k in range(3):
        ball = nan if k == 1 else np.array([0.1, 0.2])
        h.append(
            episode=0,
            act=[0, 0],
            q_prev=[0, 0],
            q=[0, 0],
            hand_prev=[0, 0, 0],
            hand=[0, 0, 0],
            touch=[0, 0],
            meas_prev=[[0, 0], ball],
            meas=[[0, 0], ball],
            std=[[0.01, 0.01], ball],
            est_prev=[[0, 0], [0, 0]],
            est=[[0, 0], [0, 0]],
            truth_prev=[[0, 0], [0, 0]],
            truth=[[0, 0], [0, 0]],
            state=np.zeros(4),
        )
    arm, objects = h.columns("perceived")
    assert (
        len(arm["act.shoulder"]) == 3
        and len(objects["box"]["pos.box"]) == 3
        and len(objects["ball"]["pos.ball"]) == 2
    )
    assert all(np.isfinite(v).all() for v in objects["ball"].values())
    with pytest.raises(ValueError, match="missing fields"):
        h.append(episode=0)


def test_history_round_trips_through_npz(fitted, tmp_path):
    path = fitted.history.save(tmp_path / "h.npz", metadata={"seed": 1})
    loaded, meta = History.load(path)
    assert (
        meta["seed"] == 1 and loaded.objects == fitted.history.objects and len(loaded) == len(fitted.history)
    )
    np.testing.assert_array_equal(loaded.array("state"), fitted.history.array("state"))
    np.testing.assert_array_equal(loaded.array("meas"), fitted.history.array("meas"))


@pytest.mark.parametrize("std", [1e-4, 1.0])
def test_measurement_sites_weigh_perception_by_its_uncertainty(fitted, std):
    agent = Agent(fitted.env, replace(TINY, state_steps=200), seed=1, model=fitted.model)
    agent.reset(seed=5)
    prev, est_prev = agent.percept, dict(agent.estimate)
    offset = np.array([0.02, -0.015])
    shifted = {
        o: replace(m, position=m.position + offset, std=np.full(2, std)) for o, m in prev.measurements.items()
    }
    est = agent.state_posterior(prev, est_prev, replace(prev, measurements=shifted), np.zeros(2))
    blanket = agent._blanket(("box", "ball"))
    roots = {"hand_prev": prev.hand[None], "hand": prev.hand[None]}
    roots.update({f"pos_prev.{o}": est_prev[o][None] for o in est_prev})
    roots.update({f"contact.{o}": np.zeros((1, 1)) for o in est_prev})
    pred = blanket.predict(
        {k: torch.as_tensor(v, dtype=torch.float32) for k, v in roots.items() if k in blanket.graph.roots}
    )
    for o in ("box", "ball"):
        if std < 0.01:  # a sharp measurement wins
            np.testing.assert_allclose(est[o], shifted[o].position, atol=0.004)
        else:  # a vague one is ignored: the model's prediction stays (within the short SVI's noise)
            p = pred[f"pos.{o}"][0].numpy()
            assert np.linalg.norm(est[o] - p) < 0.01 < np.linalg.norm(est[o] - shifted[o].position)


def test_slots_bind_by_size_then_follow_ids_and_rebind_lost_ones():
    def state(objs):
        objects = {
            oid: SimpleNamespace(mask=SimpleNamespace(area=area), position_source="centroid")
            for oid, (_, area) in objs.items()
        }
        return SimpleNamespace(
            observations=lambda: {
                oid: (np.array([x, y, 1.0]), np.full(3, 0.01)) for oid, ((x, y), _) in objs.items()
            },
            object=lambda oid: objects[oid],
        )

    T = np.eye(4)
    slots = ObjectSlots(("box", "ball"))
    out = slots.update(state({1: ((0.0, 0.1), 900), 2: ((0.2, 0.1), 2000)}), T)
    assert slots.bound == {"box": 2, "ball": 1} and out["box"].obj_id == 2
    out = slots.update(state({2: ((0.2, 0.1), 2000)}), T)
    assert out["ball"] is None and out["box"] is not None  # lost, not NaN
    out = slots.update(state({2: ((0.2, 0.1), 2000), 7: ((0.05, 0.12), 950)}), T)
    assert slots.bound["ball"] == 7 and out["ball"].obj_id == 7
    p, s = to_table(np.array([0.1, 0.0, 0.5]), np.array([0.01, 0.02, 0.03]), np.eye(4))
    np.testing.assert_allclose(p, [0.1, 0.0, 0.5]) and np.testing.assert_allclose(s, [0.01, 0.02, 0.03])
    with pytest.raises(ValueError, match="distinct and non-empty"):
        ObjectSlots(("box", "box"))


def test_grid_curiosity_prefers_unvisited_cells(rng):
    cur = GridCuriosity((0.0, 0.0), (1.0, 1.0), bins=(4, 4), alpha=0.0)
    cur.partial_fit(rng.uniform(0, 0.5, size=(200, 2)))  # only the lower-left quarter is visited
    targets = np.array([cur.sample(rng, [0.25, 0.25]) for _ in range(200)])
    assert np.mean(np.any(targets > 0.5, axis=1)) > 0.9 and cur.occupancy() == pytest.approx(4 / 16)
    assert grid_occupancy([[0.1, 0.1], [0.9, 0.9], [2.0, 2.0]], (0, 0), (1, 1), (2, 2)) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="NaN or inf"):
        cur.partial_fit([[np.nan, 0.0]])
    with pytest.raises(ValueError, match="low < high"):
        GridCuriosity((0, 0), (0, 1))


def test_candidate_actions_stay_in_range(rng):
    a = candidate_actions(np.zeros(2), np.array([-1.0, -2.0]), np.array([1.0, 0.1]), rng, 16)
    assert a.shape == (16, 2) and np.all(a >= [-1.0, -2.0]) and np.all(a <= [1.0, 0.1])


def test_bad_inputs(env, fitted):
    with pytest.raises(ValueError, match="epochs must be a positive int"):
        AgentConfig(epochs=0)
    with pytest.raises(ValueError, match="target_scale must be > 0"):
        AgentConfig(target_scale=0.0)
    with pytest.raises(ValueError, match="not in the environment"):
        Agent(env, AgentConfig(objects=("boat",)))
    with pytest.raises(ValueError, match="call reset"):
        Agent(env, TINY).plan({"box": [0.0, 0.1]})
    with pytest.raises(ValueError, match="expected a finite \\(x, y\\)"):
        fitted.plan({"box": [0.0, np.nan]})
    with pytest.raises(ValueError, match="unknown object"):
        fitted.plan({"boat": [0.0, 0.1]})
    with pytest.raises(ValueError, match="mode 'dream' unknown"):
        fitted.decide("dream")
    with pytest.raises(ValueError, match="steps must be a non-negative int"):
        fitted.run(-1)
    with pytest.raises(ValueError, match="body_mask has shape"):
        agent_module.self_filtered_frame(
            np.zeros((4, 4, 3), np.uint8),
            np.zeros((4, 4), np.float32),
            np.eye(3),
            0.0,
            np.zeros((2, 2), bool),
        )
    with pytest.raises(ValueError, match="seed must be a non-negative int"):
        Agent(env, TINY, seed=-1)


def test_a_visible_object_is_measured_and_a_hidden_one_is_not(env):
    agent = Agent(env, TINY, seed=1)
    agent.reset(seed=5)
    assert all(m is not None for m in agent.percept.measurements.values())  # both seen: slots bound
    pose = env.object_poses()["box"]
    box = (pose[0, 3], pose[1, 3], np.degrees(np.arctan2(pose[1, 0], pose[0, 0])))
    # the box stays where it is, the ball goes to the table's right edge, outside the camera's view
    env.reset(seed=5, options={"objects": {"box": box, "ball": (0.40, -0.02, 0.0)}})
    percept = agent.perceive()
    m = percept.measurements["box"]
    assert isinstance(m, Measurement) and m.position.shape == (2,) and m.std.shape == (2,)
    assert np.isfinite(m.position).all() and np.all(m.std > 0) and m.obj_id == agent.slots.bound["box"]
    assert np.linalg.norm(m.position - env.object_positions()["box"][:2]) < 0.03
    assert percept.measurements["ball"] is None
