"""The ``pusher`` experiment's model skips the cross-fitted calibration: its plans do not read the calibrated sd."""

from dataclasses import replace

import numpy as np
import pytest

from inference import CalibrationOptions
from pal.agent.plan import plan
from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher import PLAN, PUSH_MODEL

SMALL = pusher.TINY.model
SMALL_PLAN = replace(
    PLAN,
    action=replace(
        PLAN.action,
        horizon=4,
        sampling=replace(PLAN.action.sampling, population=16, elites=4, iterations=2),
    ),
)


def test_the_pusher_model_is_calibrated_on_its_validation_rows():
    assert PUSH_MODEL.schedule.calibration.folds is None


@pytest.mark.slow
def test_plans_are_the_same_with_and_without_the_cross_fitted_calibration(scripted_pusher_agent):
    """One scripted push, refitted with 5 calibration folds and without: the same plans, other sd."""
    out = {}
    for folds in (5, None):
        model = replace(SMALL, schedule=replace(SMALL.schedule, calibration=CalibrationOptions(folds=folds)))
        agent = scripted_pusher_agent(model)
        agent.refit()
        rule = agent.model.provenance["fit"]["sigma_rule"]["dpos.object"]
        goal = {"object": agent.percept.goals["object"]}
        found = plan(agent.model, agent.belief(), goal, SMALL_PLAN, seed=3)
        scale = agent.model.predict_scale(
            {k: np.asarray(v)[None] for k, v in agent.belief().items()} | {"act": np.zeros((1, 7))}
        )["dpos.object"]
        out[folds] = (rule, found.sequence, found.loss, float(scale.sum()))
    assert "out-of-fold" in out[5][0] and "out-of-fold" not in out[None][0]
    np.testing.assert_array_equal(out[5][1], out[None][1])
    assert out[5][2] == out[None][2]
    assert out[5][3] != out[None][3]  # the calibration did change the sd, which the plan does not read
