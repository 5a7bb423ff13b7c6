"""Hierarchical against flat action inference in the pushing world: the layers, the nested chain, counting, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inference import ActionOptions
from inference.hierarchy import LevelQuery
from inference.hierarchy_count import count_evaluations
from pal.baselines.scripted_pusher import HAND_RADIUS
from pal.experiments.closed_loop import hierarchy_compare as hc
from pal.experiments.closed_loop.hierarchy_pushing import (
    HierarchyConfig,
    fit_push_gains,
    make_realise,
    push_phase,
    pushing_hierarchy,
)
from pal.experiments.closed_loop.push_goals import GoalGeometry
from pal.experiments.closed_loop.setup import babbled_agent, fitted_model
from pal.sim.pushing import BOX_HALF, OBJECT_RADIUS

CFG = HierarchyConfig()
D = OBJECT_RADIUS["box"] + HAND_RADIUS + CFG.gap  # approach distance behind the box centre, m


def _t(*v: float) -> torch.Tensor:
    return torch.tensor([v], dtype=torch.float64)


def _state(hand: tuple[float, float]) -> dict[str, torch.Tensor]:
    return {"ee_prev": _t(*hand, 0.035), "pos_prev.box": _t(0.10, 0.20), "q_prev": _t(0.0, -1.0)}


def test_realised_waypoints_lie_behind_the_box_then_through_it() -> None:
    events = {"push.box": _t(0.03, 0.0)}  # push along +x by 3 cm
    state = _state((0.10, 0.30))  # the hand on the +y side of the box
    via, approach, through = (p["ee"][0].numpy() for p in make_realise(CFG.gap)(events, state))
    box = np.array([0.10, 0.20])
    np.testing.assert_allclose(approach, [0.10 - D, 0.20, 0.035], atol=1e-12)
    near = min(BOX_HALF[:2]) + HAND_RADIUS
    np.testing.assert_allclose(through, [0.10 - near + 0.03, 0.20, 0.035], atol=1e-12)
    assert np.linalg.norm(via[:2] - box) == pytest.approx(D, abs=1e-12)
    assert via[0] < box[0] and via[1] > box[1]  # behind the box, on the hand's side
    # the phase follows the hand: in front of the box -> via; clear way -> approach; on the line -> through
    assert push_phase(events, _state((0.17, 0.20)), CFG) == 0
    assert push_phase(events, _state((0.00, 0.30)), CFG) == 1
    assert push_phase(events, _state((0.10 - D + 0.01, 0.205)), CFG) == 2


def _series(gain: float, pushes: int) -> dict[str, np.ndarray]:
    """A hand moving +x by 1 cm a step, touching the box on the first ``pushes`` steps, the box following by ``gain``."""
    t = 8
    ee = np.zeros((t + 1, 3))
    ee[:, 0] = 0.01 * np.arange(t + 1)
    touch = np.zeros((t + 1, 1))
    touch[1 : pushes + 1] = 1.0
    pos = np.zeros((t + 1, 2))
    for k in range(1, t + 1):
        pos[k] = pos[k - 1] + (gain * 0.01 * touch[k, 0], 0.0)
    return {"ee": ee, "touch.box": touch, "pos.box": pos}


@pytest.fixture(scope="module")
def fitted():
    agent = babbled_agent(hc.TINY.setup, 0)
    model, _ = fitted_model(agent, hc.TINY.setup, 0, "truth", np.arange(len(agent.history)))
    agent.env.close()
    return agent, model


def test_push_gains_from_the_bottom_up_evidence(fitted) -> None:
    agent, model = fitted
    h, _ = pushing_hierarchy(model, agent.history, CFG, objects=("box",))
    gains, sigma, rows = fit_push_gains(h, [_series(0.5, 6)] * 4, ("box",), ridge=1e-6)
    assert rows == {"box": 24}
    np.testing.assert_allclose(gains["box"][0, 0], 0.5, atol=1e-3)
    assert sigma["box"] == pytest.approx(1e-3)  # exact data: the floor
    prior, _, none = fit_push_gains(h, [_series(0.5, 0)], ("box",), ridge=1e-3)
    assert none == {"box": 0}
    np.testing.assert_allclose(prior["box"], np.eye(2))  # no push events: the identity prior


def test_nested_chain_and_counted_evaluations(fitted) -> None:
    agent, model = fitted
    cfg = hc.TINY.hierarchy
    h, info = pushing_hierarchy(model, agent.history, cfg, seed=0)
    assert set(info) == {"box", "ball"} and np.asarray(info["box"]["gain"]).shape == (2, 2)
    box, goal = np.array([0.05, 0.15]), np.array([0.09, 0.15])
    state = {
        "q_prev": np.array([-0.4, -2.4]),
        "ee_prev": np.array([-0.05, 0.25, 0.035]),
        "pos_prev.box": box,
        "pos_prev.ball": np.array([-0.22, 0.0]),
    }
    st = {k: torch.as_tensor(v)[None] for k, v in state.items()}
    events, result, sub = h.event_targets({"pos.box": torch.as_tensor(goal)[None]}, st)
    assert set(events) == {"push.box"}  # contextualisation: only the box's push reaches its position
    assert "push.ball" in sub.dropped
    assert torch.all(events["push.box"].abs() <= cfg.max_push + 1e-9)
    predicted = result.predicted["pos.box"][0].numpy()
    # the event moves the box towards the goal
    assert np.linalg.norm(predicted - goal) < np.linalg.norm(box - goal)
    u = events["push.box"][0].numpy() / np.linalg.norm(events["push.box"][0].numpy())
    approach = h.realise(events, st)[1]["ee"][0, :2].numpy()
    along = float((approach - box) @ u)
    # the approach waypoint lies behind the box on the push line (float32 model)
    assert along == pytest.approx(-(OBJECT_RADIUS["box"] + HAND_RADIUS + cfg.gap), abs=1e-6)
    # the object level's context is cached above, so the decisions below sample only the body layer
    nested, flat = hc._Nested(h, cfg), hc._Flat(model, hc.TINY, 0)
    counts = {}
    for name, planner in (("hierarchy", nested), ("flat", flat)):
        with count_evaluations(*planner.models()) as count:
            action, _ = planner.decide(state, goal)
        assert action.shape == (2,) and np.all(np.isfinite(action))
        counts[name] = count
    assert counts["hierarchy"].total > 0 and counts["flat"].total > 0
    assert counts["hierarchy"].by_site["dq"] > 0 and counts["hierarchy"].by_site["dpos.box"] > 0
    assert counts["flat"].by_site["dpos.box"] > 0 and counts["flat"].by_site["dq"] > 0
    assert "dpos.ball" not in counts["hierarchy"].by_site  # the ball's sites are not in the active submodels


@pytest.mark.slow
def test_section_reports_both_methods_on_the_same_goals(tiny_run) -> None:
    report = tiny_run("experiment", "hierarchy").report  # the report of hierarchy_section(hc.TINY)
    m = report.metrics
    for method in hc.METHODS:
        assert len(m["episodes"][method]) == hc.TINY.goals
        assert m[method]["decisions"] >= 1 and m[method]["evaluations_mean"] > 0
    assert m["evaluations_ratio"] == pytest.approx(
        m["hierarchy"]["evaluations_mean"] / m["flat"]["evaluations_mean"]
    )
    names = {t.name for t in report.targets}
    assert names == {"success_hier_minus_flat", "evaluations_per_decision_hier_over_flat"}
    start = [ep["path"][0] for ep in m["episodes"]["hierarchy"]]
    assert start == [ep["path"][0] for ep in m["episodes"]["flat"]]  # the same seeded start states
    # LoT's tiny run includes the section under its name, on the same goals
    lot = tiny_run("experiment", "lot").report.metrics["hierarchy"]
    assert set(lot) == set(m) and lot["episodes"]["flat"][0]["path"] == m["episodes"]["flat"][0]["path"]


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: hc.Config(goals=0), "goals must be a positive int"),
        (lambda: hc.Config(tolerance=0.0), "tolerance"),
        (lambda: GoalGeometry(distance=(0.08, 0.04)), r"distance must be \(low, high\) with low <= high"),
        (lambda: GoalGeometry(start_radius=(0.1,)), r"start_radius must be \(low, high\)"),
        (
            lambda: HierarchyConfig(body_query=LevelQuery(3, ActionOptions(scale=0.01))),
            "body_query.options.sampling must be a SamplingConfig",
        ),
        (lambda: HierarchyConfig(contact_threshold=1.5), "contact_threshold"),
        (lambda: HierarchyConfig(max_push=0.0), "max_push"),
    ],
)
def test_bad_config_values(make, match) -> None:
    with pytest.raises(ValueError, match=match):
        make()


def test_unknown_object_geometry(fitted) -> None:
    agent, model = fitted
    with pytest.raises(ValueError, match=r"objects \['boat'\] have no push geometry"):
        pushing_hierarchy(model, agent.history, CFG, objects=("boat",))
