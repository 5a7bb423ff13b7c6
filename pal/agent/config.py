"""The agent's settings, one frozen sub-config per part: model and fit, estimate, plan, curiosity, learning."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from pal.checks import check_choice, check_float, check_int
from pal.perception import PipelineConfig

__all__ = [
    "AgentConfig",
    "BabbleConfig",
    "CuriosityConfig",
    "EstimateConfig",
    "LearnConfig",
    "ModelConfig",
    "PlanConfig",
]

log = logging.getLogger(__name__)


def _widths(name: str, value: tuple[int, ...]) -> tuple[int, ...]:
    return tuple(check_int(name, h) for h in value)


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
        epochs, batch_size, lr: fitting schedule. validation: held-out share (sigma, early stopping).
        patience: early-stopping patience, epochs (None: every epoch).
        min_sigma: floor on fitted homoscedastic sigmas, m (keeps state inference well conditioned).
        beta: the beta of the heteroscedastic fit's beta-NLL (0: the NLL; 1: the location gets the
            MSE gradient, so rare large pushes are not given up to a wide scale).
    """

    kind: str = "hetero"
    members: int = 5
    hidden: tuple[int, ...] = (64, 64)
    arm_hidden: tuple[int, ...] | None = None
    position_sigma: float = 1e-3
    structure: str = "preset"
    epochs: int = 150
    batch_size: int = 256
    lr: float = 0.005
    validation: float = 0.1
    patience: int | None = 25
    min_sigma: float = 0.003
    beta: float = 1.0

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, ("hetero", "mlp"))
        check_float("beta", self.beta, 0.0, 1.0)
        check_choice("structure", self.structure, ("preset", "discover"))
        check_int("members", self.members)
        object.__setattr__(self, "hidden", _widths("hidden", self.hidden))
        if self.arm_hidden is not None:
            object.__setattr__(self, "arm_hidden", _widths("arm_hidden", self.arm_hidden))
        for name in ("epochs", "batch_size"):
            check_int(name, getattr(self, name))
        if self.patience is not None:
            check_int("patience", self.patience)
        for name in ("lr", "position_sigma", "min_sigma"):
            check_float(name, getattr(self, name), 0.0, open_low=True)
        check_float("validation", self.validation, 0.0, 1.0, open_high=True)
        if self.patience is not None and self.validation == 0:
            raise ValueError("patience needs validation rows; set validation > 0 or patience=None")


@dataclass(frozen=True)
class EstimateConfig:
    """State inference through the measurement sites (Eq. 4.41-4.42), perceived objects only.

    Attributes:
        steps, lr, lr_final: SVI steps and learning rate (decaying to ``lr_final``). The guide
            starts at 0, so ``lr`` must let it travel across the table (~0.5 m).
        init_scale: initial guide scale, m. particles: ELBO particles.
        guide: ``"mvn"`` (full covariance: pos.o and dpos.o are tightly coupled) or ``"normal"``.
    """

    steps: int = 40
    lr: float = 0.035
    lr_final: float = 0.002
    init_scale: float = 0.005
    particles: int = 16
    guide: str = "mvn"

    def __post_init__(self) -> None:
        check_int("steps", self.steps)
        check_int("particles", self.particles)
        check_choice("guide", self.guide, ("mvn", "normal"))
        for name in ("lr", "lr_final", "init_scale"):
            check_float(name, getattr(self, name), 0.0, open_low=True)
        ratio = (self.lr_final / self.lr) ** (1.0 / self.steps)
        travel = self.lr * (1 - ratio**self.steps) / max(1 - ratio, 1e-12)
        if travel < 0.45:
            log.warning(
                "state inference can move its guide only %.2f m from 0 in %d steps (lr %g -> %g); positions "
                "on the table reach 0.45 m, so estimates may be cut short: raise steps or lr",
                travel,
                self.steps,
                self.lr,
                self.lr_final,
            )


