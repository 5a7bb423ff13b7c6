"""LoT with a Bernoulli contact switch in the graph: the simulator's contact as the model defines it,
queries with a gated model (touch, moving, counterfactuals with a latent or an observed switch), the
per-query targets and their preconditions, the scripted Pusher-v5 contact data and the
contact-motion measurement, and the tiny run's new columns and targets."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch

from pal.agent import ModelConfig, build_graph, build_model, pusher_spec, pushing_spec
from pal.agent.config import MODEL_SCHEDULE
from pal.baselines.scripted_pusher import inverse_kinematics
from pal.baselines.scripted_pusher_v5 import ScriptedPusherV5, scripted_episode
from pal.experiments.language import lot
from pal.experiments.language.contact_motion import MotionCheck, contact_situations, predicted_motion
from pal.experiments.language.lot_play import QueryResult, agree, allowance, play_queries, query_targets
from pal.language import P
from pal.language.evaluate import Answer
from pal.language.sim_worlds import PushingWorld, pushing_situations
from pal.language.vocabularies import pushing_signature
from pal.language.world import ModelWorld, Situations
from pal.perception.grounding import GroundingConfig
from pal.sim.pushing import PushingEnv

TINY = ModelConfig(
    members=1, hidden=(4,), schedule=replace(MODEL_SCHEDULE, epochs=1, patience=None), displacement="gated"
)
#: A reset seed of Pusher-v5 whose scripted episode pushes the object (it moves ~5 cm).
PUSHED_SEED = 1


@pytest.fixture(scope="module")
def pushing():
    env = PushingEnv(camera=False)
    values, states = pushing_situations(env, 4, np.random.default_rng(0), near_fraction=1.0)
    yield env, values, states
    env.close()


def _gated_pushing_model(env):
    spec = pushing_spec()
    graph = build_graph(spec, (env.ctrl_low, env.ctrl_high), displacement="gated")
    return build_model(spec, graph, TINY, seed=0).double()


def test_the_simulator_reports_contact_as_the_model_defines_it(pushing):
    env, values, states = pushing
    sit = Situations(values, states)
    # two steps of servo targets that put the hand on the box: the arm touches it
    reach = np.stack([inverse_kinematics(env, values["pos.box"][i]) for i in range(4)])
    plan = torch.as_tensor(np.repeat(reach[:, None], 2, 1))
    share = PushingWorld(env).play(sit, [plan])[0].paths["contact.box"]
    switch = PushingWorld(env, contact="touch").play(sit, [plan])[0].paths["contact.box"]
    assert float(share.max()) > 0.0 and float(share[share > 0].min()) < 1.0  # a share, touched at all
    torch.testing.assert_close(switch, (share > 0).double(), rtol=0, atol=0)
    with pytest.raises(ValueError, match="contact 'share' unknown"):
        PushingWorld(env, contact="share")


def test_gated_model_plays_touch_moving_and_counterfactual_queries(pushing):
    env, values, states = pushing
    model = _gated_pushing_model(env)
    sit = Situations(values, states)
    out = ModelWorld(model).play(
        sit, [torch.as_tensor(values["q"])[:, None]], 16, torch.Generator().manual_seed(0)
    )
    contact = out[0].paths["contact.box"][:, :, 1:]
    assert set(contact.unique().tolist()) == {0.0, 1.0}  # the switch, sampled both ways
    sig = pushing_signature(grounding=GroundingConfig(position_floor=0.001))
    world = ModelWorld(model)
    ask = lambda q: P(q, sig, world, sit, model=model, samples=32, seed=3)  # noqa: E731
    touch = ask("P(touch(hand, box) | do(hold(hand)))")
    assert 0.0 < touch.p < 1.0 and math.isfinite(touch.se)
    # twin worlds share the switch's Gumbel noise: the same plan replays the same contact
    assert ask("P(touch(hand, box)[do(hold(hand))] | do(hold(hand)), touch(hand, box)@end)").p == 1.0
    assert ask("P(touch(hand, box)[do(hold(hand))] | do(hold(hand)), not touch(hand, box)@end)").p == 0.0
    # without contact the box rests (off branch N(0, position_sigma)): moving is graded ~0 with a 1 mm floor
    rest = ask("P(moving(box) | do(hold(hand)), not touch(hand, box)@end)")
    assert rest.p < 0.15, rest
    # counterfactuals with a latent switch (moving as evidence) and an observed one (touch) answer in [0, 1]
    for q in (
        "P(moving(box)[do(hold(hand))] | do(reach(hand, box)), moving(box)@end)",
        "P(moving(box)[do(hold(hand))] | do(reach(hand, box)), touch(hand, box)@end)",
    ):
        a = ask(q)
        assert 0.0 <= a.p <= 1.0 and math.isfinite(a.se), q


def test_evidence_that_never_holds_gives_no_answer_with_a_reason(pushing):
    env, values, states = pushing
    model = _gated_pushing_model(env)
    far = dict(values, **{"pos.box": values["pos.box"] + 100.0})  # the box 100 m away: near is exactly 0
    sit = Situations(far, states)
    (r,) = play_queries(
        ["P(touch(hand, box) | do(hold(hand)), near(hand, box))"],
        pushing_signature(),
        model,
        ModelWorld(model),
        ModelWorld(model),
        sit,
        samples=2,
        horizon=1,
        seed=0,
    )
    assert r.model is None and r.sim is None and r.diff is None and not r.met(0.05)
    assert "model:" in r.reason and "simulator:" in r.reason and "never holds" in r.reason
    (t,) = query_targets("pushing", "gated", [r], 0.05, 20)
    assert t.value is None and t.verdict == "not evaluated" and "no answer" in t.precondition.reason


def _answer(p, se, n=30):
    return Answer(p, se, n, 1, float(n))


def test_per_query_targets_follow_the_agreement_rule_and_need_20_situations():
    rng = np.random.default_rng(0)
    for _ in range(300):
        m, s = _answer(*rng.uniform(0, 1, 2) * (1, 0.2)), _answer(*rng.uniform(0, 1, 2) * (1, 0.2))
        assert agree(m, s, 0.05) == (abs(m.p - s.p) <= allowance(m, s, 0.05) + 1e-12)
    results = [
        QueryResult("a", _answer(0.50, 0.01), _answer(0.53, 0.01)),  # within 0.05
        QueryResult("b", _answer(0.50, 0.10), _answer(0.68, 0.10)),  # inside both intervals
        QueryResult("c", _answer(0.50, 0.01), _answer(0.60, 0.01)),  # apart
        QueryResult("d", _answer(0.50, 0.01, 19), _answer(0.50, 0.01, 19)),  # too few situations
    ]
    targets = query_targets("w", "smooth", results, 0.05, 20)
    assert [t.name for t in targets] == [f"query.w.smooth.{k}" for k in (1, 2, 3, 4)]
    assert [t.verdict for t in targets] == ["met", "met", "not met", "not evaluated"]
    assert targets[1].threshold == pytest.approx(0.196) and "was 19.0" in targets[3].precondition.reason


def test_scripted_pusher_pushes_the_object_and_refuses_other_worlds():
    env = gymnasium.make("Pusher-v5")
    ep = scripted_episode(env, PUSHED_SEED)
    obj = ep["observations"][:, 17:19]
    assert np.linalg.norm(obj[-1] - obj[0]) > 0.01 and "push" in ep["phases"]
    assert ep["actions"].shape == (100, 7) and np.abs(ep["actions"]).max() <= 2.0
    with pytest.raises(ValueError, match="tips_arm"):
        ScriptedPusherV5(PushingEnv(camera=False))
    env.close()


def test_contact_situations_and_predicted_motion():
    env = gymnasium.make("Pusher-v5")
    check = MotionCheck(situations=3, episodes=1, num_samples=8)
    sit = contact_situations(env, check, [PUSHED_SEED], floor=3e-4)
    env.close()
    assert sit["sim_on"].shape == (3,) and np.all(sit["sim_on"] > 3e-4)
    np.testing.assert_array_equal(sit["sim_far"], 0.0)  # the object at rest 30 cm away does not move
    d = np.linalg.norm(sit["far"]["pos_prev.object"][:, :2] - sit["far"]["ee_prev"][:, :2], axis=1)
    np.testing.assert_allclose(d, 0.3, atol=1e-9)
    np.testing.assert_array_equal(sit["far"]["vel_prev.object"], 0.0)
    spec = pusher_spec()
    bounds = (np.full(7, -2.0), np.full(7, 2.0))
    for form in ("gated", "smooth"):
        cfg = replace(TINY, displacement=form, position_sigma=1e-4)
        model = build_model(spec, build_graph(spec, bounds, displacement=form), cfg, seed=0)
        out = predicted_motion(model, sit, check, seed=0)
        for key in ("expected_on", "expected_far", "predictive_on", "predictive_far"):
            assert out[key].shape == (3,) and np.all(np.isfinite(out[key])) and np.all(out[key] >= 0), key


def test_lot_config_refuses_a_comparison_equal_to_the_primary():
    with pytest.raises(ValueError, match="primary model's displacement form"):
        lot.Config(comparison="gated")
    with pytest.raises(ValueError, match="comparison 'soft' unknown"):
        lot.Config(comparison="soft")
    assert lot.Config(comparison=None).comparison is None


def test_tiny_run_has_both_models_per_query_and_the_contact_motion_targets(tiny_run):
    report = tiny_run("experiment", "lot").report
    names = {t.name for t in report.targets}
    for world, n in (("pushing", len(lot.TINY.queries)), ("pusher", len(lot.TINY.pusher.queries))):
        assert {f"queries_met.{world}", f"queries_met.{world}.smooth"} <= names
        for form in ("gated", "smooth"):
            assert {f"query.{world}.{form}.{k}" for k in range(1, n + 1)} <= names
    motion = [t for t in report.targets if t.name.startswith("contact_motion.")]
    assert {t.name for t in motion} == {
        f"contact_motion.{f}.{k}" for f in ("gated", "smooth") for k in ("expected", "predictive")
    }
    for t in report.targets:
        if t.name.startswith("query."):
            assert t.value is None or 0.0 <= t.value <= 1.0, t
            assert t.precondition is not None and (t.value is not None or not t.precondition.holds)
    for t in motion:  # the tiny run finds too few contact situations: not evaluated, with the reason
        assert t.verdict == "not evaluated" and "contact situations" in t.precondition.reason
    m = report.metrics
    assert m["pushing"]["model"] == "gated" and set(m["pushing"]["comparisons"]) == {"smooth"}
    assert m["pusher"]["moved_episodes"] >= 0 and "contact_motion" in m["pusher"]
    for world in ("pushing", "pusher"):
        cols = next(t.columns for t in report.tables if t.title.startswith(m[world].get("title", "")))
        assert "P smooth [95 %]" in cols
        for q in m[world]["queries"] + m[world]["comparisons"]["smooth"]["queries"]:
            for a in (q["model"], q["simulator"]):
                assert a is None or (0.0 <= a["p"] <= 1.0)
    json.dumps(m, allow_nan=False)  # no NaN anywhere in the metrics
