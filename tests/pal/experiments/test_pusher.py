"""The pusher experiment on Gymnasium's Pusher-v5, its PETS-style baseline and aggregation learner (tiny budgets)."""

import json
from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch

from pal.agent import PlanConfig, pusher_spec
from pal.agent.aggregate import AggregationConfig, Exploration, episode_seed, run_rounds
from pal.agent.graph import contact_rule
from pal.baselines.pets import BaselineConfig, CEMPlanner, ProbabilisticEnsemble
from pal.baselines.pets_aggregate import PetsLearner
from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher_metrics import block, targets
from pal.experiments.closed_loop.pusher_runs import Episode, step_cost


@pytest.mark.slow
def test_pusher_reports_checkpoint_rows_for_three_controllers_and_does_not_evaluate_unmoved_ratios(tiny_run):
    rep = tiny_run("experiment", "pusher").report
    m, agg = rep.metrics, pusher.TINY.aggregation
    assert m["checkpoints"] == list(agg.checkpoints)
    curve = rep.tables[0]
    assert [(r[0], r[1]) for r in curve.rows] == [(p, c) for p in agg.checkpoints for c in pusher.CONTROLLERS]
    for point in agg.checkpoints:
        row = m["at"][str(point)]
        for c in pusher.CONTROLLERS:
            assert row[c]["episodes"] == pusher.TINY.eval_goals * pusher.TINY.runs
            assert (
                row[c]["final_planar"]["median"] <= row[c]["final_distance"]["median"]
            )  # the goal sits lower
        for c in ("pal", "baseline"):
            # scored after the refit that reached the point: the first episode, then the whole budget with its branch
            assert row[c]["env_steps"] == [
                {agg.checkpoints[0]: agg.episode_steps, agg.checkpoints[1]: agg.budget}[point]
            ]
            assert row[c]["predicted_final"]["mean"] is not None
            ranking = row[c]["ranking"]  # one probe of the ceiling's episode, 4 candidates
            assert ranking["probes"] == 1 and -1.0 <= ranking["rho"] <= 1.0 and ranking["regret"] >= 0.0
    for c in ("pal", "baseline"):
        counts = m["training"][c]["counts"][0]
        assert counts == {
            "env_steps": agg.budget,
            "episodes": agg.rounds,
            "random_episodes": 1,
            "branches": agg.rounds - 1,  # one start per model episode
            "branch_steps": agg.branching.steps_per_episode(agg.episode_steps) * (agg.rounds - 1),
            "refits": agg.rounds,
            "warm_refits": agg.rounds - 1,
        }
    # three tiny steps move nothing: every ratio and the full-budget targets are not evaluated
    verdicts = {t.name: t.verdict for t in rep.targets}
    assert verdicts[f"pal_over_baseline_at_{agg.checkpoints[0]}"] == "not evaluated"
    assert (
        verdicts["pal_median_final"] == "not evaluated"
        and verdicts["pal_step_cpu_seconds"] == "not evaluated"
    )
    assert all(v != "met" for v in verdicts.values())
    assert rep.tables[1].title.startswith("How each learner's model ranks candidate plans")
    assert len(rep.tables[1].rows) == 2 * len(agg.checkpoints)
    assert rep.figures["learning_curve"].axes[0].get_xlabel() == "environment steps"
    # one goal: tip and object of each controller, their starts, and the goal
    assert len(rep.figures["paths"].axes[0].get_lines()) == 3 * len(pusher.CONTROLLERS) + 1
    assert rep.figures["paths"].get_suptitle() == (
        f"seed {pusher.TINY.seed}: the first evaluation goals after {agg.checkpoints[-1]} environment steps"
    )
    json.dumps(rep.metrics, allow_nan=False)


