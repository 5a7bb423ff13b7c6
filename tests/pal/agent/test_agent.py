"""The closed loop (pal.agent) on the pushing world: a seeded run, lost objects, measurement sites, history."""

import warnings
from dataclasses import replace
from types import SimpleNamespace

import gymnasium
import numpy as np
import pytest
import torch

import pal.agent.estimate as estimate_module
from inference import SamplingConfig
from pal.agent import (
    Agent,
    AgentConfig,
    CuriosityConfig,
    EstimateConfig,
    ModelConfig,
    PlanConfig,
    pushing_spec,
)
from pal.agent.config import MODEL_SCHEDULE, PLAN_ACTION, PLAN_SAMPLING
from pal.agent.curiosity import GridCuriosity, grid_occupancy
from pal.agent.history import History
from pal.agent.perception import ObjectSlots, to_table
from pal.sim.pushing import PushingEnv

TINY = AgentConfig(
    model=ModelConfig(
        hidden=(8,), members=2, schedule=replace(MODEL_SCHEDULE, epochs=3, batch_size=64, patience=None)
    ),
    estimate=EstimateConfig(num_steps=5),
    plan=PlanConfig(
        action=replace(
            PLAN_ACTION, sampling=replace(PLAN_SAMPLING, population=8, elites=2, iterations=1, refine_steps=2)
        )
    ),
    curiosity=CuriosityConfig(
        sampling=SamplingConfig(population=8, elites=2, iterations=1), influence_samples=4
    ),
    reset_every=None,
)


class Sealed(gymnasium.Wrapper):
    """Only the Gymnasium interface: the agent cannot reach the simulator's ground-truth methods."""

    dt = 0.4

    @property
    def unwrapped(self):
        return self


@pytest.fixture(scope="module")
def env():
    e = PushingEnv(camera=True)
    yield e
    e.close()


@pytest.fixture(scope="module")
def fitted(env):
    """An agent that babbled 8 steps and fitted its world model."""
    agent = Agent(env, pushing_spec(), TINY, seed=1)
    agent.run(8, "babble")
    agent.refit()
    return agent


def short_run(env, seed, config=TINY, babble=4):
    """Babble, refit, two curious steps and one goal step, through the Gymnasium interface only."""
    agent = Agent(Sealed(env), pushing_spec(), config, seed=seed)
    decisions = agent.run(babble, "babble")
    agent.refit()
    decisions += agent.run(2, "curious")
    agent.goal = {"box": agent.estimate["box"] + np.array([0.03, 0.0])}
    decisions += agent.run(1, "goal")
    return agent, decisions


# the tiny agent's state estimate runs few SVI steps on purpose
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
@pytest.mark.slow
def test_seeded_loop_runs_end_to_end_through_the_gymnasium_interface_and_repeats(env):
    a, da = short_run(env, 0)
    b, db = short_run(env, 0)
    assert len(a.history) == 7 and [d.mode for d in da[:4]] == ["babble"] * 4
    assert {d.mode for d in da[4:6]} <= {"curious", "babble"} and da[6].mode in ("goal", "hold")
    for x, y in zip(da, db, strict=True):
        np.testing.assert_array_equal(x.action, y.action)
    np.testing.assert_array_equal(a.history.array("est"), b.history.array("est"))
    arm, objects = a.history.columns()
    for cols in (arm, *objects.values()):
        assert all(np.isfinite(v).all() for v in cols.values())
    # the truth the environment reports in info is kept for evaluation, and perception saw both objects near it
    meas, truth = a.history.array("meas"), a.history.array("truth")
    seen = np.isfinite(meas[..., 0])
    assert seen.mean() > 0.5 and np.all(np.linalg.norm(meas[seen] - truth[seen], axis=-1) < 0.06)
    assert a.history.array("state").shape == (7, env.state_size)


# the tiny agent's state estimate runs few SVI steps on purpose
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
@pytest.mark.slow
def test_a_lost_object_is_unobserved_and_no_nan_reaches_the_model(fitted, monkeypatch):
    agent = Agent(
        fitted.env,
        pushing_spec(),
        replace(TINY, estimate=EstimateConfig(num_steps=200)),
        seed=1,
        model=fitted.model,
    )
    agent.fitted = True
    agent.reset(seed=5)
    prev, est_prev = agent.percept, dict(agent.estimate)
    assert all(e is not None for e in est_prev.values())
    lost = replace(prev, measurements={**prev.measurements, "ball": None})
    seen = {}
    real = estimate_module.infer_state

    real_scale = estimate_module.MeasurementScale

    def spy(model, observed, **kwargs):
        seen["observed"] = observed
        return real(model, observed, **kwargs)

    def spy_scale(scales):
        seen["scale"] = scales
        return real_scale(scales)

    monkeypatch.setattr(estimate_module, "infer_state", spy)
    monkeypatch.setattr(estimate_module, "MeasurementScale", spy_scale)
    est = agent.estimator.update(agent.model, prev, est_prev, {}, lost, seed=0)
    assert "meas.ball" not in seen["observed"] and "meas.box" in seen["observed"]
    assert set(seen["scale"]) == {"meas.box"}
    assert all(np.isfinite(np.asarray(v)).all() for v in seen["observed"].values())
    assert np.isfinite(est["ball"]).all() and np.isfinite(est["box"]).all()
    # unobserved: the ball's estimate is the model's prediction, not pulled anywhere by perception
    blanket = agent.estimator.blanket(agent.model, ("box", "ball"))
    roots = {
        k: torch.as_tensor(np.asarray(v), dtype=torch.float32)
        for k, v in seen["observed"].items()
        if k in blanket.graph.roots
    }
    pred = blanket.predict(roots)
    np.testing.assert_allclose(est["ball"], pred["pos.ball"][0].numpy(), atol=0.01)


