"""The Pusher-v5 part of the LoT experiment: queries over the fingertip, the object and its goal.

The agent (spec :func:`pal.agent.pusher_spec`: joints, velocities, fingertip, the object with
momentum) babbles uniform random torques in Gymnasium's ``Pusher-v5`` (episodes of 100 steps,
as in :mod:`pal.experiments.closed_loop.pusher`). Random torques almost never touch the object,
so ``contact_episodes`` episodes of the **scripted pusher**
(:class:`pal.baselines.scripted_pusher_v5.ScriptedPusherV5`, which reads the true state and
pushes the object towards its goal) are added to the data: every contact the models learn from
comes from those episodes. The primary model (the gated displacement form: ``contact.object``
a Bernoulli switch labelled "the object moved more than MOVED_SIGMAS * position_sigma over the
step", latent in the queries) and the comparison model (the smooth form) are fitted on the
same data (:func:`pal.experiments.language.lot_play.fitted_models`).

Pusher-v5's object is very light and damped: a push moves it at most ~3.4 mm per 50 ms step,
so the moved rule's floor of the agent's default ``position_sigma`` (1 mm: a floor of 3 mm)
would label almost no push; this part's model takes ``position_sigma = 0.1 mm`` (floor 0.3 mm;
the observed positions are exact, an object at rest moves by 0).

N start situations are drawn from the same babbling (:func:`pal.language.sim_worlds.pusher_situations`
with ``babble_steps``: the arm where k random-torque steps after a reset took it, the object at
rest, moved near the fingertip in half of them). The queries (vocabulary
:func:`pal.language.vocabularies.pusher_signature`, the goal marker held constant in the model
world) are compiled over ``horizon`` steps by each model and played in it and in the simulator
(:class:`pal.language.sim_worlds.PusherWorld`) as in :mod:`pal.experiments.language.lot_play`.
With ``motion``, the contact-motion target of :mod:`pal.experiments.language.contact_motion`
is measured for both models.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import gymnasium
import numpy as np
import torch

from pal.agent import Agent, AgentConfig, ModelConfig, pusher_spec
from pal.agent.config import MODEL_SCHEDULE
from pal.agent.graph import MOVED_SIGMAS
from pal.baselines.scripted_pusher_v5 import ScriptedPusherV5
from pal.checks import check_int
from pal.experiments.closed_loop.pusher import MODEL
from pal.experiments.closed_loop.pusher_runs import ENV_ID
from pal.experiments.language.contact_motion import (
    MotionCheck,
    contact_situations,
    motion_targets,
    predicted_motion,
)
from pal.experiments.language.lot_play import QueryResult, Section, fitted_models, play_queries, query_section
from pal.language.sim_worlds import PusherWorld, pusher_situations
from pal.language.vocabularies import pusher_signature
from pal.language.world import ModelWorld, Situations
from pal.perception.grounding import GroundingConfig

__all__ = ["PUSHER_MODEL", "PUSHER_QUERIES", "QUICK_PUSHER", "TINY_PUSHER", "PusherPart", "pusher_section"]

#: The Pusher-v5 queries (text syntax of :mod:`pal.language.syntax`).
PUSHER_QUERIES: tuple[str, ...] = (
    "P(near(fingertip, object) | do(reach(fingertip, object)), not near(fingertip, object))",
    "P(near(fingertip, object) | do(hold(fingertip)), near(fingertip, object))",
    "P(touch(fingertip, object) | do(reach(fingertip, object)), near(fingertip, object))",
    "P(moving(object) | do(push(fingertip, object)), near(fingertip, object))",
    "P(left_of(fingertip, goal) | do(reach(fingertip, object)))",
    "P(near(fingertip, object)[do(hold(fingertip))] | do(reach(fingertip, object)), near(fingertip, object)@end)",
)

#: The part's model: that of :mod:`pal.experiments.closed_loop.pusher`, gated, ``position_sigma`` 0.1 mm (module docstring).
PUSHER_MODEL = replace(MODEL, displacement="gated", position_sigma=1e-4)
#: Steps of a scripted contact episode (Pusher-v5's episode).
EPISODE_STEPS = 100


@dataclass(frozen=True)
class PusherPart:
    """Settings of the Pusher-v5 part.

    Attributes:
        babble_steps: random-torque steps the models are fitted on.
        contact_episodes: scripted-pusher episodes of 100 steps added to the babbling data (0: none).
        model: the primary world model and its fit (the comparison form is set by the experiment).
        situations: N start situations.
        num_samples: S residual samples per situation in the model world.
        horizon: steps of the compiled plans (one step: 0.05 s).
        start_steps: K, situations are drawn k ~ U{0..K-1} babbling steps after a reset.
        queries: the query texts.
        motion: the contact-motion measurement, or None to leave it out.
    """

    babble_steps: int = 3000
    contact_episodes: int = 6
    model: ModelConfig = PUSHER_MODEL
    situations: int = 60
    num_samples: int = 32
    horizon: int = 5
    start_steps: int = 100
    queries: tuple[str, ...] = PUSHER_QUERIES
    motion: MotionCheck | None = MotionCheck()

    def __post_init__(self) -> None:
        check_int("babble_steps", self.babble_steps)
        check_int("contact_episodes", self.contact_episodes, 0)
        check_int("situations", self.situations, 2)
        check_int("num_samples", self.num_samples, 1)
        check_int("horizon", self.horizon, 1)
        check_int("start_steps", self.start_steps, 0)
        if not self.queries:
            raise ValueError("pusher queries must hold at least one query text")


QUICK_PUSHER = PusherPart(
    babble_steps=1000,
    model=replace(PUSHER_MODEL, schedule=replace(PUSHER_MODEL.schedule, epochs=30)),
    situations=40,
    num_samples=16,
)
TINY_PUSHER = PusherPart(
    babble_steps=40,
    contact_episodes=1,
    model=ModelConfig(
        members=2,
        hidden=(8,),
        schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None),
        displacement="gated",
        position_sigma=1e-4,
    ),
    situations=3,
    num_samples=2,
    horizon=2,
    start_steps=5,
    queries=(PUSHER_QUERIES[4], "P(touch(fingertip, object) | do(hold(fingertip)))"),
    motion=MotionCheck(situations=4, episodes=1, num_samples=4),
)


def _seed(*keys: int) -> int:
    return int(np.random.SeedSequence(list(keys)).generate_state(1)[0] % 2**31)


def _contact_episodes(agent: Agent, episodes: int, seed: int) -> None:
    """``episodes`` scripted-pusher episodes (reset seeds from ``seed``), recorded in the agent's history."""
    pusher = ScriptedPusherV5(agent.env)
    for e in range(episodes):
        agent.reset(seed=_seed(seed, 16, e))
        pusher.reset()
        for _ in range(EPISODE_STEPS):
            agent.step(pusher.act()[0])
            if agent.done:
                break