def test_the_baseline_aggregates_its_own_episodes_with_warm_refits():
    env = gymnasium.make("Pusher-v5")
    plan = pusher.TINY.plan
    learner = PetsLearner(
        env, BaselineConfig(members=2, hidden=(8,), epochs=1), plan, step_cost(plan), seed=0
    )
    result = run_rounds(learner, AggregationConfig(rounds=3, episode_steps=4), seed=0)
    env.close()
    assert result.counts.to_dict() == {
        "env_steps": 12,
        "episodes": 3,
        "random_episodes": 1,
        "branches": 0,
        "branch_steps": 0,
        "refits": 3,
        "warm_refits": 2,
    }
    assert len(learner.data[0]) == 12
    first, *later = result.episodes
    assert len(first.predicted) == 0 and all(len(e.predicted) == 4 for e in later)  # random first, then CEM
    assert all(e.observations.shape == (5, 23) for e in result.episodes)


def test_the_baseline_executes_its_plan_plus_the_same_episode_noise_as_the_agent():
    env = gymnasium.make("Pusher-v5")
    plan = pusher.TINY.plan
    learner = PetsLearner(
        env, BaselineConfig(members=2, hidden=(8,), epochs=1), plan, step_cost(plan), seed=0
    )
    planned, act = [], learner.planner.act

    def spy(obs):
        a, final = act(obs)
        planned.append(a)
        return a, final

    learner.planner.act = spy
    noise = Exploration(sd=0.05)
    run_rounds(learner, AggregationConfig(rounds=2, episode_steps=4, exploration=noise), seed=0)
    env.close()
    seed = episode_seed(0, 1)
    expected = np.clip(np.stack(planned) + noise.offsets(seed, 4, learner.low, learner.high), -2, 2)
    np.testing.assert_allclose(np.stack(learner.data[1][4:]), expected, atol=1e-12)
    assert np.abs(expected - np.stack(planned)).max() > 0.01


def test_the_baseline_learns_a_linear_system_and_plans_with_it():
    g = np.random.default_rng(0)
    obs = g.normal(size=(400, 3))
    act = g.uniform(-1, 1, size=(400, 2))
    nxt = obs + 0.3 * np.concatenate([act, act[:, :1]], 1)
    model = ProbabilisticEnsemble(3, 2, BaselineConfig(members=2, hidden=(32,), epochs=200), seed=0)
    losses = model.fit(obs, act, nxt)
    assert losses[-1] < losses[0]
    x = torch.as_tensor(obs[:50], dtype=torch.float32).expand(2, 50, 3)
    a = torch.as_tensor(act[:50], dtype=torch.float32).expand(2, 50, 2)
    with torch.no_grad():
        err = (model(x, a) - torch.as_tensor(nxt[:50], dtype=torch.float32)).abs().mean()
    assert float(err) < 0.05
    # drive the first coordinate to 0: CEM picks the action that moves it there
    cost = lambda o, a: o[..., 0].abs()  # noqa: E731
    config = PlanConfig()  # horizon 2, population 64, 8 elites, 3 iterations
    planner = CEMPlanner(model, -np.ones(2), np.ones(2), config, cost, seed=0)
    action, final = planner.act(np.array([0.4, 0.0, 0.0]))
    assert action[0] < -0.3 and abs(final[0]) < 0.15


def _episode(final: float, moved: float) -> Episode:
    return Episode(
        final,
        final,
        0.2,
        0.1,
        0.01,
        0.01,
        [[0.1, 0.1], [0.1 + moved, 0.1]],
        [[0.0, 0.0]] * 2,
        [0.0, 0.0],
        0.3,
        moved,
    )


def _at(moved: dict[str, list[float]]) -> dict:
    """One checkpoint's scores where controller c moves the object by moved[c][g] metres on goal g."""
    return {"6000": {c: block([[_episode(0.2 - d, d) for d in v]], 0.05) for c, v in moved.items()}}


