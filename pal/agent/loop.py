"""The agent: the closed perception-action loop over any Gymnasium environment (thesis §4.1, Eq. 4.1-4.4, §6.3).

``Agent(env, spec)`` composes five parts, each in its own module:

1. **perceive** (:mod:`pal.agent.senses`): the observation and ``info`` of the last ``reset`` or
   ``step``, read through the spec; Π on the camera frame when the spec has perceived objects;
2. **estimate** (:mod:`pal.agent.estimate`): the belief over the object positions, through the
   measurement sites for perceived objects (a lost object stays unobserved);
3. **plan** (:mod:`pal.agent.plan`): a pure function of the model, the belief and a target; the
   sampling planner over a horizon, replanned every k steps (MPC, :mod:`pal.agent.replan`); curious
   actions come from :mod:`pal.agent.explore` (the contact gate), :mod:`pal.agent.influence` (gated
   ensemble disagreement) or :mod:`pal.agent.curiosity` (the density of Eq. 4.34-4.38);
4. **act**: ``env.step(a)``, the transition recorded in :class:`pal.agent.history.History`
   (:mod:`pal.agent.record`);
5. **learn** (:mod:`pal.agent.learn`): refits (Eq. 4.33) and revisions when the residual monitor fires.

The world model is built from the spec (:mod:`pal.agent.graph`). The agent calls nothing but
``reset`` and ``step`` on the environment; ground truth that the environment reports in
``info`` is copied into the history for evaluation and never read. Bad specs, spaces that do
not match, actions without bounds and perceived objects that Π does not see are refused when
the agent is made (:meth:`Agent.__init__` resets the environment once to check).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import asdict
from typing import Any

import gymnasium
import numpy as np
import torch
from tqdm import tqdm

from inference.planning import shift_plan
from models import KinematicMechanism, WorldModel
from pal.agent.body_checks import check_joint_sensors, resolve_servo
from pal.agent.config import AgentConfig
from pal.agent.correction import Correction
from pal.agent.curiosity import GridCuriosity
from pal.agent.decision import MODES, Decision, check_mode, from_plan
from pal.agent.dynamics import dynamics_mechanisms
from pal.agent.estimate import Estimator, belief
from pal.agent.explore import contact_search, diagnose, push_counts
from pal.agent.goals import check_reachable, check_targets, current
from pal.agent.graph import FIXED_SIGMA, build_graph, build_model, discover_parents
from pal.agent.history import History
from pal.agent.influence import explore
from pal.agent.kinematics import check_effector, known_mechanisms, point_mechanisms
from pal.agent.learn import Learner, site_data
from pal.agent.plan import Plan, PlanRequest, one_step, plan_batch
from pal.agent.record import transition
from pal.agent.replan import Replanning
from pal.agent.senses import Percept, Senses
from pal.agent.spec import EnvSpec, check_env
from pal.checks import check_int

__all__ = ["MODES", "Agent", "Decision"]

log = logging.getLogger(__name__)


class Agent:
    """The perception-action loop (module docstring).

    Args:
        env: any ``gymnasium.Env`` with 1-D Box observation and action spaces described by ``spec``.
        spec: what the observation entries (or perceived objects) are.
        config: the parts' settings.
        seed: master seed (actions, targets, inference, episode resets, the model's weights and fits).
        model: a fitted world model over the spec's graph to start from (default: a fresh one,
            fitted by :meth:`refit`).
        goal: optional user goal, object (or the effector's name) -> target position, m
            (``"goal"`` mode; default the goals the spec observes).
        mode: optional default mode of :meth:`run` (one of ``MODES``); ``"goal"`` is checked here,
            so a goal mode with nothing to reach fails at construction, not at the first step.

    Raises:
        ValueError: the environment does not match the spec (:func:`pal.agent.spec.check_env`),
            ``config.servo`` contradicts an actuator of the MJCF, sensed angles or velocities
            that are not MuJoCo's (:mod:`pal.agent.body_checks`), a transform whose first
            observation does not fit (cos^2 + sin^2 != 1), objects of different dims, an info entry the spec reads is missing, or a perceived
            object that Π does not see in the first frame, an unknown ``mode``, or ``mode="goal"``
            with no goal given and none observed (:func:`pal.agent.goals.check_reachable`).
    """

    def __init__(
        self,
        env: gymnasium.Env,
        spec: EnvSpec,
        config: AgentConfig | None = None,
        *,
        seed: int = 0,
        model: WorldModel | None = None,
        goal: Mapping[str, Any] | None = None,
        mode: str | None = None,
    ) -> None:
        if not isinstance(spec, EnvSpec):
            raise ValueError(f"spec must be an EnvSpec, got {type(spec).__name__}")
        self.mode = None if mode is None else check_mode(mode)
        self.env, self.spec, self.config = env, spec, config or AgentConfig()
        self.seed = check_int("seed", seed, minimum=0)
        self.low, self.high = check_env(spec, env)
        self.servo = resolve_servo(env, self.config.servo)
        dims = {o.dim for o in spec.objects}
        if len(dims) > 1:
            raise ValueError(f"objects have different dims {sorted(dims)}; the history holds one dim for all")
        cfg = self.config
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 2]))
        displacement = cfg.model.displacement
        bounds = (self.low, self.high)
        self.graph = (
            build_graph(spec, bounds, displacement=displacement, frame=cfg.model.object_frame)
            if model is None
            else model.graph
        )
        self.model = model if model is not None else self._new_model(self.graph)
        self.fitted = model is not None
        self.history = History(
            spec.joints,
            spec.object_names,
            provenance={"seed": self.seed, "config": asdict(cfg)},
            actions=len(spec.actions),
            effector_dim=0 if spec.effector is None else spec.effector.dim,
            object_dim=dims.pop() if dims else 2,
            velocities=spec.velocities is not None,
            momentum=spec.object_momentum,
        )
        self.senses = Senses(spec, cfg.perception, cfg.top_surface)
        self.estimator = Estimator(spec, cfg.estimate, cfg.model.displacement)
        self.learner = Learner(spec, cfg.model, cfg.learn)
        (x0, y0), (x1, y1) = cfg.curiosity.region
        c = cfg.curiosity
        self.curiosity = {o: GridCuriosity((x0, y0), (x1, y1), c.bins, c.locality) for o in spec.object_names}
        self.goal = {} if goal is None else self._check_targets(goal)
        if mode == "goal":
            check_reachable(spec, self.goal)
        self.correction = Correction(self.config.correction)
        self.episode, self.steps, self.episode_steps, self.clock = -1, 0, 0, 0.0
        self.percept: Percept | None = None
        self.estimate: dict[str, np.ndarray | None] = {}
        self.previous: dict[str, np.ndarray | None] = {}
        self.done = False
        self._sequence: np.ndarray | None = None
        self._plan: Plan | None = None
        self._replan = Replanning(self.config.plan.replan_every)
        self._target_index = 0
        self._dt = float(getattr(env.unwrapped, "dt", 1.0))
        self._probe()

    def _new_model(self, graph: Any) -> WorldModel:
        model = self.config.model
        known = known_mechanisms(self.env, self.spec, FIXED_SIGMA) if model.kinematics == "mjcf" else {}
        if model.dynamics == "mjcf":
            known.update(dynamics_mechanisms(self.env, self.spec, FIXED_SIGMA, self.servo))
        if model.object_frame == "push" and self.spec.effector_points:
            known.update(point_mechanisms(self.env, self.spec, FIXED_SIGMA))
        return build_model(self.spec, graph, self.config.model, mechanisms=known, seed=self.seed)

    def _probe(self) -> None:
        """Reset once and read the percept: missing info entries and unseen objects fail here."""
        seed = int(np.random.SeedSequence([self.seed, 4]).generate_state(1)[0])
        obs, info = self.env.reset(seed=seed)
        self.senses.check_first(obs)
        percept = self.senses.read(obs, info, 0.0)
        check_joint_sensors(self.spec, self.env, percept.q, percept.v)
        dee = self.model.mechanism("dee") if "dee" in self.model.graph else None
        if isinstance(dee, KinematicMechanism) and percept.effector is not None:
            check_effector(dee, percept.q, percept.effector, str(self.spec.effector_body))
        unseen = [o for o in self.spec.perceived if percept.measurements[o] is None]
        if unseen:
            n = 0 if percept.perception is None else len(percept.perception.observations())
            raise ValueError(
                f"objects {unseen} named by the spec are not seen: perception finds {n} object(s) in the first "
                f"frame and the spec names {len(self.spec.perceived)}; check the camera and the spec's objects"
            )
        self.senses.reset()

    def _check_targets(self, targets: Mapping[str, Any]) -> dict[str, np.ndarray]:
        return check_targets(self.spec, targets)

    # ------------------------------------------------------------------ perceive, estimate
    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Percept:
        """Start an episode: reset the environment and perception; the estimate is the first measurement."""
        self.episode += 1
        self.episode_steps = 0
        if seed is None:
            seed = int(np.random.SeedSequence([self.seed, 3, self.episode]).generate_state(1)[0])
        obs, info = self.env.reset(seed=seed, options=options)
        self.senses.reset()
        self.done = False
        self._sequence = None
        self._replan.reset()
        self.percept = self.senses.read(obs, info, self.clock)
        self.estimate = self.estimator.initial(self.percept)
        self.previous = {}
        self.correction.reset()
        self._visit()
        return self.percept

    def _visit(self) -> None:
        for o, e in self.estimate.items():
            if e is not None and e.shape == (2,):
                self.curiosity[o].partial_fit(e)

    def belief(self) -> dict[str, np.ndarray]:
        """The planner's state: the graph's lag-1 roots now (:func:`pal.agent.estimate.belief`)."""
        if self.percept is None:
            raise ValueError("call reset() before planning")
        return belief(self.spec, self.percept, self.estimate, self.previous)

    # ------------------------------------------------------------------ plan
    def _seed(self) -> int:
        return int(self.rng.integers(2**31))

    @property
    def effector_name(self) -> str | None:
        """The effector's name in targets, or None for a spec without one."""
        return self.spec.effector_name if self.spec.effector is not None else None

    def plan(self, targets: Mapping[str, Any], mode: str = "goal") -> Plan:
        """Plan towards ``targets`` (object or effector -> (d,) m) from the belief, warm-started (:func:`pal.agent.plan.plan`).

        With ``config.correction.window`` the rollouts carry the filtered residuals abducted from
        the last executed transitions (:mod:`pal.agent.correction`).
        """
        request = self.plan_request(targets, mode)
        return self.adopt(plan_batch(self.model, [request], self.config.plan, effector=self.effector_name)[0])

    def plan_request(self, targets: Mapping[str, Any], mode: str = "goal") -> PlanRequest:
        """What :meth:`plan` plans for: the belief, the targets, a seed, the warm start, the residuals."""
        if self.percept is None:
            raise ValueError("call reset() before plan()")
        targets = self._check_targets(targets)
        missing = [o for o in targets if current(self.spec, self.percept, self.estimate, o) is None]
        if missing:
            raise ValueError(f"no state estimate for {missing}; they have not been perceived in this episode")
        cfg = self.config.plan
        init = None
        if cfg.warm_start and self._sequence is not None:  # shifted by the actions executed from it
            init = shift_plan(torch.as_tensor(self._sequence), steps=self._replan.shift()).numpy()
        elif self.servo and len(self.low) == len(self.percept.q):  # start the search from holding still
            init = np.tile(np.clip(self.percept.q, self.low, self.high), (cfg.action.horizon, 1))
        noise = self.correction.noise(self.model)
        return PlanRequest(self.belief(), targets, self._seed(), init, mode, noise)

    def adopt(self, p: Plan) -> Plan:
        """Take ``p`` as the current plan: its rest warm-starts the next search, or is executed (``replan_every``)."""
        self._sequence, self._plan = p.sequence, p
        self._replan.planned()
        return p

    def random_action(self) -> np.ndarray:
        """A babbling action (A,): uniform in the bounds, or for servos a move around the joint angles."""
        b = self.config.babble
        if (
            self.servo
            and self.percept is not None
            and self.rng.random() < b.local
            and len(self.low) == len(self.percept.q)
        ):
            r = b.reach
            return np.clip(self.percept.q + self.rng.uniform(-r, r, size=len(self.low)), self.low, self.high)
        return self.rng.uniform(self.low, self.high)

    def _hold(self) -> np.ndarray:
        return self.percept.q.copy() if self.servo else np.zeros(len(self.low))

    def decide(self, mode: str) -> Decision:
        """Choose a(t): ``"babble"`` (random), ``"curious"`` or ``"goal"`` (the goal, or the observed goals)."""
        check_mode(mode)
        if self.percept is None:
            raise ValueError("call reset() before decide()")
        if mode == "goal":
            pending = self.goal_pending()
            return (
                pending
                if isinstance(pending, Decision)
                else self.goal_decided(self.plan(pending[0]), pending[1])
            )
        if mode == "babble" or not self.fitted:
            return Decision("babble", self.random_action())
        known = [o for o in self.spec.object_names if self.estimate.get(o) is not None]
        if not known:
            return Decision("babble", self.random_action())
        c = self.config.curiosity
        if c.method == "contact":
            return self._contact(tuple(known))
        if c.method == "disagreement":
            generator = torch.Generator().manual_seed(self._seed())
            seq, score, _ = explore(
                self.model, self.belief(), tuple(known), c, self.config.plan.action.scale, generator
            )
            if score < c.min_score:
                return Decision("babble", self.random_action(), score=score)
            mean, sd, _ = one_step(self.model, self.belief(), seq[0], tuple(known))
            return Decision("curious", seq[0], step_mean=mean, step_sd=sd, score=score)
        o = known[self._target_index % len(known)]
        self._target_index += 1
        target = self.curiosity[o].sample(self.rng, self.estimate[o])
        p = self.plan({o: target}, mode="curious")
        self._sequence = None
        if np.linalg.norm(self.estimate[o] - target) - p.objective < self.config.plan.min_progress:
            return Decision("babble", self.random_action(), p.targets, p.predicted, p.objective)
        return from_plan(p)

    def _contact(self, known: tuple[str, ...]) -> Decision:
        """A curious step of the contact method (:mod:`pal.agent.explore`); babbles below ``min_score``."""
        c = self.config.curiosity
        (x0, y0), (x1, y1) = c.region
        est_prev, est = self.history.array("est_prev"), self.history.array("est")
        grids = {}
        for o in known:
            k = self.history.objects.index(o)
            grid = GridCuriosity((x0, y0), (x1, y1), c.bins, c.locality)
            grids[o] = push_counts(est_prev[:, k], est[:, k], grid, c.moved)
        generator = torch.Generator().manual_seed(self._seed())
        scale = self.config.plan.action.scale
        found = contact_search(self.model, self.belief(), self._hold(), known, grids, c, scale, generator)
        mode, action = "curious", found.sequence[0]
        if found.information < c.min_score:
            mode, action = "babble", self.random_action()
        diag = diagnose(self.model, self.belief(), action, known, c, scale, generator)
        return Decision(mode, action, score=found.information, diagnostics=diag)

    def goal_pending(self) -> Decision | tuple[dict[str, np.ndarray], float]:
        """Goal mode up to its plan: a decision that needs no new plan, or the goal to plan for and its distance now (m).

        A decision: babble before the first fit, hold while no goal object is known (or, for a
        servo, within ``goal_tolerance``), the current plan's next action (``replan_every``).
        ``decide("goal")`` is ``goal_decided(plan(goal), now)`` when a goal is returned.
        """
        if self.percept is None:
            raise ValueError("call reset() before decide()")
        check_reachable(self.spec, self.goal)
        if not self.fitted:
            return Decision("babble", self.random_action())
        known = [o for o in self.spec.object_names if self.estimate.get(o) is not None]
        goal = self.goal or dict(self.percept.goals)
        now_at = {o: current(self.spec, self.percept, self.estimate, o) for o in goal}
        goal = {
            o: t
            for o, t in goal.items()
            if o in known or (o not in self.spec.object_names and now_at[o] is not None)
        }
        if not goal:
            log.debug("goal mode: no goal's object is known yet; holding")
            return Decision("hold", self._hold())
        now = sum(float(np.linalg.norm(now_at[o] - t)) for o, t in goal.items())
        if self.servo and now <= self.config.plan.goal_tolerance:
            return Decision("hold", self._hold(), goal)
        if (held := self._held(goal)) is not None:  # a plan's next action (PlanConfig.replan_every)
            return held
        return goal, now

    def goal_decided(self, p: Plan, now: float) -> Decision:
        """The goal-mode decision from the plan made for :meth:`goal_pending`'s goal (a servo holds when it gains too little)."""
        if self.servo and p.objective > now - self.config.plan.min_progress:
            self._sequence = None
            return Decision("hold", self._hold(), p.targets, p.predicted, p.objective)
        return from_plan(p)

    def _held(self, goal: Mapping[str, np.ndarray]) -> Decision | None:
        """The current plan's next action while no new plan is due (``PlanConfig.replan_every``)."""
        p = self._plan
        if self._sequence is None or p is None or self._replan.due(len(self._sequence)):
            return None
        if set(p.targets) != set(goal) or any(not np.array_equal(p.targets[o], goal[o]) for o in goal):
            return None  # the goal moved: plan for the new one
        action = self._sequence[self._replan.take()].copy()
        mean, sd, _ = one_step(self.model, self.belief(), action, tuple(p.targets), self.effector_name)
        return Decision(p.mode, action, p.targets, p.predicted, p.objective, mean, sd, sequence=p.sequence)

    # ------------------------------------------------------------------ act, learn
    def step(self, action: Any) -> Percept:
        """Execute ``a``, perceive, update the estimate and record the transition."""
        if self.percept is None:
            raise ValueError("call reset() before step()")
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), self.low, self.high)
        prev, est_prev, before = self.percept, dict(self.estimate), dict(self.previous)
        obs, _, terminated, truncated, info = self.env.step(a.astype(np.float32))
        self.clock += self._dt
        self.steps += 1
        self.episode_steps += 1
        self.done = bool(terminated or truncated)
        new = self.senses.read(obs, info, self.clock, reference=self.estimate)
        vel_prev = {
            o: (None if est_prev[o] is None or before.get(o) is None else est_prev[o] - before[o])
            for o in est_prev
        }
        self.estimate = self.estimator.update(
            self.model if self.fitted else None, prev, est_prev, vel_prev, new, self._seed()
        )
        self.previous = est_prev
        self.percept = new
        if self.fitted:
            roots = belief(self.spec, prev, est_prev, before)
            self.correction.observe(self.model, roots, a, new, self.spec.periodic)
        self._visit()
        self.history.append(
            **transition(
                self.history, self.episode, self.episode_steps == 1, a, prev, new, est_prev, self.estimate
            )
        )
        return new

    def refit(self) -> dict[str, Any]:
        """Refit the world model on the whole history (Eq. 4.33).

        At the first fit with ``model.structure="discover"`` the learned sites' parents are learnt
        first (:func:`pal.agent.graph.discover_parents`).
        """
        if not self.fitted and self.config.model.structure == "discover":
            data = site_data(self.history, self.spec, config=self.config.model)
            parents = discover_parents(
                self.spec,
                self.graph,
                {k: v for k, v in data.items() if not k.startswith("meas.")},
                seed=self.seed,
            )
            self.graph = build_graph(
                self.spec, (self.low, self.high), parents, displacement=self.config.model.displacement
            )
            self.model = self._new_model(self.graph)
        self.model, out = self.learner.refit(self.model, self.history, self.seed + len(self.history))
        self.graph = self.model.graph
        self.fitted = True
        self.estimator.forget()
        self.correction.reset()
        log.info("refit on %d transitions: %s", len(self.history), out["rows"])
        return out

    def run(
        self,
        steps: int,
        mode: str | None = None,
        *,
        refit_every: int | None = None,
        callback: Callable[[Agent, Decision, Percept], None] | None = None,
        progress_bar: bool = False,
    ) -> list[Decision]:
        """Run ``steps`` loop steps in ``mode`` (default the constructor's ``mode``, else ``"curious"``) and return their decisions.

        A fitted model is refitted every ``refit_every`` steps (default ``config.curiosity.refit_every``
        in the curious mode, else ``config.learn.refit_every``; 0 disables). Episodes restart every ``reset_every`` steps and when the environment ends one.
        """
        check_int("steps", steps, minimum=0)
        mode = (self.mode or "curious") if mode is None else mode
        check_mode(mode)
        if mode == "goal":
            check_reachable(self.spec, self.goal)
        default = self.config.curiosity.refit_every if mode == "curious" else self.config.learn.refit_every
        every = default if refit_every is None else refit_every
        decisions = []
        for _ in tqdm(range(steps), desc=f"loop ({mode})", disable=not progress_bar, leave=False):
            limit = self.config.reset_every
            if self.percept is None or self.done or (limit is not None and self.episode_steps >= limit):
                self.reset()
            decision = self.decide(mode)
            percept = self.step(decision.action)
            decisions.append(decision)
            if callback is not None:
                callback(self, decision, percept)
            if self.fitted and every and self.steps % every == 0 and mode != "babble":
                self.refit()
        return decisions