def _moved_episodes(agent: Agent, floor: float) -> int:
    """Episodes of the history in which some object moved by more than ``floor`` m over a step."""
    h = agent.history
    step = np.linalg.norm(h.array("meas") - h.array("meas_prev"), axis=-1)  # (N, O), NaN where unseen
    moved = np.nan_to_num(step, nan=0.0).max(1) > floor
    return len(set(h.array("episode")[moved].tolist()))


def _queries(
    part: PusherPart, models: dict[str, Any], seed: int, grounding: GroundingConfig | None
) -> tuple[dict[str, list[QueryResult]], np.ndarray]:
    env = gymnasium.make(ENV_ID)
    try:
        values, states = pusher_situations(
            env, part.situations, np.random.default_rng([seed, 15]), babble_steps=part.start_steps
        )
        out = {}
        for name, (model, _) in models.items():
            given = {k: v for k, v in values.items() if k in model.graph or k == "goal.object"}
            sit = Situations({k: torch.as_tensor(v, dtype=model.dtype) for k, v in given.items()}, states)
            out[name] = play_queries(
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
    return out, np.linalg.norm(values["ee"][:, :2] - values["pos.object"][:, :2], axis=1)


def _motion(
    part: PusherPart, models: dict[str, Any], seed: int, moved: int
) -> tuple[dict[str, Any], Any, list]:
    assert part.motion is not None
    floor = MOVED_SIGMAS * part.model.position_sigma
    env = gymnasium.make(ENV_ID)
    try:
        seeds = [_seed(seed, 17, e) for e in range(part.motion.episodes)]
        situations = contact_situations(env, part.motion, seeds, floor)
    finally:
        env.close()
    empty = {f"{k}_{w}": np.zeros(0) for k in ("expected", "predictive") for w in ("on", "far")}
    predicted = {
        n: predicted_motion(m, situations, part.motion, seed) if situations["sim_on"].size else empty
        for n, (m, _) in models.items()
    }
    return motion_targets(predicted, situations, part.motion, moved)


def pusher_section(
    part: PusherPart,
    seed: int,
    tolerance: float,
    grounding: GroundingConfig | None = None,
    comparison: str | None = None,
) -> Section:
    """Babble, add the scripted contact episodes, fit, and answer the Pusher-v5 queries in both worlds.

    ``grounding``: the built-ins' scales (:func:`pal.language.vocabularies.pusher_signature`).
    ``comparison``: the displacement form of the comparison model (None: the primary alone).
    """
    config = AgentConfig(model=part.model, reset_every=None, servo=False)
    agent = Agent(gymnasium.make(ENV_ID), pusher_spec(), config, seed=seed)
    try:
        agent.run(part.babble_steps, "babble")
        _contact_episodes(agent, part.contact_episodes, seed)
        models = fitted_models(agent, part.model, comparison, seed + len(agent.history), "perceived")
    finally:
        agent.env.close()
    moved = _moved_episodes(agent, MOVED_SIGMAS * part.model.position_sigma)
    results, near = _queries(part, models, seed, grounding)
    section = query_section(
        "pusher",
        "Pusher-v5",
        results,
        tolerance,
        caption=f"{part.situations} situations ({part.start_steps} babbling steps at most after a reset); "
        f"plans over {part.horizon} steps; model {part.num_samples} residual samples each.",
        metrics={
            "rows": {n: r for n, (_, r) in models.items()},
            "babble_steps": part.babble_steps,
            "contact_episodes": part.contact_episodes,
            "moved_episodes": moved,
            "start_fingertip_object_xy": [float(np.percentile(near, q)) for q in (25, 50, 75)],
        },
        notes=(
            f"Pusher-v5, seed {seed}, {part.babble_steps} random-torque babbling steps and {part.contact_episodes} "
            f"episodes of the scripted pusher (the only source of contact in the data; the object moved in {moved} "
            "episodes); the goal marker (not a model variable) held at its start in the model world.",
        ),
    )
    if part.motion is None:
        return section
    metrics, table, targets = _motion(part, models, seed, moved)
    return replace(
        section,
        metrics={**section.metrics, "contact_motion": metrics},
        tables=(*section.tables, table),
        targets=(*section.targets, *targets),
    )
