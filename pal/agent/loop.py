"""The agent: the closed perception-action loop of thesis §4.1 (Eq. 4.1-4.4), Alg. 4.1-4.2, §6.3.

At every step t the agent

1. renders o(t) = [RGB-D, q] (:meth:`Agent.perceive`);
2. runs Π on the self-filtered frame and reads each tracked object's table position with its
   uncertainty (from the pose diagnostics) (:mod:`pal.agent.perception`);
3. forms s(t) = s_vis(t) ∪ q(t) (Eq. 4.3): joint angles, hand position and touch are sensed,
   object positions perceived;
4. gives the perceived positions to the world model through the measurement sites
   ``meas.o ~ Normal(pos.o, sigma_perception(t))``: :func:`inference.infer_state` with
   ``measurement_scale`` returns the posterior over the true position ``pos.o`` given the last
   transition (Eq. 4.41-4.42). A lost object has no measurement site: it is unobserved and its
   posterior is the model's prediction; no NaN ever reaches the model;
5. takes a target over an object variable, from curiosity (:class:`pal.agent.curiosity.GridCuriosity`,
   Eq. 4.34-4.38) or from a user goal;
6. infers the action with :func:`inference.infer_action` (Alg. 4.2), from ``action_starts`` random
   starts, keeping the best under the model;
7. steps the environment (``do(a)``, Eq. 4.48) and records the transition (:class:`pal.agent.history.History`).

:meth:`Agent.run` babbles first (random servo targets, half of them small moves), fits the pushing world model
(:func:`models.pushing_graph`, Eq. 4.33), then learns online, curiosity-driven, refitting every
``refit_every`` steps. Episodes end every ``reset_every`` steps (the objects are put back).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import pyro
import torch
from tqdm import tqdm

from inference import infer_action, infer_state
from models import WorldModel
from pal.agent.config import AgentConfig
from pal.agent.curiosity import GridCuriosity
from pal.agent.history import History
from pal.agent.perception import Measurement, ObjectSlots, self_filtered_frame
from pal.agent.world import build_world_model, candidate_actions, fit_world_model, submodel
from pal.checks import check_int
from pal.perception import PerceptionState, Pipeline
from pal.sim.camera import CameraFrame
from pal.sim.pushing import JOINTS, PushingEnv

__all__ = ["MODES", "Agent", "AgentConfig", "Decision", "Percept"]

log = logging.getLogger(__name__)

#: Ways :meth:`Agent.decide` chooses an action.
MODES = ("babble", "curious", "goal")


@dataclass(frozen=True, eq=False)
class Percept:
    """o(t) and what Π made of it.

    Attributes:
        frame: the rendered camera view. perception: Π's state.
        measurements: slot -> :class:`Measurement` or None (lost).
        q: (J,) joint angles, rad. hand: (3,) hand position, m (table frame).
        table_from_camera: (4, 4) camera pose. time: s on the agent's clock.
    """

    frame: CameraFrame
    perception: PerceptionState
    measurements: dict[str, Measurement | None]
    q: np.ndarray
    hand: np.ndarray
    table_from_camera: np.ndarray
    time: float


@dataclass(frozen=True)
class Decision:
    """An action and why it was chosen.

    Attributes:
        mode: babble / curious / goal / setup / hold.
        action: (J,) servo targets, rad.
        targets: slot -> (2,) target position, m.
        predicted: slot -> (2,) position the model predicts, m (after the setup step for ``"setup"``).
        objective: predicted distance to the targets, m.
    """

    mode: str
    action: np.ndarray
    targets: dict[str, np.ndarray] = field(default_factory=dict)
    predicted: dict[str, np.ndarray] = field(default_factory=dict)
    objective: float | None = None


class Agent:
    """The perception-action loop around a :class:`PushingEnv` (module docstring).

    Args:
        env: the world. config: loop settings.
        seed: master seed (actions, targets, inference seeds, episode resets, the model's
            initial weights and its fits).
        model: a fitted world model to start from (default: a fresh one, fitted after babbling).
        goal: optional user goal, slot -> (x, y) table position, m (used in ``"goal"`` mode).
    """

    def __init__(
        self,
        env: PushingEnv,
        config: AgentConfig | None = None,
        *,
        seed: int = 0,
        model: WorldModel | None = None,
        goal: Mapping[str, Any] | None = None,
    ) -> None:
        self.env, self.config = env, config or AgentConfig()
        self.seed = check_int("seed", seed, minimum=0)
        cfg = self.config
        unknown = [o for o in cfg.objects if o not in env.objects]
        if unknown:
            raise ValueError(f"objects {unknown} are not in the environment; it has {list(env.objects)}")
        self.joints = tuple(JOINTS)
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 2]))
        self.model = model if model is not None else build_world_model(env, cfg.objects, cfg.hidden, seed)
        self.fitted = model is not None
        self.history = History(
            self.joints, cfg.objects, provenance={"seed": self.seed, "config": asdict(cfg)}
        )
        self.pipeline = Pipeline(cfg.perception)
        self.slots = ObjectSlots(cfg.objects, use_top=cfg.top_surface)
        (x0, y0), (x1, y1) = cfg.region
        self.curiosity = {o: GridCuriosity((x0, y0), (x1, y1), cfg.bins, cfg.alpha) for o in cfg.objects}
        self.goal = {} if goal is None else self._check_targets(goal)
        self.episode, self.steps, self.episode_steps, self.clock = -1, 0, 0, 0.0
        self.estimate: dict[str, np.ndarray | None] = {}
        self._target_index = 0
        self._blankets: dict[tuple[str, ...], WorldModel] = {}
        self.percept: Percept | None = None

    # ------------------------------------------------------------------ o(t) -> s(t)
    def _check_targets(self, targets: Mapping[str, Any]) -> dict[str, np.ndarray]:
        out = {}
        for name, value in targets.items():
            if name not in self.config.objects:
                raise ValueError(
                    f"target names unknown object {name!r}; objects are {list(self.config.objects)}"
                )
            v = np.asarray(value, dtype=np.float64)
            if v.shape != (2,) or not np.all(np.isfinite(v)):
                raise ValueError(f"target of {name!r} is {value!r}; expected a finite (x, y) in metres")
            out[name] = v
        return out

    def perceive(self) -> Percept:
        """Render o(t) = [RGB-D, q] and run Π (steps 1-3 of the module docstring)."""
        env = self.env
        view = env.camera_frame()
        frame = self_filtered_frame(view.rgb, view.depth, view.K, self.clock, env.arm_mask(view))
        state = self.pipeline(frame)
        T = env.table_from_camera(view)
        return Percept(
            view,
            state,
            self.slots.update(state, T, self.estimate, float(view.K[1, 1]), frame),
            env.data.qpos[env.qpos_indices].copy(),
            env.hand_position(),
            T,
            self.clock,
        )

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Percept:
        """Start an episode: reset the world and perception; the estimate is the first measurement."""
        self.episode += 1
        self.episode_steps = 0
        if seed is None:
            seed = int(np.random.SeedSequence([self.seed, 3, self.episode]).generate_state(1)[0])
        self.env.reset(seed=seed, options=options)
        self.pipeline.reset()
        self.slots.reset()
        self.estimate = {}
        self.percept = self.perceive()
        self.estimate = {
            o: (None if m is None else m.position.copy()) for o, m in self.percept.measurements.items()
        }
        self._visit()
        return self.percept

    def _visit(self) -> None:
        for o, e in self.estimate.items():
            if e is not None:
                self.curiosity[o].partial_fit(e)

    def _blanket(self, objects: tuple[str, ...]) -> WorldModel:
        if objects not in self._blankets:
            self._blankets[objects] = submodel(self.model, objects, blanket=True)
        return self._blankets[objects]

    def state_posterior(
        self, prev: Percept, est_prev: dict[str, np.ndarray | None], new: Percept, touch: np.ndarray
    ) -> dict[str, np.ndarray | None]:
        """Posterior mean of pos.o after the transition (Eq. 4.41-4.42) through the measurement sites.

        The evidence is the sensed hand before and after, the previous estimate ``pos_prev.o``,
        touch ``contact.o`` and, for a visible object, ``meas.o`` with perception's sigma; a lost
        object's ``meas.o`` is left unobserved, so its posterior is the model's prediction.
        """
        meas = new.measurements
        if not self.fitted:
            return {o: (m.position.copy() if m is not None else est_prev[o]) for o, m in meas.items()}
        known = tuple(o for o in self.config.objects if est_prev[o] is not None)
        out = {o: (None if meas[o] is None else meas[o].position.copy()) for o in self.config.objects}
        if not known:  # nothing seen yet in this episode: the first measurement starts the estimate
            return out
        obs: dict[str, Any] = {"hand_prev": prev.hand[None], "hand": new.hand[None]}
        scales = {}
        for k, o in enumerate(self.config.objects):
            if o not in known:
                continue
            obs[f"pos_prev.{o}"] = est_prev[o][None]
            obs[f"contact.{o}"] = np.array([[touch[k]]])
            m = meas[o]
            if m is not None:
                obs[f"meas.{o}"] = m.position[None]
                scales[f"meas.{o}"] = torch.as_tensor(m.std[None], dtype=torch.get_default_dtype())
        cfg = self.config
        with pyro.validation_enabled(False):  # the evidence was checked above; validation only adds cost
            post = infer_state(
                self._blanket(known),
                obs,
                measurement_scale=scales or None,
                num_steps=cfg.state_steps,
                lr=cfg.state_lr,
                lr_final=cfg.state_lr_final,
                num_particles=16,
                num_samples=64,
                init_scale=cfg.state_init_scale,
                guide=cfg.state_guide,
                seed=int(self.rng.integers(2**31)),
            )
        for o in known:
            out[o] = post.mean[f"pos.{o}"][0].numpy().astype(np.float64)
        return out

    # ------------------------------------------------------------------ target -> action
    def _base_state(self, n: int) -> dict[str, Any]:
        state: dict[str, Any] = {
            f"q_prev.{j}": np.full((n, 1), self.percept.q[c]) for c, j in enumerate(self.joints)
        }
        for o, e in self.estimate.items():
            if e is not None:
                state[f"pos_prev.{o}"] = np.tile(e, (n, 1))
        return state

    def _infer(
        self, state: Mapping[str, Any], targets: Mapping[str, np.ndarray], n: int
    ) -> tuple[Any, np.ndarray]:
        """Alg. 4.2 for n units at once; returns the result and each unit's predicted distance, m."""
        cfg = self.config
        result = infer_action(
            self.model,
            state,
            {f"pos.{o}": np.tile(t, (n, 1)) for o, t in targets.items()},
            scale=cfg.target_scale,
            steps=cfg.action_steps,
            lr=cfg.action_lr,
            init="random",
            seed=int(self.rng.integers(2**31)),
        )
        dist = sum(
            np.linalg.norm(result.predicted[f"pos.{o}"].numpy() - t, axis=1) for o, t in targets.items()
        )
        return result, np.asarray(dist, dtype=np.float64)

    def plan(self, targets: Mapping[str, Any], lookahead: bool | None = None) -> Decision:
        """The action whose predicted outcome is closest to ``targets`` (slot -> (2,) m).

        Direct: Alg. 4.2 from ``action_starts`` random starts, the best under the model wins.
        With ``lookahead`` (default ``config.lookahead``) also two steps: ``action_starts``
        candidate first actions (:func:`candidate_actions`) are simulated through the model
        (Alg. 4.1; small moves only, so that a mispredicted sweep cannot fling the object) and
        Alg. 4.2 infers the follow-up from each predicted state; a first action
        whose follow-up is predicted to end ``lookahead_margin`` m closer than the best direct
        action is taken instead (mode ``"setup"``: it repositions the hand for the next push).
        """
        cfg = self.config
        if self.percept is None:
            raise ValueError("call reset() before plan()")
        targets = self._check_targets(targets)
        missing = [o for o in targets if self.estimate.get(o) is None]
        if missing:
            raise ValueError(f"no state estimate for {missing}; they have not been perceived in this episode")
        k = cfg.action_starts
        direct, dist = self._infer(self._base_state(k), targets, k)
        best = int(np.argmin(dist))
        action = np.array([float(direct.actions[f"act.{j}"][best, 0]) for j in self.joints])
        predicted = {o: direct.predicted[f"pos.{o}"][best].numpy().astype(np.float64) for o in targets}
        mode, score = "goal", float(dist[best])
        if cfg.lookahead if lookahead is None else lookahead:
            first = candidate_actions(
                self.percept.q, self.env.ctrl_low, self.env.ctrl_high, self.rng, k, wide=0.0
            )
            values = {
                **self._base_state(k),
                **{f"act.{j}": first[:, c : c + 1] for c, j in enumerate(self.joints)},
            }
            step1 = self.model.predict(values)
            state2 = {f"q_prev.{j}": step1[f"q.{j}"] for j in self.joints}
            state2.update(
                {f"pos_prev.{o}": step1[f"pos.{o}"] for o in self.estimate if self.estimate[o] is not None}
            )
            _, dist2 = self._infer(state2, targets, k)
            b2 = int(np.argmin(dist2))
            if dist2[b2] < score - cfg.lookahead_margin:
                action, mode, score = first[b2].astype(np.float64), "setup", float(dist2[b2])
                predicted = {o: step1[f"pos.{o}"][b2].numpy().astype(np.float64) for o in targets}
        return Decision(mode, action, dict(targets), predicted, score)

    def random_action(self) -> np.ndarray:
        """A babbling action: (J,) servo targets, rad.

        Uniform over the joint ranges, or, with probability ``babble_local``, within
        ``babble_reach`` rad of the current angles (small moves).
        """
        low, high = self.env.ctrl_low, self.env.ctrl_high
        if self.percept is not None and self.rng.random() < self.config.babble_local:
            r = self.config.babble_reach
            return np.clip(self.percept.q + self.rng.uniform(-r, r, size=len(low)), low, high)
        return self.rng.uniform(low, high)

    def decide(self, mode: str) -> Decision:
        """Choose a(t): ``"babble"`` (random), ``"curious"`` (curiosity target, Eq. 4.38) or ``"goal"``."""
        if mode not in MODES:
            raise ValueError(f"mode {mode!r} unknown; expected one of {MODES}")
        if mode == "babble" or not self.fitted:
            return Decision("babble", self.random_action())
        known = [o for o in self.config.objects if self.estimate.get(o) is not None]
        if mode == "goal":
            goal = {o: t for o, t in self.goal.items() if o in known}
            if not goal:
                return Decision("hold", self.percept.q.copy())
            now = sum(float(np.linalg.norm(self.estimate[o] - t)) for o, t in goal.items())
            if now <= self.config.goal_tolerance:
                return Decision("hold", self.percept.q.copy(), goal)
            d = self.plan(goal)
            if d.objective is None or d.objective > now - self.config.min_progress:
                return Decision("hold", self.percept.q.copy(), goal, d.predicted, d.objective)
            return d
        if not known:
            return Decision("babble", self.random_action())
        o = known[self._target_index % len(known)]
        self._target_index += 1
        target = self.curiosity[o].sample(self.rng, self.estimate[o])
        d = self.plan({o: target}, lookahead=False)
        if np.linalg.norm(self.estimate[o] - target) - d.objective < self.config.min_progress:
            return Decision("babble", self.random_action(), d.targets, d.predicted, d.objective)
        return Decision("curious", d.action, d.targets, d.predicted, d.objective)

    # ------------------------------------------------------------------ acting
    def step(self, action: Any) -> Percept:
        """Execute ``do(a)``, perceive, update the state estimate and record the transition."""
        if self.percept is None:
            raise ValueError("call reset() before step()")
        env, prev, est_prev = self.env, self.percept, dict(self.estimate)
        sim_state = env.get_state()
        truth_prev = env.object_positions()
        _, _, _, _, info = env.step(action)
        ctrl = info["ctrl"]
        self.clock += env.dt
        self.steps += 1
        self.episode_steps += 1
        new = self.perceive()
        self.estimate = self.state_posterior(prev, est_prev, new, info["touch"])
        self.percept = new
        self._visit()
        truth = env.object_positions()
        nan2 = np.full(2, np.nan)
        objs = self.config.objects
        pick = lambda ms: np.array([nan2 if ms[o] is None else ms[o].position for o in objs])  # noqa: E731
        self.history.append(
            episode=self.episode,
            act=ctrl,
            q_prev=prev.q,
            q=new.q,
            hand_prev=prev.hand,
            hand=new.hand,
            touch=[info["touch"][env.objects.index(o)] for o in objs],
            meas_prev=pick(prev.measurements),
            meas=pick(new.measurements),
            std=np.array([nan2 if new.measurements[o] is None else new.measurements[o].std for o in objs]),
            est_prev=np.array([nan2 if est_prev[o] is None else est_prev[o] for o in objs]),
            est=np.array([nan2 if self.estimate[o] is None else self.estimate[o] for o in objs]),
            truth_prev=np.array([truth_prev[o][:2] for o in objs]),
            truth=np.array([truth[o][:2] for o in objs]),
            state=sim_state,
        )
        return new

    def refit(self) -> dict[str, Any]:
        """Refit the world model on the whole history (Eq. 4.33)."""
        c = self.config
        out = fit_world_model(
            self.model,
            self.history,
            epochs=c.epochs,
            batch_size=c.batch_size,
            lr=c.lr,
            min_sigma=c.min_sigma,
            seed=self.seed + len(self.history),
        )
        self.fitted = True
        self._blankets.clear()
        log.info("refit on %d transitions: %s", len(self.history), out["rows"])
        return out

    def run(
        self,
        steps: int,
        mode: str = "curious",
        *,
        refit_every: int | None = None,
        callback: Callable[[Agent, Decision, Percept], None] | None = None,
        progress_bar: bool = False,
    ) -> list[Decision]:
        """Run ``steps`` loop steps in ``mode`` and return their decisions.

        A fitted model is refitted every ``refit_every`` steps (default ``config.refit_every``;
        0 disables). Episodes restart every ``reset_every``.
        """
        check_int("steps", steps, minimum=0)
        every = self.config.refit_every if refit_every is None else refit_every
        decisions = []
        for _ in tqdm(range(steps), desc=f"loop ({mode})", disable=not progress_bar, leave=False):
            limit = self.config.reset_every
            if self.percept is None or (limit is not None and self.episode_steps >= limit):
                self.reset()
            decision = self.decide(mode)
            percept = self.step(decision.action)
            decisions.append(decision)
            if callback is not None:
                callback(self, decision, percept)
            if self.fitted and every and self.steps % every == 0 and mode != "babble":
                self.refit()
        return decisions
