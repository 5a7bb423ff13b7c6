"""The agent over any Gymnasium env: specs and their bad inputs, the graph from a spec, Pusher-v5, curiosity's gate."""

from dataclasses import replace
from types import SimpleNamespace

import gymnasium
import numpy as np
import pytest
import torch

from inference import SamplingConfig
from models import LinearMechanism
from pal.agent import (
    Agent,
    AgentConfig,
    CuriosityConfig,
    EnvSpec,
    ModelConfig,
    ObjectSpec,
    PlanConfig,
    Sensor,
    build_graph,
    build_model,
    check_env,
    discover_parents,
    plan,
    pusher_spec,
)
from pal.agent.config import MODEL_SCHEDULE, PLAN_ACTION, PLAN_SAMPLING
from pal.agent.influence import explore, influence
from pal.sim.pushing import PushingEnv

TINY = AgentConfig(
    model=ModelConfig(hidden=(8,), members=2, schedule=replace(MODEL_SCHEDULE, epochs=3, patience=None)),
    plan=PlanConfig(
        action=replace(
            PLAN_ACTION,
            horizon=3,
            target_at="every",
            scale=1.0,
            sampling=replace(PLAN_SAMPLING, population=8, elites=2, iterations=1, refine_steps=0),
        ),
        preference="distance",
        effector_weight=0.5,
    ),
    reset_every=None,
    servo=False,
)


@pytest.fixture(scope="module")
def pusher():
    env = gymnasium.make("Pusher-v5")
    yield env
    env.close()


class Unbounded(gymnasium.Wrapper):
    """Pusher with an action space that has no bounds."""

    def __init__(self, env):
        super().__init__(env)
        self.action_space = gymnasium.spaces.Box(-np.inf, np.inf, (7,), np.float32)


def test_specs_refuse_overlaps_bad_dims_and_missing_sensors():
    for make, match in (
        (
            lambda: EnvSpec(("a", "b"), Sensor(obs=(0, 1)), effector=Sensor(obs=(1, 2, 3))),
            "index 1 is given to both 'angles' and 'effector'",
        ),
        (lambda: EnvSpec(("a",), Sensor(obs=(0, 1))), "angles has dim 2, expected 1"),
        (lambda: Sensor(obs=(0,), info="x"), "either observation indices or an info key"),
        (lambda: Sensor(obs=(-1,)), "observation index must be a non-negative int"),
        (lambda: EnvSpec(("a",), Sensor(obs=(0,)), objects=(ObjectSpec("o"),)), "camera"),
        (
            lambda: EnvSpec(("a",), Sensor(obs=(0,)), objects=(ObjectSpec("o", Sensor(obs=(1, 2))),)),
            "effector",
        ),
        (
            lambda: EnvSpec(("a",), Sensor(obs=(0,)), action_low=(0.0,), action_high=(np.inf,)),
            "no finite bounds",
        ),
        (
            lambda: ObjectSpec("o", Sensor(obs=(1, 2)), goal=Sensor(obs=(3,))),
            "goal of 'o' has dim 1, expected 2",
        ),
    ):
        with pytest.raises(ValueError, match=match):
            make()


def _info(key: str, dim: int = 2) -> Sensor:
    return Sensor(info=key, dim=dim)


#: (EnvSpec keyword arguments over joints ("a",) and angles obs (0,), the two roles of the key).
INFO_OVERLAPS = [
    ({"effector": _info("pos"), "objects": (ObjectSpec("o", _info("pos")),)}, "'effector' and 'pos.o'"),
    (
        {"effector": _info("hand"), "objects": (ObjectSpec("o", _info("box"), goal=_info("hand")),)},
        "'effector' and 'goal.o'",
    ),
    (
        {"effector": _info("hand"), "objects": (ObjectSpec("o", _info("box"), goal=_info("box")),)},
        "'pos.o' and 'goal.o'",
    ),
    (
        {
            "effector": _info("hand", 1),
            "objects": (ObjectSpec("o", _info("x", 1)),),
            "touch": _info("hand", 1),
        },
        "'effector' and 'touch'",
    ),
    (
        {"effector": _info("rgbd"), "objects": (ObjectSpec("o"),), "camera": "rgbd"},
        "'camera' and 'effector'",
    ),
    (
        {"effector": _info("self_mask"), "objects": (ObjectSpec("o"),), "camera": "rgbd"},
        "'camera' and 'effector'",
    ),
    ({"velocities": _info("q", 1), "effector": _info("q", 1)}, "'velocities' and 'effector'"),
    (
        {"effector": _info("hand"), "objects": (ObjectSpec("o", _info("b")), ObjectSpec("p", _info("b")))},
        "'pos.o' and 'pos.p'",
    ),
]


