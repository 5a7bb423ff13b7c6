"""The ``pusher-data`` experiment: both data sets are scored (tiny sizes), bad settings are refused."""

from dataclasses import replace

import pytest

from pal.agent.exploration import Branching
from pal.experiments.closed_loop import pusher_data
from pal.experiments.closed_loop.pusher_data import Config


@pytest.mark.slow
def test_pusher_data_scores_the_expert_data_and_the_data_with_continuations(tiny_run):
    rep = tiny_run("experiment", "pusher-data").report
    tiny = pusher_data.TINY
    m = rep.metrics
    assert list(m) == ["expert", "expert + continuations"]
    steps = tiny.expert_episodes * tiny.episode_steps
    c = tiny.continuations
    starts = len(range(0, tiny.episode_steps - c.steps + 1, c.every))
    assert m["expert"]["transitions"] == steps
    assert (
        m["expert + continuations"]["transitions"]
        == steps + tiny.expert_episodes * starts * c.per_state * c.steps
    )
    (target,) = rep.targets
    assert target.name == "continuations_rho_obj_gain" and target.verdict == "not evaluated"  # 1 episode, 1 probe
    for row in m.values():
        assert row["probes"] == 1 and 0 <= row["moving"] <= row["transitions"]
        # one closed-loop goal per model: distances in the table's range, the moved share a fraction
        assert 0.0 < row["closed-loop start x-y, median [m]"] < 1.0
        assert 0.0 < row["closed-loop final x-y, median [m]"] < 1.0
        assert row["closed-loop moved share"] in (0.0, 1.0)
        assert row["rho"] is None or -1.0 <= row["rho"] <= 1.0
        forced = row["rho_obj, arm from the truth"]
        assert forced is None or -1.0 <= forced <= 1.0
        # with the arm forced the object cannot be off by more than the table; the probe's truth spreads
        assert 0.0 <= row["final object error, arm from the truth [cm]"] < 100.0
        assert row["candidates' final spread [cm]"] >= 0.0
    assert len({row["closed-loop start x-y, median [m]"] for row in m.values()}) == 1  # the same goals for both


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"expert_episodes": 0}, "expert_episodes must be"),
        ({"episode_steps": 101}, "episode_steps must be"),
        ({"continuations": 3}, "continuations must be a Branching, got int"),
        ({"continuations": Branching(per_state=0)}, "continuations.per_state must be a positive int, got 0"),
        ({"episode_steps": 10}, "continuations.steps 25 exceeds episode_steps 10"),
        ({"eval_goals": -1}, "eval_goals must be"),
    ],
)
def test_pusher_data_refuses_bad_settings(changes, match):
    with pytest.raises(ValueError, match=match):
        replace(Config(), **changes)


@pytest.mark.slow
def test_pusher_data_without_closed_loop_goals_leaves_those_cells_empty():
    rep = pusher_data.run(replace(pusher_data.TINY, eval_goals=0))
    for row in rep.metrics.values():
        assert row["closed-loop final x-y, median [m]"] is None and row["closed-loop moved share"] is None
        assert row["probes"] == 1
    assert rep.targets[0].verdict == "not evaluated"
