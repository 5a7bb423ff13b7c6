"""The open-loop drift experiment on Pusher-v5 (tiny sizes): a table per checkpoint and refused settings."""

from dataclasses import replace

import numpy as np
import pytest

from pal.experiments.closed_loop import pusher_drift


@pytest.mark.slow
def test_pusher_drift_scores_each_checkpoint_against_the_tip_staying_put(tiny_run):
    rep = tiny_run("experiment", "pusher-drift").report
    m, tiny = rep.metrics, pusher_drift.TINY
    assert m["starts"] == tiny.test_episodes * len(range(1, 100 - tiny.rollout_steps + 1, tiny.stride))
    assert [r[0] for r in rep.tables[0].rows] == list(tiny.steps)
    for k in tiny.steps:
        row = m["steps"][str(k)]
        assert all(np.isfinite(v) and v >= 0 for v in row.values())
        assert row["tip_stays"] > 0  # colored-noise torques move the arm
    # errors grow with the open-loop horizon
    first, last = (m["steps"][str(k)] for k in (tiny.steps[0], tiny.steps[-1]))
    assert last["tip_stays"] > first["tip_stays"]
    assert 0.0 <= m["near_limit_share"] <= 1.0 and m["fit_cpu_seconds"] > 0


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"steps": (1, 30)}, "steps"),
        ({"steps": ()}, "steps"),
        ({"rollout_steps": 100}, "rollout_steps"),
        ({"torque_sd": 0.0}, "torque_sd"),
        ({"train_episodes": 0}, "train_episodes"),
    ],
)
def test_pusher_drift_refuses_bad_settings(changes, match):
    with pytest.raises(ValueError, match=match):
        replace(pusher_drift.Config(), **changes)