@pytest.mark.parametrize(("kwargs", "roles"), INFO_OVERLAPS, ids=[r for _, r in INFO_OVERLAPS])
def test_an_info_key_read_by_two_roles_is_refused_naming_the_key_and_both(kwargs, roles):
    with pytest.raises(ValueError, match=rf"info key '\w+' is read by both {roles}; roles may not overlap"):
        EnvSpec(("a",), Sensor(obs=(0,)), **kwargs)


def test_the_env_must_match_the_spec_at_construction(pusher):
    good = pusher_spec()
    low, high = check_env(good, pusher)
    assert low.shape == (7,) and np.all(high == 2.0)
    far = EnvSpec(good.joints, good.angles, good.velocities, Sensor(obs=(14, 15, 30)), good.objects[:0])
    with pytest.raises(
        ValueError, match="reads observation index 30 for 'effector', but the observation has 23 entries"
    ):
        Agent(pusher, far, TINY)
    other = EnvSpec(good.joints, good.angles, observation_dim=20)
    with pytest.raises(
        ValueError, match=r"observation space has shape \(23,\), but the spec is written for \(20,\)"
    ):
        Agent(pusher, other, TINY)
    with pytest.raises(ValueError, match="no finite bounds in the action space"):
        Agent(Unbounded(pusher), good, TINY)
    with pytest.raises(ValueError, match="the spec has 2 actions"):
        Agent(pusher, EnvSpec(("a", "b"), Sensor(obs=(0, 1))), TINY)


def test_perceived_objects_that_perception_never_sees_fail_at_construction():
    env = PushingEnv(("box",), camera=True, camera_size=(160, 120))
    names = ("box", "ball", "boat", "cup", "can")
    spec = EnvSpec(
        ("shoulder", "elbow"),
        Sensor(obs=(0, 1)),
        effector=Sensor(info="hand", dim=3),
        objects=tuple(ObjectSpec(o) for o in names),
        camera="rgbd",
    )
    with pytest.raises(
        ValueError, match=r"objects \['box', 'ball', 'boat', 'cup', 'can'\] named by the spec are not seen"
    ):
        Agent(env, spec, replace(TINY, servo=None))  # position servos, read from the MJCF
    with pytest.raises(ValueError, match="need info entries"):
        Agent(
            PushingEnv(camera_size=(160, 120)),
            EnvSpec(**{**spec.__dict__, "objects": spec.objects[:2]}),
            replace(TINY, servo=None),
        )
    env.close()


def test_the_graph_from_the_pusher_spec_and_its_fixed_relations():
    spec = pusher_spec()
    graph = build_graph(spec, (-2 * np.ones(7), 2 * np.ones(7)), displacement="smooth")
    assert graph.parents("dq") == ("act", "q_prev", "v_prev") and graph.parents("dee") == ("q_prev", "dq")
    assert graph.parents("dpos.object") == ("vel_prev.object", "rel_prev.object", "rel.object")
    assert "contact.object" not in graph and "meas.object" not in graph  # no touch sensor, nothing perceived
    model = build_model(spec, graph, ModelConfig(members=3, hidden=(8,), displacement="smooth"), seed=0)
    g = torch.Generator().manual_seed(0)
    roots = {r: torch.randn(4, graph[r].dim, generator=g) for r in graph.roots}
    roots["act"] = roots["act"].clamp(-2, 2)
    out = model.predict(roots)
    torch.testing.assert_close(out["q"], roots["q_prev"] + out["dq"])
    torch.testing.assert_close(out["rel.object"], out["ee"] - roots["pos_prev.object"])
    torch.testing.assert_close(out["pos.object"], roots["pos_prev.object"] + out["dpos.object"])
    assert model.predict(roots, members=True)["dpos.object"].shape == (3, 4, 3)


