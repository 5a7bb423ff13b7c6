"""The object layer refined through its own rollouts: windows, the chained loss, and the site it may change."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from inference import FitSchedule
from pal.agent import Agent, ModelConfig
from pal.agent.config import MODEL_SCHEDULE
from pal.agent.history import History
from pal.agent.rollout_fit import ROLLOUT_SCHEDULE, RolloutFit, object_windows, refine_objects


def _history(
    episodes: list[list[float]], unknown: tuple[int, ...] = (), jump: tuple[int, ...] = ()
) -> History:
    """A one-joint, one-object history; ``episodes`` are the object's x per step boundary (positions)."""
    h = History(("j",), ("box",), momentum=True)
    row = 0
    for e, xs in enumerate(episodes):
        for t in range(len(xs) - 1):
            prev = np.array([[xs[t] + (0.5 if row in jump else 0.0), 0.0]])
            now = np.array([[xs[t + 1], 0.0]])
            if row in unknown:
                now = np.full((1, 2), np.nan)
            h.append(
                episode=e,
                act=[0.0],
                q_prev=[0.0],
                q=[0.0],
                hand_prev=[0.0, 0.0, 0.0],
                hand=[0.0, 0.0, 0.0],
                touch=[0.0],
                meas_prev=prev,
                meas=now,
                std=np.zeros((1, 2)),
                est_prev=prev,
                est=now,
                truth_prev=prev,
                truth=now,
                state=np.zeros(1),
                vel_prev=np.zeros((1, 2)),
            )
            row += 1
    return h


def test_windows_stay_inside_episodes_and_links():
    h = _history([[0, 1, 2, 3, 4, 5], [0, 1, 2, 3]])  # rows 0-4 and 5-7
    np.testing.assert_array_equal(object_windows(h, 3, 1), [[0, 1, 2], [1, 2, 3], [2, 3, 4], [5, 6, 7]])
    np.testing.assert_array_equal(object_windows(h, 3, 2), [[0, 1, 2], [2, 3, 4], [5, 6, 7]])
    np.testing.assert_array_equal(object_windows(h, 1, 3), [[0], [3], [5]])
    assert object_windows(h, 9, 1).shape == (0, 9)


def test_windows_skip_unknown_positions_and_broken_links():
    h = _history([[0, 1, 2, 3, 4, 5, 6]], unknown=(2,), jump=(5,))
    # row 2 is unknown; row 5 does not start where row 4 ended (a restart without a new episode)
    np.testing.assert_array_equal(object_windows(h, 2, 1), [[0, 1], [3, 4]])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"window": -1}, "rollout.window"),
        ({"stride": 0}, "rollout.stride"),
        ({"schedule": {"lr": 0.1}}, "rollout.schedule must be a FitSchedule, got dict"),
    ],
)
def test_bad_settings_name_the_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RolloutFit(**kwargs)


def _pusher_agent(make, rollout: RolloutFit) -> Agent:
    """An agent on Pusher-v5 with its body from the MJCF and ``rollout``, fed one scripted episode that pushes."""
    return make(
        ModelConfig(
            members=2,
            hidden=(16,),
            kinematics="mjcf",
            dynamics="mjcf",
            position_sigma=1e-4,
            schedule=replace(MODEL_SCHEDULE, epochs=200, patience=None, validation=0.0),
            rollout=rollout,
        )
    )


def _chained_rms(agent: Agent, windows: np.ndarray) -> float:
    """The RMS of the members' chained object positions against the recorded ones, m, arm assigned."""
    arm, objects = agent.history.columns("perceived", windows.reshape(-1), contact="moved", floor=3e-4)
    cols = {**arm, **objects["object"]}
    w, h = windows.shape
    seq = {k: torch.as_tensor(v.reshape(w, h, -1), dtype=agent.model.dtype) for k, v in cols.items()}
    graph = agent.model.graph
    with torch.no_grad():
        out = agent.model.rollout(
            {r: seq[r][:, 0] for r in graph.roots if graph[r].lag == 1},
            {"act": seq["act"]},
            members=True,
            assign={k: seq[k] for k in ("dq", "q", "v", "dee", "ee")},
        )
    return float((out["pos.object"] - seq["pos.object"]).pow(2).sum(-1).mean().sqrt())


def test_the_refinement_lowers_the_chained_error_it_reports_and_changes_only_the_object_layer(
    scripted_pusher_agent,
):
    settings = RolloutFit(
        window=5, stride=1, schedule=FitSchedule(epochs=15, lr=3e-3, batch_size=16, validation=0.0)
    )
    plain, refined = (_pusher_agent(scripted_pusher_agent, r) for r in (RolloutFit(), settings))
    assert plain.history.array("meas")[-1, 0, 0] != plain.history.array("meas_prev")[0, 0, 0]  # it pushed
    assert "rollout" not in plain.refit()
    report = refined.refit()["rollout"]
    windows = object_windows(refined.history, 5, 1)
    assert report["windows"] == len(windows) > 50 and report["epoch"] >= 1
    before, after = report["rms_m"]
    # the reported errors are the chained errors of the one-step fit and of the refined model
    assert _chained_rms(plain, windows) == pytest.approx(before, rel=1e-4)
    assert _chained_rms(refined, windows) == pytest.approx(after, rel=1e-4)
    assert after < 0.8 * before
    for site in ("rel.object", "pos.object"):  # fixed relations stay as they are
        for key, value in plain.model.mechanism(site).state_dict().items():
            torch.testing.assert_close(refined.model.mechanism(site).state_dict()[key], value)
    changed = [
        s
        for s in ("contact.object", "dpos.object")
        if not all(
            torch.equal(v, plain.model.mechanism(s).state_dict()[k])
            for k, v in refined.model.mechanism(s).state_dict().items()
        )
    ]
    assert changed == ["contact.object", "dpos.object"]


def test_a_row_subset_refines_on_its_own_windows_only(scripted_pusher_agent):
    agent = _pusher_agent(scripted_pusher_agent, RolloutFit())
    agent.refit()
    settings = RolloutFit(window=5, stride=1, schedule=replace(ROLLOUT_SCHEDULE, epochs=1))
    out = refine_objects(
        agent.model,
        agent.history,
        ["object"],
        settings,
        contact="moved",
        floor=3e-4,
        rows=np.arange(30),
        seed=0,
    )
    inside = object_windows(agent.history, 5, 1)
    assert out["windows"] == int((inside < 30).all(1).sum()) == 26
    assert refine_objects(
        agent.model, agent.history, ["object"], RolloutFit(), contact="moved", floor=3e-4
    ) == {"windows": 0}
