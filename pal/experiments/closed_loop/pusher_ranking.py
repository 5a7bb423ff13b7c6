"""Does a learner's model order candidate plans as the true dynamics would? The planning-relevant model error.

An MPC learner acts well when its model ranks the candidates its planner compares in the true
order, however far off each prediction is; it learns nothing from a 25-step error alone. The
probes are states of the planner's ceiling episodes (the learners' planner and cost with the true
simulator, :class:`pal.baselines.simulator_mpc.SimulatorMPC`), so the fingertip reaches and
pushes the object there. At a probe, candidates a^(n) (n = 1..N, the first the ceiling's own
plan) are that plan plus colored noise (exponent ``beta``, sd ``spread`` in torque units),
clipped to the bounds; then

    C_true(n)  = sum_t c(obs_t(a^(n)), a^(n)_t)    obs_t from the exact state by MuJoCo
    C_model(n) = the learner's prediction of the same sum (the mean over its members)
    rho        = Spearman(C_true, C_model)          rho_obj: of the final object-goal distance (x-y)
    regret     = (C_true(argmin C_model) - min C_true) / (median C_true - min C_true)

``regret`` is 0 when the model picks the best candidate and 1 for a median one. ``rho_obj`` is
undefined (None) at a probe where the model predicts the same final object position for every
candidate (a model that has seen no push). Scores are medians over probes.

:func:`arm_forced_score` separates the object layer's error from the arm's: the agent's model
rolls the object forward as before, while the arm's sites are set to the true trajectory of each
candidate at every step, ``do(q_t, v_t, ee_t = truth)`` (given values replace their mechanisms in
:meth:`models.forward.ForwardQueries.predict`); the object's prediction, the mean over the
members at each step, feeds its next step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium
import numpy as np
import torch
from scipy.stats import spearmanr

from inference.planning import colored_noise
from pal.agent.config import PlanConfig
from pal.baselines.simulator_mpc import PUSHER_BODIES, SimulatorMPC, pusher_observation
from pal.checks import check_float, check_int
from pal.experiments.closed_loop.pusher_runs import roots, step_cost

__all__ = ["Probe", "RankingConfig", "arm_forced_score", "pal_predictor", "pets_predictor", "probes", "score"]

#: ``(previous obs (D,), obs (D,), actions (N, H, A)) -> (summed cost (N,), final obs (N, D))``.
Predictor = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
_OBJ, _GOAL = slice(17, 20), slice(20, 23)


@dataclass(frozen=True)
class RankingConfig:
    """Where and how the models' rankings are probed (module docstring).

    Attributes:
        goals: ceiling episodes per seed that give the probes (0: no ranking scores).
        steps: steps per ceiling episode; every: a probe every this many steps (from step ``every - 1``).
        candidates: N per probe. spread: the candidates' noise sd, torque units. beta: its colour exponent.
    """

    goals: int = 3
    steps: int = 70
    every: int = 10
    candidates: int = 60
    spread: float = 0.5
    beta: float = 2.0

    def __post_init__(self) -> None:
        check_int("ranking.goals", self.goals, minimum=0)
        for name in ("steps", "every"):
            check_int(f"ranking.{name}", getattr(self, name))
        check_int("ranking.candidates", self.candidates, minimum=3)
        check_float("ranking.spread", self.spread, 0.0, open_low=True)
        check_float("ranking.beta", self.beta, 0.0)


@dataclass(frozen=True)
class Probe:
    """One probe: the observations before and at it (D,), candidates (N, H, A) and their true observations (N, H, D)."""

    previous: np.ndarray
    obs: np.ndarray
    actions: np.ndarray
    truth: np.ndarray


def probes(env: gymnasium.Env, plan: PlanConfig, config: RankingConfig, seeds: list[int]) -> list[Probe]:
    """Probes along ceiling episodes from ``env.reset(seed=s)`` for the first ``config.goals`` of ``seeds``."""
    cost = step_cost(plan)
    out: list[Probe] = []
    for s in seeds[: config.goals]:
        obs, _ = env.reset(seed=s)
        planner = SimulatorMPC(env, plan, cost, pusher_observation, PUSHER_BODIES, seed=s)
        generator = torch.Generator().manual_seed(s)
        previous = np.asarray(obs, dtype=np.float64)
        for t in range(config.steps):
            action, _ = planner.act()
            if t % config.every == config.every - 1:
                out.append(_probe(planner, previous, np.asarray(obs, np.float64), config, generator))
            previous = np.asarray(obs, dtype=np.float64)
            obs, _, terminated, truncated, _ = env.step(action.astype(np.float32))
            if terminated or truncated:
                break
    return out


def _probe(
    planner: SimulatorMPC,
    previous: np.ndarray,
    obs: np.ndarray,
    config: RankingConfig,
    generator: torch.Generator,
) -> Probe:
    plan = planner.plan.numpy().astype(np.float64)  # (H, A), the sequence the ceiling just chose
    n, (h, a) = config.candidates, plan.shape
    noise = colored_noise((n, a, h), config.beta, generator, torch.float64).numpy().transpose(0, 2, 1)
    low, high = planner.low.numpy(), planner.high.numpy()
    actions = np.clip(plan[None] + config.spread * noise, low, high)
    actions[0] = plan
    return Probe(previous, obs, actions, planner.predict(planner.state(), actions))


def score(found: list[Probe], predict: Predictor, plan: PlanConfig) -> dict[str, float | int | None]:
    """Median ``rho``, ``rho_obj`` and ``regret`` over the probes (module docstring), and their count."""
    cost = step_cost(plan)
    rho, rho_obj, regret = [], [], []
    for p in found:
        true = cost(torch.as_tensor(p.truth), torch.as_tensor(p.actions)).sum(-1).numpy()
        model, final = predict(p.previous, p.obs, p.actions)
        rho.append(_spearman(true, model))
        goal = p.obs[_GOAL][:2]
        rho_obj.append(
            _spearman(
                np.linalg.norm(p.truth[:, -1, _OBJ][:, :2] - goal, axis=-1),
                np.linalg.norm(final[:, _OBJ][:, :2] - goal, axis=-1),
            )
        )
        spread = float(np.median(true) - true.min())
        regret.append(float(true[int(np.argmin(model))] - true.min()) / spread if spread > 0 else None)
    return {"rho": _median(rho), "rho_obj": _median(rho_obj), "regret": _median(regret), "probes": len(found)}


def _median(values: list[float | None]) -> float | None:
    """The median of the defined values, None when there are none."""
    v = [x for x in values if x is not None]
    return float(np.median(v)) if v else None


def _spearman(a: np.ndarray, b: np.ndarray) -> float | None:
    if np.ptp(a) <= 1e-12 or np.ptp(b) <= 1e-12:
        return None
    return float(spearmanr(a, b).statistic)


def pal_predictor(model: object, plan: PlanConfig) -> Predictor:
    """The agent's world model on Pusher-v5's layout: its members' rollouts, the step cost averaged over members."""
    cost = step_cost(plan)

    def predict(previous: np.ndarray, obs: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, h, _ = actions.shape
        state = roots(previous, obs)
        dtype = model.dtype  # type: ignore[attr-defined]
        graph = model.graph  # type: ignore[attr-defined]
        lagged = [r for r in graph.roots if graph[r].lag == 1]
        init = {r: torch.as_tensor(np.tile(state[r], (n, 1)), dtype=dtype) for r in lagged}
        act = torch.as_tensor(actions, dtype=dtype)
        out = model.rollout(init, {"act": act}, members=True)  # type: ignore[attr-defined]
        k = out["ee"].shape[0]
        goal = torch.as_tensor(np.broadcast_to(obs[_GOAL], (k, n, h, 3)).copy(), dtype=dtype)
        pred = torch.cat([out["q"], out["v"], out["ee"], out["pos.object"], goal], -1)
        total = cost(pred, act.expand(k, n, h, act.shape[-1])).sum(-1).mean(0)
        return total.numpy().astype(np.float64), pred[:, :, -1].mean(0).numpy().astype(np.float64)

    return predict


def _arm_forced(model: object, plan: PlanConfig, truth: np.ndarray) -> Predictor:
    """The agent's model with the arm set to ``truth`` (N, H, D) at every step (module docstring); mean over members."""
    cost = step_cost(plan)

    def predict(previous: np.ndarray, obs: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, h, _ = actions.shape
        dtype = model.dtype  # type: ignore[attr-defined]
        act, true = torch.as_tensor(actions, dtype=dtype), torch.as_tensor(truth, dtype=dtype)
        state = {k: torch.as_tensor(np.tile(v, (n, 1)), dtype=dtype) for k, v in roots(previous, obs).items()}
        goal = torch.as_tensor(np.tile(obs[_GOAL], (n, 1)), dtype=dtype)
        steps = []
        for t in range(h):
            arm = {"q": true[:, t, :7], "v": true[:, t, 7:14], "ee": true[:, t, 14:17]}
            with torch.no_grad():
                pos = model.predict({**state, **arm, "act": act[:, t]}, members=True)["pos.object"].mean(0)  # type: ignore[attr-defined]
            state = {
                "q_prev": arm["q"],
                "v_prev": arm["v"],
                "ee_prev": arm["ee"],
                "pos_prev.object": pos,
                "vel_prev.object": pos - state["pos_prev.object"],
            }
            steps.append(torch.cat([arm["q"], arm["v"], arm["ee"], pos, goal], -1))
        pred = torch.stack(steps, 1)
        return cost(pred, act).sum(-1).numpy().astype(np.float64), pred[:, -1].numpy().astype(np.float64)

    return predict


def arm_forced_score(found: list[Probe], model: object, plan: PlanConfig) -> dict[str, float | int | None]:
    """:func:`score` of the agent's model with its arm forced to each candidate's true trajectory (module docstring).

    Adds ``error``: the RMS over a probe's candidates of the predicted final object x-y position
    against the true one, m, and ``spread``: the RMS of the true final x-y positions around their
    mean, m (an error above it ranks worse than predicting one position for all); medians over probes.
    """
    per_probe, error, spread = [], [], []
    for p in found:
        predicted = _arm_forced(model, plan, p.truth)(p.previous, p.obs, p.actions)
        per_probe.append(score([p], lambda *_, result=predicted: result, plan))
        final = predicted[1][:, _OBJ][:, :2]
        true = p.truth[:, -1, _OBJ][:, :2]
        error.append(float(np.sqrt(((final - true) ** 2).sum(-1).mean())))
        spread.append(float(np.sqrt(((true - true.mean(0)) ** 2).sum(-1).mean())))
    out: dict[str, float | int | None] = {
        k: _median([r[k] for r in per_probe]) for k in ("rho", "rho_obj", "regret")
    }
    return {**out, "error": _median(error), "spread": _median(spread), "probes": len(found)}


def pets_predictor(learner: object) -> Predictor:
    """The baseline's ensemble through its planner's own cost (:meth:`pal.baselines.pets.CEMPlanner.costs`)."""

    def predict(previous: np.ndarray, obs: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o = torch.as_tensor(obs, dtype=torch.float32)[None]
        with torch.no_grad():
            total, final = learner.planner.costs(o, torch.as_tensor(actions, dtype=torch.float32))  # type: ignore[attr-defined]
        return total.numpy().astype(np.float64), final.numpy().astype(np.float64)

    return predict