@dataclass(frozen=True)
class PlanConfig:
    """Model-predictive control: the sampling planner over a horizon, replanned every step (Alg. 4.2).

    Attributes:
        horizon: planning steps H.
        population, elites, iterations, alpha, noise_beta, init_std: the CEM / iCEM stage
            (:class:`inference.SamplingConfig`).
        refine_steps, lr: projected Adam on the best elite after it (0: none).
        risk: None (the members' mean prediction), ``"mean"`` (expected cost over the ensemble
            members) or ``"disagreement"`` (cost of the mean plus ``risk_weight`` x the members'
            variance on the targets).
        risk_weight: the weight of ``"disagreement"`` (> 0 risk averse, < 0 seeking).
        preference: ``"gaussian"`` (``-0.5 |x - target|^2 / scale^2``) or ``"distance"``
            (``-|x - target| / scale``).
        target_at: ``"final"`` (the targets at the horizon's end) or ``"every"`` (every step).
        scale: preference scale, m.
        effector_weight: weight of the effector's distance to each targeted object in the
            preference (0: none; it brings the effector to the object).
        action_weight: weight of ``|a|^2`` (action units squared) in the preference.
        move_weight: weight of ``|a - q_prev|^2`` (rad^2): for position servos, the size of the move
            (small moves have outcomes the model knows better).
        warm_start: start the search from the previous plan shifted by one step.
        min_progress: a goal step predicted to gain less than this (m) holds still.
        goal_tolerance: a goal closer than this (m, by the estimate) is held.
    """

    horizon: int = 2
    population: int = 64
    elites: int = 8
    iterations: int = 3
    alpha: float = 0.1
    noise_beta: float = 0.0
    init_std: float = 0.5
    refine_steps: int = 20
    lr: float = 0.05
    risk: str | None = None
    risk_weight: float = 0.0
    preference: str = "gaussian"
    target_at: str = "final"
    scale: float = 0.02
    effector_weight: float = 0.0
    action_weight: float = 0.0
    move_weight: float = 0.0
    warm_start: bool = True
    min_progress: float = 0.002
    goal_tolerance: float = 0.005

    def __post_init__(self) -> None:
        for name in ("horizon", "population", "elites", "iterations"):
            check_int(name, getattr(self, name))
        check_int("refine_steps", self.refine_steps, minimum=0)
        if self.elites > self.population:
            raise ValueError(f"elites {self.elites} exceed population {self.population}")
        check_float("alpha", self.alpha, 0.0, 1.0, open_high=True)
        check_float("noise_beta", self.noise_beta, 0.0)
        for name in ("init_std", "lr", "scale"):
            check_float(name, getattr(self, name), 0.0, open_low=True)
        if self.risk is not None:
            check_choice("risk", self.risk, ("mean", "disagreement"))
        check_float("risk_weight", self.risk_weight)
        check_choice("preference", self.preference, ("gaussian", "distance"))
        check_choice("target_at", self.target_at, ("final", "every"))
        for name in ("effector_weight", "action_weight", "move_weight", "min_progress", "goal_tolerance"):
            check_float(name, getattr(self, name), 0.0)


@dataclass(frozen=True)
class CuriosityConfig:
    """How a curious agent picks what to do (:mod:`pal.agent.curiosity`, :mod:`pal.agent.influence`).

    Attributes:
        method: ``"disagreement"`` (ensemble disagreement over object variables gated by the
            causal action-influence score) or ``"density"`` (targets from Eq. 4.34-4.38 on a grid).
        horizon, population, elites, iterations: the search over action sequences (disagreement).
        influence_samples: actions M per state in the influence estimate.
        influence_scale: nats at which the gate opens fully (gate = min(1, I / scale)).
        min_score: below this score (disagreement in ``plan.scale`` units) the agent babbles.
        region, bins, alpha: the density method's grid over the table (m, cells, locality gain).
    """

    method: str = "disagreement"
    horizon: int = 2
    population: int = 64
    elites: int = 8
    iterations: int = 3
    influence_samples: int = 8
    influence_scale: float = 0.5
    min_score: float = 1e-3
    region: tuple[tuple[float, float], tuple[float, float]] = ((-0.3, 0.0), (0.3, 0.45))
    bins: tuple[int, int] = (8, 8)
    alpha: float = 0.5

    def __post_init__(self) -> None:
        check_choice("method", self.method, ("disagreement", "density"))
        for name in ("horizon", "population", "elites", "iterations", "influence_samples"):
            check_int(name, getattr(self, name))
        if self.elites > self.population:
            raise ValueError(f"elites {self.elites} exceed population {self.population}")
        check_float("influence_scale", self.influence_scale, 0.0, open_low=True)
        check_float("min_score", self.min_score, 0.0)
        check_float("alpha", self.alpha, 0.0)
        object.__setattr__(self, "bins", tuple(check_int("bins", b, minimum=2) for b in self.bins))


@dataclass(frozen=True)
class LearnConfig:
    """Online learning: refits, and the structural revision when the residual monitor fires (Eq. 4.50).

    Attributes:
        refit_every: refit period, steps (in the curious and goal modes).
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
class AgentConfig:
    """Settings of the loop (the seed is an argument of :class:`pal.agent.Agent`, not a setting).

    Attributes:
        perception: configuration of Π (perceived objects only).
        top_surface: perceived positions are the centres of the objects' top surfaces.
        model, estimate, plan, curiosity, learn, babble: the parts' settings.
        reset_every: steps per episode before the environment is reset (None: never).
        servo: actions are joint position targets (babbling moves around the joint angles).
    """

    perception: PipelineConfig = PipelineConfig(relations=None)
    top_surface: bool = True
    model: ModelConfig = ModelConfig()
    estimate: EstimateConfig = EstimateConfig()
    plan: PlanConfig = PlanConfig()
    curiosity: CuriosityConfig = CuriosityConfig()
    learn: LearnConfig = LearnConfig()
    babble: BabbleConfig = BabbleConfig()
    reset_every: int | None = 40
    servo: bool = True

    def __post_init__(self) -> None:
        if self.reset_every is not None:
            check_int("reset_every", self.reset_every)
