"""The ranking scores of the pusher experiment: an oracle ranks perfectly, a reversed model worst, a blind one not at all."""

from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch
from scipy.stats import spearmanr

from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher_ranking import RankingConfig, arm_forced_score, probes, score
from pal.experiments.closed_loop.pusher_runs import step_cost

PLAN = replace(
    pusher.PLAN,
    action=replace(
        pusher.PLAN.action,
        horizon=4,
        sampling=replace(pusher.PLAN.action.sampling, population=8, elites=2, iterations=1),
    ),
)
SMALL = RankingConfig(goals=1, steps=4, every=2, candidates=6)


@pytest.fixture(scope="module")
def found():
    env = gymnasium.make("Pusher-v5")
    out = probes(env, PLAN, SMALL, [3])
    env.close()
    return out


def _oracle(found, sign=1.0):
    cost = step_cost(PLAN)

    def predict(previous, obs, actions):
        p = next(p for p in found if p.obs is obs)
        true = cost(torch.as_tensor(p.truth), torch.as_tensor(actions)).sum(-1).numpy()
        return sign * true, p.truth[:, -1]

    return predict


def test_probes_hold_the_ceilings_plan_and_its_true_outcomes(found):
    assert len(found) == SMALL.steps // SMALL.every
    for p in found:
        assert p.actions.shape == (SMALL.candidates, 4, 7) and p.truth.shape == (SMALL.candidates, 4, 23)
        assert np.all(np.abs(p.actions) <= 2.0)
        assert not np.allclose(p.actions[0], p.actions[1])  # the candidates differ
        np.testing.assert_array_equal(p.obs[20:23], p.truth[0, -1, 20:23])  # the goal does not move


def test_an_oracle_ranks_perfectly_a_reversed_model_worst_and_a_blind_one_not_at_all(found):
    best = score(found, _oracle(found), PLAN)
    assert best["rho"] == pytest.approx(1.0, abs=1e-12) and best["regret"] == pytest.approx(0.0, abs=1e-12)
    assert best["probes"] == len(found)
    worst = score(found, _oracle(found, -1.0), PLAN)
    assert worst["rho"] == pytest.approx(-1.0, abs=1e-12) and worst["regret"] > 1.0

    def blind(previous, obs, actions):
        return np.zeros(len(actions)), np.tile(obs, (len(actions), 1))

    none = score(found, blind, PLAN)
    assert none["rho"] is None and none["rho_obj"] is None  # constant predictions rank nothing


class _GluedObject:
    """A model whose object sits on the fingertip it is given (two members); it logs the values it gets."""

    dtype = torch.float64

    def __init__(self) -> None:
        self.calls: list[dict] = []

    def predict(self, values, members=False):
        self.calls.append(values)
        return {"pos.object": values["ee"].expand(2, *values["ee"].shape)}


def test_the_arm_forced_score_sets_the_arm_to_the_truth_and_rolls_the_object_on(found):
    model = _GluedObject()
    got = arm_forced_score(found, model, PLAN)
    assert got["probes"] == len(found)
    p = found[0]
    for t in range(4):  # the first probe's steps: the arm is the candidates' true trajectory
        values = model.calls[t]
        np.testing.assert_array_equal(values["ee"].numpy(), p.truth[:, t, 14:17])
        np.testing.assert_array_equal(values["act"].numpy(), p.actions[:, t])
        previous = p.truth[:, t - 1, 14:17] if t else np.tile(p.obs[14:17], (len(p.actions), 1))
        np.testing.assert_array_equal(values["ee_prev"].numpy(), previous)
        if t:  # the object's own prediction feeds its next step
            np.testing.assert_array_equal(values["pos_prev.object"].numpy(), p.truth[:, t - 1, 14:17])
    # the object glued to the tip: the predicted trajectory is the truth with the object on the tip
    cost = step_cost(PLAN)
    expected = []
    for q in found:
        glued = q.truth.copy()
        glued[..., 17:20] = q.truth[..., 14:17]
        true, model_cost = (
            cost(torch.as_tensor(x), torch.as_tensor(q.actions)).sum(-1).numpy() for x in (q.truth, glued)
        )
        expected.append(spearmanr(true, model_cost).statistic)
    assert got["rho"] == pytest.approx(float(np.median(expected)), abs=1e-9)
    # its final x-y error is the tip's distance from the object at the end; the spread the truth's own
    gap = [np.sqrt(((q.truth[:, -1, 14:16] - q.truth[:, -1, 17:19]) ** 2).sum(-1).mean()) for q in found]
    ends = [q.truth[:, -1, 17:19] for q in found]
    spread = [np.sqrt(((e - e.mean(0)) ** 2).sum(-1).mean()) for e in ends]
    assert got["error"] == pytest.approx(float(np.median(gap)), rel=1e-9)
    assert got["spread"] == pytest.approx(float(np.median(spread)), rel=1e-9)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("candidates", 2, "ranking.candidates"),
        ("spread", 0.0, "ranking.spread"),
        ("goals", -1, "ranking.goals"),
    ],
)
def test_ranking_config_refuses_bad_values(field, value, match):
    with pytest.raises(ValueError, match=match):
        replace(RankingConfig(), **{field: value})
