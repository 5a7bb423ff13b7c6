"""The agent's settings, one frozen sub-config per part: model and fit, estimate, plan, curiosity, learning.

Each part nests the option object of :mod:`inference` that it passes on unchanged
(``model.schedule``: :class:`inference.FitSchedule`; ``estimate.svi``: :class:`inference.SVIOptions`;
``plan.action``: :class:`inference.ActionOptions` with its :class:`inference.SamplingConfig`;
``curiosity.sampling``) and declares beside it only the agent's own settings.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from inference import ActionOptions, CalibrationOptions, FitSchedule, SamplingConfig, SVIOptions
from inference.action_objective import check_risk
from models.heteroscedastic import check_log_scale_bounds
from pal.agent.rollout_fit import RolloutFit
from pal.checks import check_choice, check_float, check_int
from pal.perception import PipelineConfig

__all__ = [
    "ARM_LOG_SCALE_BOUNDS",
    "CURIOSITY_SAMPLING",
    "DISPLACEMENTS",
    "ESTIMATE_SVI",
    "LOG_SCALE_BOUNDS",
    "MODEL_SCHEDULE",
    "PLAN_ACTION",
    "PLAN_SAMPLING",
    "PREFERENCES",
    "AgentConfig",
    "BabbleConfig",
    "CorrectionConfig",
    "CuriosityConfig",
    "EstimateConfig",
    "LearnConfig",
    "ModelConfig",
    "PlanConfig",
]

log = logging.getLogger(__name__)


def _check_type(name: str, value: Any, cls: type) -> Any:
    """``value`` if it is a ``cls``, else ``ValueError`` naming the field and the class."""
    if not isinstance(value, cls):
        raise ValueError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")
    return value


def _widths(name: str, value: tuple[int, ...]) -> tuple[int, ...]:
    return tuple(check_int(name, h) for h in value)


#: The agent's fit: 150 epochs of 256-row batches, lr 0.005, 10 % held out, patience 25, beta-NLL with beta 0.5;
#: a gated site's on branch is calibrated on the out-of-fold residuals of 5 refits over all its contact rows.
MODEL_SCHEDULE = FitSchedule(
    epochs=150,
    batch_size=256,
    lr=0.005,
    validation=0.1,
    patience=25,
    beta=0.5,
    calibration=CalibrationOptions(folds=5),
)


#: The forms of an object's displacement site (:attr:`ModelConfig.displacement`).
DISPLACEMENTS = ("smooth", "gated")

#: Fixed (lo, hi) of the log-scale s = log(sigma / training sd) of the object sites (:attr:`ModelConfig.log_scale_bounds`).
LOG_SCALE_BOUNDS = (-4.0, 1.0)
#: The same for the arm's sites dq, v, dee (:attr:`ModelConfig.arm_log_scale_bounds`).
ARM_LOG_SCALE_BOUNDS = (-6.0, 1.0)


@dataclass(frozen=True)
class ModelConfig:
    """The world model (:mod:`pal.agent.graph`) and its fit (Eq. 4.33).

    Attributes:
        kind: ``"hetero"`` (``X ~ Normal(f(pa), sigma(pa))``, beta-NLL) or ``"mlp"`` (MSE, one sigma).
        members: ensemble size K per learned site (1: none).
        hidden: MLP widths of the object sites. arm_hidden: of the arm sites (default ``hidden``).
        position_sigma: residual sd of ``pos = pos_prev + dpos``, m.
        structure: ``"preset"`` (the spec's graph) or ``"discover"`` (the learned sites' parents
            are learnt with :func:`inference.discover` at the first fit).
        schedule: the :func:`inference.fit` schedule, passed as it is (its ``validation`` share
            sets sigma and early stopping; ``patience`` needs ``validation > 0``; ``beta`` is the
            beta-NLL's, 0.5 as in :func:`inference.fit`'s default: the gated form trains its on
            branch on the contact rows only, so rare pushes are not outweighed by resting rows and
            need no MSE gradient, beta 1; the smooth form was used with beta 1; ``calibration``: the
            contact rows held out for validation are ~10 % of ~12 %, so the on branches are
            calibrated on 5-fold out-of-fold residuals, for ~3x the fit time).
        min_sigma: floor on fitted homoscedastic sigmas, m (keeps state inference well conditioned).
        displacement: ``"gated"`` (the default: ``contact.o`` a Bernoulli switch of every object
            and ``dpos.o`` a :class:`models.GatedMechanism`: exactly 0 with sd ``position_sigma``
            without contact, the smooth form's mechanism with contact) or ``"smooth"`` (``dpos.o``
            one smooth mechanism of its parents); see :mod:`pal.agent.graph`.
        log_scale_bounds: fixed soft bounds ``(lo, hi)`` of the heteroscedastic object sites'
            log-scale ``s = log(sigma / sd)``, ``sd`` the site's training sd
            (:mod:`models.heteroscedastic`; not learned, as mbrl-lib keeps its bounds fixed).
            (-4, 1): sigma between 1.8 % and 2.7 training sd; for the pushes of the pushing world
            (training sd 4-5 cm on the contact rows) the lower end is about the 1 mm measurement
            floor. Fitted gated on branches stay inside: s from -2.4 to 0.9 (pushing world, 1000
            babbling steps, these defaults, seed 0).
        arm_log_scale_bounds: the same for the arm's sites ``dq``, ``v``, ``dee``, (-6, 1): sigma
            between 0.25 % and 2.7 training sd; the joints are sensed without noise and their
            fitted log-scales reach s = -5.6 (``dee``) on the same run, so a floor at -4 would
            widen them.
        kinematics: ``"learned"`` (``q_prev, dq -> dee`` an MLP like the other arm sites) or
            ``"mjcf"``: the effector's forward kinematics read from the MuJoCo env's own model
            up to ``EnvSpec.effector_body``, a fixed :class:`models.KinematicMechanism`
            (:mod:`pal.agent.kinematics`).
        dynamics: ``"learned"`` (``dq`` and ``v`` MLPs) or ``"mjcf"``: the joints' motion under
            the torques stepped by MuJoCo through the env's own model, with the body's contacts
            with static geometry and without those with objects (:mod:`pal.agent.dynamics`);
            needs ``kinematics="mjcf"``, so that only the objects are learned.
        object_frame: ``"world"`` (the default) or ``"push"``: the objects' contact and
            displacement read their parents turned towards the effector, with the body's
            ``EnvSpec.effector_points`` among them (:mod:`pal.agent.graph_frame`); perceived
            objects are filtered through it (:mod:`pal.agent.estimate`).
        rollout: after the one-step fit, refine the objects' ``contact.o`` and ``dpos.o`` on
            windows of ``rollout.window`` recorded steps, chained as the planner chains them
            (:mod:`pal.agent.rollout_fit`; window 0, the default: off).
    """

    kind: str = "hetero"
    members: int = 5
    hidden: tuple[int, ...] = (64, 64)
    arm_hidden: tuple[int, ...] | None = None
    position_sigma: float = 1e-3
    structure: str = "preset"
    schedule: FitSchedule = MODEL_SCHEDULE
    min_sigma: float = 0.003
    displacement: str = "gated"
    log_scale_bounds: tuple[float, float] = LOG_SCALE_BOUNDS
    arm_log_scale_bounds: tuple[float, float] = ARM_LOG_SCALE_BOUNDS
    kinematics: str = "learned"
    dynamics: str = "learned"
    object_frame: str = "world"
    rollout: RolloutFit = RolloutFit()

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, ("hetero", "mlp"))
        check_choice("kinematics", self.kinematics, ("learned", "mjcf"))
        check_choice("dynamics", self.dynamics, ("learned", "mjcf"))
        if self.dynamics == "mjcf" and self.kinematics != "mjcf":
            raise ValueError(
                f"dynamics='mjcf' needs kinematics='mjcf' (the body known from its MJCF), got kinematics={self.kinematics!r}"
            )
        check_choice("structure", self.structure, ("preset", "discover"))
        check_choice("object_frame", self.object_frame, ("world", "push"))
        if self.structure == "discover" and self.object_frame == "push":
            raise ValueError(
                "structure='discover' searches the world frame's parents; use object_frame='world' with it"
            )
        check_choice("displacement", self.displacement, DISPLACEMENTS)
        check_int("members", self.members)
        object.__setattr__(self, "hidden", _widths("hidden", self.hidden))
        if self.arm_hidden is not None:
            object.__setattr__(self, "arm_hidden", _widths("arm_hidden", self.arm_hidden))
        _check_type("schedule", self.schedule, FitSchedule)
        _check_type("rollout", self.rollout, RolloutFit)
        for name in ("log_scale_bounds", "arm_log_scale_bounds"):
            object.__setattr__(self, name, check_log_scale_bounds(getattr(self, name), name))
        for name in ("position_sigma", "min_sigma"):
            check_float(name, getattr(self, name), 0.0, open_low=True)
        if self.schedule.patience is not None and self.schedule.validation == 0:
            raise ValueError(
                "schedule.patience needs validation rows; set schedule.validation > 0 or schedule.patience=None"
            )


#: The agent's state inference: lr 0.035 decaying to 0.002, 16 particles, guide scale 5 mm.
ESTIMATE_SVI = SVIOptions(lr=0.035, lr_final=0.002, num_particles=16, init_scale=0.005)


@dataclass(frozen=True)
class EstimateConfig:
    """State inference through the measurement sites (Eq. 4.41-4.42), perceived objects only.

    Attributes:
        num_steps: SVI steps.
        guide: ``"mvn"`` (full covariance: pos.o and dpos.o are tightly coupled) or ``"normal"``.
        svi: the optimiser and guide settings of :func:`inference.infer_state`, passed as they are:
            the learning rate decays from ``svi.lr`` to ``svi.lr_final``; the guide starts at 0,
            so ``svi.lr`` must let it travel across the table (~0.5 m); ``svi.init_scale`` (m) is
            the guide's initial scale.
    """

    num_steps: int = 40
    guide: str = "mvn"
    svi: SVIOptions = ESTIMATE_SVI

    def __post_init__(self) -> None:
        check_int("num_steps", self.num_steps)
        check_choice("guide", self.guide, ("mvn", "normal"))
        _check_type("svi", self.svi, SVIOptions)
        lr, lr_final = self.svi.lr, self.svi.lr_final
        ratio = (lr_final / lr) ** (1.0 / self.num_steps)
        travel = lr * (1 - ratio**self.num_steps) / max(1 - ratio, 1e-12)
        if travel < 0.45:
            log.warning(
                "state inference can move its guide only %.2f m from 0 in %d steps (lr %g -> %g); positions "
                "on the table reach 0.45 m, so estimates may be cut short: raise num_steps or svi.lr",
                travel,
                self.num_steps,
                lr,
                lr_final,
            )


#: The agent's search: iCEM (coloured noise beta 2, 30 % of the elites kept, population decay 1.25),
#: then projected Adam on the best elite for 20 steps (CEM-GD).
PLAN_SAMPLING = SamplingConfig(
    population=64,
    elites=8,
    iterations=3,
    alpha=0.1,
    noise_beta=2.0,
    keep_elites=0.3,
    population_decay=1.25,
    init_std=0.5,
    refine_steps=20,
)

#: The agent's action inference: horizon 2, preference scale 2 cm, the search above, Adam lr 0.05,
#: and the expected cost over the ensemble members' particles (risk "mean"), not the cost of the
#: members' mean prediction: a planner on the mean model picks the actions where the mean is
#: optimistic (the optimiser's curse).
PLAN_ACTION = ActionOptions(scale=0.02, lr=0.05, horizon=2, sampling=PLAN_SAMPLING, risk="mean")

#: The forms of the preference's cost c(x) (:attr:`PlanConfig.preference`).
PREFERENCES = ("gaussian", "distance", "l1")


@dataclass(frozen=True)
class PlanConfig:
    """Model-predictive control: the sampling planner over a horizon, replanned every step (Alg. 4.2).

    Attributes:
        action: the options of :func:`inference.infer_action`, passed as they are except for
            the preference and the start, which the agent makes from its targets and its
            previous plan (leave ``log_preference`` None and ``init`` ``"midpoint"``):
            ``horizon`` (planning steps H), ``scale`` (preference scale, m), ``lr`` (the
            refinement's Adam), ``target_at`` (``"final"``: the targets at the horizon's end, or
            ``"every"`` step), ``risk`` (``"mean"``, the default: expected cost over the ensemble
            members' particles; ``("quantile", q)``: their q-quantile, q > 0.5 risk averse;
            None: the members' mean prediction; ``("disagreement", w)``: cost of the mean plus w x
            the members' variance on the targets, w > 0 risk averse, < 0 seeking) and ``sampling``
            (the iCEM / CEM stage; ``sampling.refine_steps`` Adam steps on the best elite after
            it, 0: none).
        preference: the cost c(x) of :mod:`pal.agent.plan`: ``"gaussian"`` (``0.5 |x|^2 /
            scale^2``), ``"distance"`` (``|x|_2 / scale``) or ``"l1"`` (``|x|_1 / scale``, PETS's
            Pusher cost).
        goal_weight: weight of each targeted object's cost to its target.
        effector_weight: weight of the effector's distance to each targeted object in the
            preference (0: none; it brings the effector to the object).
        behind_weight: weight of the optional shaping term (0, the default: off) that pulls the
            effector (x-y) to the point ``behind_offset`` m behind the object on the far side
            from its target, where a push towards the target starts (:func:`pal.agent.plan.behind`).
        behind_offset: that point's distance from the object's centre, m (> 0).
        action_weight: weight of ``|a|^2`` (action units squared) in the preference.
        move_weight: weight of ``|a - q_prev|^2`` (rad^2): for position servos, the size of the move
            (small moves have outcomes the model knows better).
        warm_start: start the search from the previous plan shifted by the steps executed from it.
        replan_every: plan anew every k steps and execute the plan's next actions in between
            (1: every step, PETS's MPC; :mod:`pal.agent.replan`).
        min_progress: a goal step predicted to gain less than this (m) holds still.
        goal_tolerance: a goal closer than this (m, by the estimate) is held.
    """

    action: ActionOptions = PLAN_ACTION
    preference: str = "gaussian"
    goal_weight: float = 1.0
    effector_weight: float = 0.0
    behind_weight: float = 0.0
    behind_offset: float = 0.05
    action_weight: float = 0.0
    move_weight: float = 0.0
    warm_start: bool = True
    replan_every: int = 1
    min_progress: float = 0.002
    goal_tolerance: float = 0.005

    def __post_init__(self) -> None:
        a = _check_type("action", self.action, ActionOptions)
        check_int("action.horizon", a.horizon)
        check_int("replan_every", self.replan_every)
        for name in ("lr", "scale"):
            check_float(f"action.{name}", getattr(a, name), 0.0, open_low=True)
        check_choice("action.target_at", a.target_at, ("final", "every"))
        check_risk(a.risk)
        if a.log_preference is not None or not (isinstance(a.init, str) and a.init == "midpoint"):
            raise ValueError(
                "plan.action.log_preference and plan.action.init are made by the agent from its targets and "
                "its previous plan; leave them None and 'midpoint'"
            )
        if not isinstance(a.sampling, SamplingConfig):
            raise ValueError(
                f"plan.action.sampling is {a.sampling!r}; the agent plans with the sampling stage: give a "
                "SamplingConfig(population=..., elites=..., refine_steps=...)"
            )
        if a.sampling.refine_steps is None:
            raise ValueError(
                "plan.action.sampling.refine_steps is None; give the Adam steps after it (0: none)"
            )
        check_choice("preference", self.preference, PREFERENCES)
        for name in (
            "goal_weight",
            "effector_weight",
            "behind_weight",
            "action_weight",
            "move_weight",
            "min_progress",
            "goal_tolerance",
        ):
            check_float(name, getattr(self, name), 0.0)
        check_float("behind_offset", self.behind_offset, 0.0, open_low=True)


#: The contact search: 64 candidates, 8 elites, 3 iterations of iCEM with pink-to-brown noise (beta 2: smooth
#: reaching sequences), started at "hold" with a spread of 0.15 of each action's range.
CURIOSITY_SAMPLING = SamplingConfig(population=64, elites=8, iterations=3, noise_beta=2.0, init_std=0.15)


@dataclass(frozen=True)
class CuriosityConfig:
    """How a curious agent picks what to do (:mod:`pal.agent.explore`, :mod:`pal.agent.influence`, :mod:`pal.agent.curiosity`).

    Attributes:
        method: ``"contact"`` (the default: the contact gate ``P(contact | a) x`` on-branch
            disagreement, times the novelty of the predicted object position, :mod:`pal.agent.explore`),
            ``"disagreement"`` (ensemble disagreement gated by the causal action-influence score,
            :mod:`pal.agent.influence`) or ``"density"`` (targets from Eq. 4.34-4.38 on a grid).
        horizon: steps of the searched action sequences (contact, disagreement); 5 lets the hand
            travel to an object before it touches it.
        sampling: the search over them (:func:`inference.planning.cross_entropy_search`); for the
            contact method it starts at "hold" with ``sampling.init_std`` (a share of each action's
            range, 0.15) as its spread.
        influence_samples: actions M per state in the influence estimate (CAI; a diagnostic of the
            contact method).
        influence_scale: nats at which the disagreement method's gate opens fully (gate = min(1, I / scale)).
        min_score: below this score the agent babbles. Contact method: the best sequence's summed
            novelty-weighted gates (disagreement in ``plan.action.scale`` units squared, weighted by
            the contact probability); 0.05 is about a 50 % touch of an object whose on branches
            disagree by 0.3 scale units (6 mm at 2 cm) in a cell pushed into once.
            Disagreement method: its gated disagreement.
        moved: an object whose estimate moved more than this over a step (m) was pushed; its
            position counts in the novelty grid (contact method).
        limit_weight: weight of the joint-limit penalty (contact method; 0: none).
        limit_margin: share of each action's range next to a bound over which the penalty rises
            from 0 to 1.
        refit_every: the curious mode refits the model every this many steps (>= 1).
        region, bins, locality: the grid over the table (m, cells) of the density method and of the
            contact method's novelty counts, and the density method's locality gain (the alpha of Eq. 4.36).
    """

    method: str = "contact"
    horizon: int = 5
    sampling: SamplingConfig = CURIOSITY_SAMPLING
    influence_samples: int = 8
    influence_scale: float = 0.5
    min_score: float = 0.05
    moved: float = 0.005
    limit_weight: float = 1.0
    limit_margin: float = 0.05
    refit_every: int = 25
    region: tuple[tuple[float, float], tuple[float, float]] = ((-0.3, 0.0), (0.3, 0.45))
    bins: tuple[int, int] = (8, 8)
    locality: float = 0.5

    def __post_init__(self) -> None:
        check_choice("method", self.method, ("contact", "disagreement", "density"))
        for name in ("horizon", "influence_samples"):
            check_int(name, getattr(self, name))
        if (
            isinstance(self.refit_every, bool)
            or not isinstance(self.refit_every, int)
            or self.refit_every < 1
        ):
            raise ValueError(
                f"curiosity.refit_every is {self.refit_every!r}; the curious agent refits its model every N steps "
                "of its budget: give an int N >= 1"
            )
        _check_type("sampling", self.sampling, SamplingConfig)
        check_float("influence_scale", self.influence_scale, 0.0, open_low=True)
        for name in ("min_score", "moved", "limit_weight"):
            check_float(name, getattr(self, name), 0.0)
        check_float("limit_margin", self.limit_margin, 0.0, 0.5, open_low=True)
        check_float("locality", self.locality, 0.0)
        object.__setattr__(self, "bins", tuple(check_int("bins", b, minimum=2) for b in self.bins))


@dataclass(frozen=True)
class LearnConfig:
    """Online learning: refits, and the structural revision when the residual monitor fires (Eq. 4.50).

    Attributes:
        refit_every: refit period, steps (in the goal mode; the curious mode's is ``curiosity.refit_every``).
        monitor: watch the windowed residuals and revise flagged mechanisms.
        window, threshold, patience: :class:`inference.ResidualMonitor` settings.
        revisions: the kinds :func:`inference.revise` tries.
    """

    refit_every: int = 100
    monitor: bool = True
    window: int = 500
    threshold: float = 2.0
    patience: int = 2
    revisions: tuple[str, ...] = ("add_parent", "split")

    def __post_init__(self) -> None:
        for name in ("refit_every", "window", "patience"):
            check_int(name, getattr(self, name))
        check_float("threshold", self.threshold, 0.0, open_low=True)
        for kind in self.revisions:
            check_choice("revisions", kind, ("add_parent", "capacity", "split"))


@dataclass(frozen=True)
class BabbleConfig:
    """Random babbling: uniform actions, or with probability ``local`` a move within ``reach`` of the joints.

    ``local`` moves apply to position-servo actions (one per joint, in joint units); for other
    actions babbling is uniform.
    """

    local: float = 0.5
    reach: float = 0.5

    def __post_init__(self) -> None:
        check_float("local", self.local, 0.0, 1.0)
        check_float("reach", self.reach, 0.0)


@dataclass(frozen=True)
class CorrectionConfig:
    """Online correction from abducted residuals (:mod:`pal.agent.correction`).

    Attributes:
        enabled: carry the filtered residuals of the executed steps forward in the planner's rollouts.
        window: k >= 1, the last k executed transitions whose residuals are averaged.
        gain: g in (0, 1], the filter's step towards that average per step.
        sites: the corrected continuous sites (those the graph has).
    """

    enabled: bool = False
    window: int = 3
    gain: float = 0.5
    sites: tuple[str, ...] = ("dq", "v", "dee")

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, bool):
            raise ValueError(f"correction.enabled is {self.enabled!r}; expected True or False")
        if isinstance(self.window, bool) or not isinstance(self.window, int) or self.window < 1:
            raise ValueError(
                f"correction.window is {self.window!r}; the residuals of the last k executed steps are averaged: "
                "give an int k >= 1"
            )
        check_float("correction.gain", self.gain, 0.0, 1.0, open_low=True)
        if not self.sites or not all(isinstance(x, str) and x for x in self.sites):
            raise ValueError(f"correction.sites is {self.sites!r}; give site names, e.g. ('dq', 'v', 'dee')")
        object.__setattr__(self, "sites", tuple(self.sites))


@dataclass(frozen=True)
class AgentConfig:
    """Settings of the loop (the seed is an argument of :class:`pal.agent.Agent`, not a setting).

    Attributes:
        perception: configuration of Π (perceived objects only).
        top_surface: perceived positions are the centres of the objects' top surfaces.
        model, estimate, plan, curiosity, learn, babble, correction: the parts' settings.
        reset_every: steps per episode before the environment is reset (None: never).
        servo: actions are joint position targets (babbling moves around the joint angles);
            None (the default): read from the MJCF's actuators when the environment is a MuJoCo
            env (:func:`pal.agent.body_checks.resolve_servo`; True otherwise); an explicit value
            that contradicts an actuator is an error.
    """

    perception: PipelineConfig = PipelineConfig(relations=None)
    top_surface: bool = True
    model: ModelConfig = ModelConfig()
    estimate: EstimateConfig = EstimateConfig()
    plan: PlanConfig = PlanConfig()
    curiosity: CuriosityConfig = CuriosityConfig()
    learn: LearnConfig = LearnConfig()
    babble: BabbleConfig = BabbleConfig()
    correction: CorrectionConfig = CorrectionConfig()
    reset_every: int | None = 40
    servo: bool | None = None

    def __post_init__(self) -> None:
        if self.reset_every is not None:
            check_int("reset_every", self.reset_every)
        if self.servo is not None and not isinstance(self.servo, bool):
            raise ValueError(f"servo is {self.servo!r}; expected True, False or None (read from the MJCF)")