def test_poor_posteriors_are_counted_not_warned_per_step(fitted):
    """The agent filters every step with a small SVI budget: diagnostics are counted, not warned."""
    agent = Agent(fitted.env, pushing_spec(), replace(TINY, estimate=EstimateConfig(num_steps=1)), seed=1)
    agent.model, agent.fitted = fitted.model, True
    agent.reset(seed=5)
    prev, est_prev = agent.percept, dict(agent.estimate)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for seed in range(3):
            agent.estimator.update(agent.model, prev, est_prev, {}, prev, seed=seed)
    assert agent.estimator.updates == 3
    assert 1 <= agent.estimator.poor_posteriors <= 3  # one SVI step: the diagnostics fail


# the tiny agent's state estimate runs few SVI steps on purpose
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
@pytest.mark.parametrize("std", [1e-4, 1.0])
def test_measurement_sites_weigh_perception_by_its_uncertainty(fitted, std, weighs_measurements):
    agent = Agent(
        fitted.env,
        pushing_spec(),
        replace(TINY, estimate=EstimateConfig(num_steps=200)),
        seed=1,
        model=fitted.model,
    )
    weighs_measurements(agent, std)


def test_history_columns_drop_rows_with_missing_positions_and_round_trip(tmp_path):
    h = History(("shoulder", "elbow"), ("box", "ball"), velocities=True, momentum=True)
    nan = np.full(2, np.nan)
    for k in range(3):
        ball = nan if k == 1 else np.array([0.1, 0.2])
        row = {f: np.zeros((2, 2)) for f in ("est_prev", "est", "truth_prev", "truth", "vel_prev", "std")}
        row.update(
            episode=0,
            act=[0, 0],
            q_prev=[0, 0],
            q=[0.1, 0],
            v_prev=[0, 0],
            v=[1, 0],
            hand_prev=[0, 0, 0],
            hand=[0.01, 0, 0],
        )
        row.update(touch=[0, 0], meas_prev=[[0, 0], ball], meas=[[0, 0.01], ball], state=np.zeros(4))
        h.append(**row)
    arm, objects = h.columns("perceived")
    assert (
        len(arm["act"]) == 3 and len(objects["box"]["pos.box"]) == 3 and len(objects["ball"]["pos.ball"]) == 2
    )
    np.testing.assert_allclose(objects["box"]["rel.box"][0], [0.01, 0.0, 0.0])  # ee - [pos, 0]
    np.testing.assert_allclose(arm["dq"][0], [0.1, 0.0]) and np.testing.assert_allclose(
        arm["v"][0], [1.0, 0.0]
    )
    assert all(np.isfinite(v).all() for v in objects["ball"].values())
    loaded, meta = History.load(h.save(tmp_path / "h.npz"))
    assert loaded.options == h.options and meta["layout"]["momentum"] is True
    np.testing.assert_array_equal(loaded.array("vel_prev"), h.array("vel_prev"))
    with pytest.raises(ValueError, match="missing fields"):
        h.append(episode=0)


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


def test_density_curiosity_plans_towards_grid_targets(fitted):
    config = replace(TINY, curiosity=replace(TINY.curiosity, method="density"))
    agent = Agent(fitted.env, pushing_spec(), config, seed=2, model=fitted.model)
    agent.reset(seed=3)
    d = agent.decide("curious")
    assert d.mode in ("curious", "babble") and len(d.targets) == 1 and d.objective is not None


def test_bad_inputs(env, fitted):
    with pytest.raises(ValueError, match="epochs must be a positive int"):
        ModelConfig(schedule=replace(MODEL_SCHEDULE, epochs=0))
    with pytest.raises(ValueError, match="action.scale must be > 0"):
        PlanConfig(action=replace(PLAN_ACTION, scale=0.0))
    with pytest.raises(ValueError, match="population 8 is smaller than elites 9"):
        PlanConfig(action=replace(PLAN_ACTION, sampling=replace(PLAN_SAMPLING, population=8, elites=9)))
    with pytest.raises(ValueError, match="the agent plans with the sampling stage"):
        PlanConfig(action=replace(PLAN_ACTION, sampling=None))
    with pytest.raises(ValueError, match="call reset"):
        Agent(env, pushing_spec(), TINY).plan({"box": [0.0, 0.1]})
    with pytest.raises(ValueError, match="expected a finite \\(2,\\)"):
        fitted.plan({"box": [0.0, np.nan]})
    with pytest.raises(ValueError, match="unknown object"):
        fitted.plan({"boat": [0.0, 0.1]})
    with pytest.raises(ValueError, match="mode 'dream' unknown"):
        fitted.decide("dream")
    with pytest.raises(ValueError, match="steps must be a non-negative int"):
        fitted.run(-1)
    with pytest.raises(ValueError, match="seed must be a non-negative int"):
        Agent(env, pushing_spec(), TINY, seed=-1)
    with pytest.raises(ValueError, match="spec must be an EnvSpec"):
        Agent(env, TINY)