def test_a_ratio_counts_only_when_pal_moved_the_object_in_90_percent_and_the_baseline_at_all():
    config = replace(
        pusher.TINY, runs=3, eval_goals=20, aggregation=AggregationConfig(rounds=60, checkpoints=(6000,))
    )
    still = {t.name: t for t in targets(config, _at({"pal": [0.0] * 10, "baseline": [0.0] * 10}), 0.3)}
    ratio = still["pal_over_baseline_at_6000"]
    assert ratio.value == 1.0 and ratio.verdict == "not evaluated" and ratio.met is False
    assert "moved > 5 mm" in ratio.precondition.reason
    some = {
        t.name: t for t in targets(config, _at({"pal": [0.1] * 8 + [0.0] * 2, "baseline": [0.02] * 10}), 0.3)
    }
    assert some["pal_over_baseline_at_6000"].verdict == "not evaluated"  # pal moved it in 80 % only
    both = {
        t.name: t
        for t in targets(config, _at({"pal": [0.1] * 9 + [0.0], "baseline": [0.0] * 9 + [0.02]}), 0.3)
    }
    t = both["pal_over_baseline_at_6000"]
    assert t.evaluated and t.verdict == "met" and t.value == pytest.approx(0.1 / 0.2)
    assert both["pal_median_final"].evaluated  # 6000 steps, 3 seeds x 20 goals: the full protocol
    assert both["pal_step_cpu_seconds"].value == 0.3  # the training episodes' median, given
    # one seed of 5 goals is too small a sample for the ratio, however much moved
    small = replace(config, runs=1, eval_goals=5)
    few = {
        t.name: t
        for t in targets(small, _at({"pal": [0.1] * 9 + [0.0], "baseline": [0.0] * 9 + [0.02]}), 0.3)
    }
    assert few["pal_over_baseline_at_6000"].verdict == "not evaluated"
    assert "this run: 1 x 5" in few["pal_over_baseline_at_6000"].precondition.reason
    assert few["pal_median_final"].verdict == "not evaluated"


def test_the_pusher_model_labels_a_push_of_a_few_millimetres_as_contact():
    rule, floor = contact_rule(pusher_spec(), pusher.MODEL)
    # a push moves Pusher-v5's object at most ~3.4 mm per step: the floor must sit well below it
    assert rule == "moved" and floor == pytest.approx(3e-4, abs=1e-12)


def test_the_agents_half_runs_with_mjcf_kinematics_and_the_online_correction():
    from pal.agent import CorrectionConfig
    from pal.experiments.closed_loop.pusher_protocol import _pal

    config = replace(
        pusher.TINY,
        model=replace(pusher.TINY.model, kinematics="mjcf"),
        correction=CorrectionConfig(enabled=True),
        lockstep=False,
    )
    out = _pal(config, 0, goals=[7])
    assert out["counts"]["env_steps"] == config.aggregation.budget
    for point in config.aggregation.checkpoints:
        (episode,) = out["at"][point]["episodes"]
        assert len(episode.path) == config.aggregation.episode_steps + 1 and episode.cpu is not None
    with pytest.raises(ValueError, match="correction must be a CorrectionConfig, got int"):
        replace(pusher.TINY, correction=1)


def test_the_agents_goals_are_evaluated_in_lockstep_and_its_step_time_comes_from_training():
    from pal.experiments.closed_loop.pusher_metrics import summarise
    from pal.experiments.closed_loop.pusher_protocol import _pal

    assert pusher.Config().lockstep is True
    out = _pal(pusher.TINY, 0, goals=[7, 8, 9])
    for point in pusher.TINY.aggregation.checkpoints:
        episodes = out["at"][point]["episodes"]
        assert len(episodes) == 3 and all(
            e.cpu is None for e in episodes
        )  # a batch's step is not one agent's
        assert all(len(e.path) == pusher.TINY.aggregation.episode_steps + 1 for e in episodes)
        assert len({e.start_planar for e in episodes}) == 3  # three goals, not one run thrice
    cpu = [e.cpu for e in out["training"] if e.cpu is not None]
    assert cpu and out["training"][0].cpu is None  # the random first round plans nothing
    per_seed = {
        0: {
            "pal": out,
            "baseline": out,
            "simulator": out["at"][pusher.TINY.aggregation.checkpoints[0]]["episodes"],
            "random": out["at"][pusher.TINY.aggregation.checkpoints[0]]["episodes"],
        }
    }
    config = replace(pusher.TINY, eval_goals=3)
    rep = summarise(config, per_seed)
    assert rep.target("pal_step_cpu_seconds").value == pytest.approx(float(np.median(cpu)))
    with pytest.raises(ValueError, match="lockstep must be a bool, got 1"):
        replace(pusher.TINY, lockstep=1)