def test_discovery_never_offers_the_new_angles_or_the_effector_to_the_joints_dynamics(monkeypatch):
    spec = pusher_spec()
    graph = build_graph(spec, (-2 * np.ones(7), 2 * np.ones(7)), displacement="smooth")
    seen = {}

    def fake_discover(variables, data, *, tiers, **kwargs):
        seen["tiers"] = tiers
        return SimpleNamespace(graph=graph)

    monkeypatch.setattr("pal.agent.graph.discover", fake_discover)
    parents = discover_parents(spec, graph, {n: np.zeros((1, graph[n].dim)) for n in graph.names})
    tier = {n: i for i, names in enumerate(seen["tiers"]) for n in names}
    assert tier["act"] == tier["q_prev"] == tier["v_prev"] == 0
    assert tier["dq"] == tier["v"] == 1  # only the roots and each other can cause the joints' motion
    assert min(tier["dee"], tier["q"], tier["ee"]) == 2 and tier["dpos.object"] > 2
    assert parents["dq"] == ("act", "q_prev", "v_prev")


def test_the_agent_learns_and_plans_on_pusher_from_observations_alone(pusher):
    agent = Agent(pusher, pusher_spec(), TINY, seed=0)
    agent.run(30, "babble")
    agent.refit()
    agent.reset(seed=3)
    assert agent.percept.perception is None and set(agent.percept.goals) == {"object"}
    belief = agent.belief()
    assert set(belief) == {"q_prev", "v_prev", "ee_prev", "pos_prev.object", "vel_prev.object"}
    d = agent.decide("goal")
    assert d.mode == "goal" and d.action.shape == (7,) and np.all(np.abs(d.action) <= 2)
    assert d.step_sd["object"].shape == (3,) and np.all(d.step_sd["object"] > 0)
    # the plan is a pure function of the model, the belief and the target: the same seed, the same plan
    again = plan(agent.model, belief, {"object": agent.percept.goals["object"]}, TINY.plan, seed=5)
    same = plan(agent.model, belief, {"object": agent.percept.goals["object"]}, TINY.plan, seed=5)
    np.testing.assert_array_equal(again.sequence, same.sequence)
    assert again.sequence.shape == (3, 7)
    agent.step(d.action)
    assert len(agent.history) == 31 and np.isfinite(agent.history.array("vel_prev")).all()


def test_the_influence_gate_sees_only_what_the_action_moves():
    spec = pusher_spec()
    graph = build_graph(spec, (-2 * np.ones(7), 2 * np.ones(7)), displacement="smooth")
    known = {
        "dq": LinearMechanism.from_coefficients(
            torch.cat([torch.eye(7), torch.zeros(7, 14)], 1), sigma=0.001
        ),
        "dee": LinearMechanism.from_coefficients(
            torch.cat([torch.zeros(3, 7), 0.05 * torch.eye(3, 7)], 1), sigma=0.001
        ),
    }
    # dpos follows the effector's move in the first model, and nothing in the second
    w = torch.zeros(3, 9)
    w[:, 3:6], w[:, 6:] = -torch.eye(3), torch.eye(3)  # parents: vel_prev, rel_prev, rel
    model = build_model(
        spec,
        graph,
        ModelConfig(kind="mlp", members=1, hidden=(4,), displacement="smooth"),
        mechanisms={**known, "dpos.object": LinearMechanism.from_coefficients(w, sigma=0.001)},
    )
    free = build_model(
        spec,
        graph,
        ModelConfig(kind="mlp", members=1, hidden=(4,), displacement="smooth"),
        mechanisms={
            **known,
            "dpos.object": LinearMechanism.from_coefficients(torch.zeros(3, 9), sigma=0.001),
        },
    )
    state = {r: torch.zeros(2, graph[r].dim) for r in graph.roots if r != "act"}
    g = torch.Generator().manual_seed(0)
    moved = influence(model, state, ("object",), 16, g)["object"]
    still = influence(free, state, ("object",), 16, g)["object"]
    assert moved.shape == (2,) and bool((moved > 1.0).all()) and bool((still < 0.05).all())
    # a single model has no disagreement: nothing to explore
    belief = {r: np.zeros(graph[r].dim) for r in graph.roots if r != "act"}
    _, score, gate = explore(
        model,
        belief,
        ("object",),
        CuriosityConfig(sampling=SamplingConfig(population=8, elites=2, iterations=1)),
        0.02,
        g,
    )
    assert score == 0.0 and gate["object"] > 1.0
