"""Experiment ``pusher-drift``: how far the agent's learned arm model drifts open-loop on Pusher-v5.

A planner that looks H steps ahead needs the model's H-step predictions, not its one-step ones.
The agent (:func:`pal.agent.pusher_spec`, the ``pusher`` experiment's world model) babbles
``train_episodes`` episodes of uniform random torques and fits once. Held-out episodes, each
from its own seeded reset, apply colored-noise torques like the planner's samples (exponent
``beta``, sd ``torque_sd`` in torque units, clipped to the bounds). From every ``stride``-th step s
of a held-out episode the model rolls the recorded torques forward ``rollout_steps`` steps with no
feedback (:meth:`models.WorldModel.rollout`, the mean over members), and is scored at the
checkpoints k of ``steps``:

    joint error(k) = || q_hat(s + k) - q(s + k) ||_2          (rad, over the 7 joints)
    tip error(k)   = || ee_hat(s + k) - ee(s + k) ||_2        (m)
    tip stays(k)   = || ee(s) - ee(s + k) ||_2                 (the predictor "the tip stays put")

with medians over the starts. ``limits`` is the share of held-out states within 0.02 rad of a
joint limit of the MJCF, where MuJoCo's limit constraint takes over the joint.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import gymnasium
import numpy as np
import torch

from inference.planning import colored_noise
from pal.agent import Agent, AgentConfig, ModelConfig, pusher_spec
from pal.agent.config import MODEL_SCHEDULE
from pal.checks import check_float, check_int
from pal.experiments.closed_loop.pusher import MODEL
from pal.experiments.closed_loop.pusher_runs import ENV_ID, roots
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target

__all__ = ["Config", "run"]

_STEPS = 100  # Pusher-v5 truncates its episodes here


@dataclass(frozen=True)
class Config:
    """The ``pusher-drift`` protocol (module docstring).

    Attributes:
        seed: the agent's seed; training episodes reset with ``seed`` and held-out ones with ``seed + 1``.
        train_episodes: random-torque episodes of 100 steps the model is fitted on.
        test_episodes: held-out colored-noise episodes of 100 steps.
        rollout_steps: open-loop steps per start. stride: steps between starts. steps: the checkpoints k.
        torque_sd: sd of the held-out torques. beta: their colour exponent.
        model: the agent's world model and fit.
    """

    seed: int = 0
    train_episodes: int = 30
    test_episodes: int = 10
    rollout_steps: int = 25
    stride: int = 5
    steps: tuple[int, ...] = (1, 5, 10, 25)
    torque_sd: float = 0.5
    beta: float = 2.0
    model: ModelConfig = MODEL

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        for name in ("train_episodes", "test_episodes", "stride"):
            check_int(name, getattr(self, name))
        check_int("rollout_steps", self.rollout_steps, maximum=_STEPS - 1)
        if not self.steps or any(not 1 <= k <= self.rollout_steps for k in self.steps):
            raise ValueError(
                f"steps {self.steps!r}: expected checkpoints in [1, rollout_steps={self.rollout_steps}]"
            )
        check_float("torque_sd", self.torque_sd, 0.0, open_low=True)
        check_float("beta", self.beta, 0.0)


QUICK = Config(train_episodes=5, test_episodes=3)
TINY = Config(
    train_episodes=1,
    test_episodes=1,
    rollout_steps=3,
    stride=40,
    steps=(1, 3),
    model=ModelConfig(members=2, hidden=(8,), schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None)),
)


def _held_out(env: gymnasium.Env, config: Config) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(observations (101, 23), torques (100, 7))`` per held-out episode."""
    generator = torch.Generator().manual_seed(config.seed + 1)
    low, high = env.action_space.low, env.action_space.high
    out = []
    for e in range(config.test_episodes):
        obs, _ = env.reset(seed=int(np.random.SeedSequence([config.seed + 1, e]).generate_state(1)[0]))
        noise = colored_noise((7, _STEPS), config.beta, generator, torch.float64).numpy().T
        torques = np.clip(config.torque_sd * noise, low, high)
        path = [obs]
        for a in torques:
            obs, *_ = env.step(a.astype(np.float32))
            path.append(obs)
        out.append((np.asarray(path, dtype=np.float64), torques))
    return out


