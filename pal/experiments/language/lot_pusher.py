"""The Pusher-v5 part of the LoT experiment: queries over the fingertip, the object and its goal.

The agent (spec :func:`pal.agent.pusher_spec`: joints, velocities, fingertip, the object with
momentum) babbles uniform random torques in Gymnasium's ``Pusher-v5`` (episodes of 100 steps,
as in :mod:`pal.experiments.closed_loop.pusher`) and fits its world model. N start situations are drawn
from the same babbling (:func:`pal.language.sim_worlds.pusher_situations` with
``babble_steps``: the arm where k random-torque steps after a reset took it, the object at
rest, moved near the fingertip in half of them). The queries (vocabulary
:func:`pal.language.vocabularies.pusher_signature`, the goal marker held constant in the model
world) are compiled over ``horizon`` steps and played in the model and in the simulator
(:class:`pal.language.sim_worlds.PusherWorld`) as in :mod:`pal.experiments.language.lot_play`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import gymnasium
import numpy as np
import torch

from pal.agent import Agent, AgentConfig, ModelConfig, pusher_spec
from pal.agent.config import MODEL_SCHEDULE
from pal.checks import check_int
from pal.experiments.closed_loop.pusher import MODEL
from pal.experiments.closed_loop.pusher_runs import ENV_ID
from pal.experiments.language.lot_play import Section, play_queries, query_section
from pal.language.sim_worlds import PusherWorld, pusher_situations
from pal.language.vocabularies import pusher_signature
from pal.language.world import ModelWorld, Situations
from pal.perception.grounding import GroundingConfig

__all__ = ["PUSHER_QUERIES", "QUICK_PUSHER", "TINY_PUSHER", "PusherPart", "pusher_section"]

#: The Pusher-v5 queries (text syntax of :mod:`pal.language.syntax`).
PUSHER_QUERIES: tuple[str, ...] = (
    "P(near(fingertip, object) | do(reach(fingertip, object)), not near(fingertip, object))",
    "P(near(fingertip, object) | do(hold(fingertip)), near(fingertip, object))",
    "P(touch(fingertip, object) | do(reach(fingertip, object)), near(fingertip, object))",
    "P(moving(object) | do(push(fingertip, object)), near(fingertip, object))",
    "P(left_of(fingertip, goal) | do(reach(fingertip, object)))",
    "P(near(fingertip, object)[do(hold(fingertip))] | do(reach(fingertip, object)), near(fingertip, object)@end)",
)


@dataclass(frozen=True)
class PusherPart:
    """Settings of the Pusher-v5 part.

    Attributes:
        babble_steps: random-torque steps the model is fitted on.
        model: the agent's world model and fit (default that of :mod:`pal.experiments.closed_loop.pusher`).
        situations: N start situations.
        num_samples: S residual samples per situation in the model world.
        horizon: steps of the compiled plans (one step: 0.05 s).
        start_steps: K, situations are drawn k ~ U{0..K-1} babbling steps after a reset.
        queries: the query texts.
    """

    babble_steps: int = 3000
    model: ModelConfig = MODEL
    situations: int = 60
    num_samples: int = 32
    horizon: int = 5
    start_steps: int = 100
    queries: tuple[str, ...] = PUSHER_QUERIES

    def __post_init__(self) -> None:
        check_int("babble_steps", self.babble_steps)
        check_int("situations", self.situations, 2)
        check_int("num_samples", self.num_samples, 1)
        check_int("horizon", self.horizon, 1)
        check_int("start_steps", self.start_steps, 0)
        if not self.queries:
            raise ValueError("pusher queries must hold at least one query text")


QUICK_PUSHER = PusherPart(
    babble_steps=1000,
    model=replace(MODEL, schedule=replace(MODEL.schedule, epochs=30)),
    situations=40,
    num_samples=16,
)
TINY_PUSHER = PusherPart(
    babble_steps=40,
    model=ModelConfig(members=2, hidden=(8,), schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None)),
    situations=3,
    num_samples=2,
    horizon=2,
    start_steps=5,
    queries=(PUSHER_QUERIES[4], "P(touch(fingertip, object) | do(hold(fingertip)))"),
)


def pusher_section(
    part: PusherPart, seed: int, tolerance: float, grounding: GroundingConfig | None = None
) -> Section:
    """Babble, fit, draw the situations and answer the Pusher-v5 queries in both worlds.

    ``grounding``: the built-ins' scales (:func:`pal.language.vocabularies.pusher_signature`).
    """
    config = AgentConfig(model=part.model, reset_every=None, servo=False)
    agent = Agent(gymnasium.make(ENV_ID), pusher_spec(), config, seed=seed)
    try:
        agent.run(part.babble_steps, "babble")
        fitted = agent.refit()
    finally:
        agent.env.close()
    model = agent.model
    env = gymnasium.make(ENV_ID)
    try:
        values, states = pusher_situations(
            env, part.situations, np.random.default_rng([seed, 15]), babble_steps=part.start_steps
        )
        given = {k: v for k, v in values.items() if k in model.graph or k == "goal.object"}
        sit = Situations({k: torch.as_tensor(v, dtype=model.dtype) for k, v in given.items()}, states)
        results = play_queries(
            part.queries,
            pusher_signature(horizon=part.horizon, grounding=grounding),
            model,
            ModelWorld(model, held=("goal.object",)),
            PusherWorld(env),
            sit,
            samples=part.num_samples,
            horizon=part.horizon,
            seed=seed,
        )
    finally:
        env.close()
    near = np.linalg.norm(values["ee"][:, :2] - values["pos.object"][:, :2], axis=1)
    return query_section(
        "pusher",
        "Pusher-v5",
        results,
        tolerance,
        caption=f"{part.situations} situations ({part.start_steps} babbling steps at most after a reset); "
        f"plans over {part.horizon} steps; model {part.num_samples} residual samples each.",
        metrics={
            "rows": {k: int(v) for k, v in fitted["rows"].items()},
            "babble_steps": part.babble_steps,
            "start_fingertip_object_xy": [float(np.percentile(near, q)) for q in (25, 50, 75)],
        },
        notes=(
            f"Pusher-v5, seed {seed}, {part.babble_steps} random-torque babbling steps; the goal marker "
            "(not a model variable) held at its start in the model world.",
        ),
    )