def _starts(episodes: list[tuple[np.ndarray, np.ndarray]], config: Config) -> dict[str, np.ndarray]:
    """The lag-1 roots at each start (N, d), the torques (N, H, 7), and the true angles and tip (N, H, d)."""
    h = config.rollout_steps
    parts: dict[str, list[np.ndarray]] = {}
    for obs, torques in episodes:
        s = np.arange(1, _STEPS - h + 1, config.stride)
        window = s[:, None] + np.arange(h)  # (n, H): the steps each start rolls over
        found = roots(obs[s - 1], obs[s])
        found |= {"act": torques[window], "q": obs[window + 1, :7], "ee": obs[window + 1, 14:17]}
        for key, value in found.items():
            parts.setdefault(key, []).append(value)
    return {k: np.concatenate(v) for k, v in parts.items()}


def _fit(env: gymnasium.Env, config: Config) -> tuple[Agent, float]:
    """The agent after babbling ``train_episodes`` random episodes and one fit; the fit's CPU seconds."""
    agent = Agent(
        env, pusher_spec(), AgentConfig(model=config.model, reset_every=None, servo=False), seed=config.seed
    )
    for e in range(config.train_episodes):
        agent.reset(seed=int(np.random.SeedSequence([config.seed, e]).generate_state(1)[0]))
        for _ in range(_STEPS):
            agent.step(agent.random_action())
    start = time.process_time()
    agent.refit()
    return agent, time.process_time() - start


@register("pusher-drift", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """The open-loop drift of the agent's learned arm model on Pusher-v5 (module docstring)."""
    env = gymnasium.make(ENV_ID)
    agent, fit_cpu = _fit(env, config)
    starts = _starts(_held_out(env, config), config)
    model = agent.model
    lagged = [r for r in model.graph.roots if model.graph[r].lag == 1]
    init = {r: torch.as_tensor(starts[r], dtype=model.dtype) for r in lagged}
    out = model.rollout(init, {"act": torch.as_tensor(starts["act"], dtype=model.dtype)})
    joint = np.linalg.norm(out["q"].numpy() - starts["q"], axis=-1)
    tip = np.linalg.norm(out["ee"].numpy() - starts["ee"], axis=-1)
    stays = np.linalg.norm(starts["ee"] - starts["ee_prev"][:, None], axis=-1)
    low, high = env.unwrapped.model.jnt_range[:7].T
    q = starts["q"].reshape(-1, 7)
    near_limit = float(np.mean((q < low + 0.02) | (q > high - 0.02)))
    env.close()
    rows = [
        [
            k,
            float(np.median(joint[:, k - 1])),
            float(np.median(tip[:, k - 1])),
            float(np.median(stays[:, k - 1])),
        ]
        for k in config.steps
    ]
    metrics = {
        "starts": len(joint),
        "fit_cpu_seconds": fit_cpu,
        "near_limit_share": near_limit,
        "steps": {str(r[0]): {"joint": r[1], "tip": r[2], "tip_stays": r[3]} for r in rows},
    }
    last = rows[-1]
    target = Target(
        f"tip_error_over_stays_at_{last[0]}",
        last[2] / last[3] if last[3] > 0 else None,
        1.0,
        "<=",
        f"the model's median tip error after {last[0]} open-loop steps over that of 'the tip stays put'",
        Precondition(
            config.test_episodes >= 10 and config.train_episodes >= 10,
            f">= 10 held-out and >= 10 training episodes (this run: {config.test_episodes} and {config.train_episodes})",
        ),
    )
    return Report(
        title="Pusher-v5: open-loop drift of the agent's learned arm model on held-out colored-noise torques",
        metrics=metrics,
        tables=[
            Table(
                "Median open-loop error after k steps",
                ["k", "joint error [rad]", "tip error [m]", "tip stays put [m]"],
                rows,
                caption="The model rolls the recorded torques forward with no feedback from each start; "
                "'tip stays put' is the error of predicting no tip motion.",
            )
        ],
        targets=[target],
        notes=[
            f"Fitted on {config.train_episodes} random-torque episodes of {_STEPS} steps ({fit_cpu:.1f} s CPU); "
            f"{len(joint)} starts on {config.test_episodes} held-out episodes of colored-noise torques "
            f"(beta {config.beta}, sd {config.torque_sd}); {near_limit:.0%} of their states are within 0.02 rad "
            "of a joint limit of the MJCF."
        ],
    )
