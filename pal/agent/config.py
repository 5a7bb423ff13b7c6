"""The agent's settings: babbling, fitting, state and action inference, curiosity, episodes."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from pal.checks import check_choice, check_float, check_int
from pal.perception import PipelineConfig

__all__ = ["AgentConfig"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AgentConfig:
    """Settings of the loop (the seed is an argument of :class:`pal.agent.Agent`, not a setting).

    Attributes:
        objects: object slots, largest object first.
        top_surface: object positions are the centres of their top surfaces, from Π's masks and
            the depth (:func:`pal.agent.perception.top_centre`); False: Π's positions as reported.
        perception: configuration of Π.
        hidden: MLP widths of the learned mechanisms.
        epochs, batch_size, lr: fitting schedule (Eq. 4.33).
        min_sigma: floor on fitted residual scales, m (keeps state inference well conditioned).
        state_steps, state_lr, state_lr_final, state_init_scale: SVI of the per-step state posterior
            (steps, learning rate decaying to ``state_lr_final``, initial guide scale in m). The
            guide starts at 0, so ``state_lr`` must let it travel across the table (~0.5 m).
        state_guide: ``"mvn"`` (full covariance: pos.o and dpos.o are tightly coupled, which a
            mean-field guide follows only slowly) or ``"normal"``.
        action_steps, action_lr, action_starts: Alg. 4.2 (Adam steps, eta_act, random starts).
        target_scale: sd of the Gaussian preference around a target, m (Eq. 4.45).
        min_progress: if the best inferred action is predicted to bring the object less than this
            much closer to its target (m), a curious agent babbles instead and a goal-directed one
            holds still (nothing to gain).
        lookahead, lookahead_margin: two-step planning for goals (:meth:`Agent.plan`), m.
        goal_tolerance: a goal closer than this (m, by the state estimate) is held, not pushed.
        region: ((x0, y0), (x1, y1)) table region of the object variables, m (curiosity grid).
        bins, alpha: curiosity grid cells per axis and locality gain (Eq. 4.36).
        babble_local, babble_reach: share of babbling actions that are small moves, and their
            range, rad (uniform servo targets otherwise, as in the thesis's babbling).
        reset_every: steps per episode before the objects are put back (None: never).
        refit_every: online refit period, steps.
    """

    objects: tuple[str, ...] = ("box", "ball")
    top_surface: bool = True
    perception: PipelineConfig = PipelineConfig(relations=None)
    hidden: tuple[int, ...] = (64, 64)
    epochs: int = 150
    batch_size: int = 256
    lr: float = 0.005
    min_sigma: float = 0.003
    state_steps: int = 40
    state_lr: float = 0.035
    state_lr_final: float = 0.002
    state_init_scale: float = 0.005
    state_guide: str = "mvn"
    action_steps: int = 80
    action_lr: float = 0.1
    action_starts: int = 32
    target_scale: float = 0.02
    min_progress: float = 0.003
    lookahead: bool = True
    lookahead_margin: float = 0.005
    goal_tolerance: float = 0.01
    region: tuple[tuple[float, float], tuple[float, float]] = ((-0.3, 0.0), (0.3, 0.45))
    bins: tuple[int, int] = (8, 8)
    alpha: float = 0.5
    babble_local: float = 0.5
    babble_reach: float = 0.5
    reset_every: int | None = 40
    refit_every: int = 100

    def __post_init__(self) -> None:
        objects = (self.objects,) if isinstance(self.objects, str) else tuple(self.objects)
        if not objects or len(set(objects)) != len(objects):
            raise ValueError(f"objects {list(objects)!r} must be distinct slot names, at least one")
        object.__setattr__(self, "objects", objects)
        object.__setattr__(self, "hidden", tuple(check_int("hidden", h) for h in self.hidden))
        for name in ("epochs", "batch_size", "state_steps", "action_steps", "action_starts", "refit_every"):
            check_int(name, getattr(self, name))
        if self.reset_every is not None:
            check_int("reset_every", self.reset_every)
        object.__setattr__(self, "bins", tuple(check_int("bins", b, minimum=2) for b in self.bins))
        check_choice("state_guide", self.state_guide, ("mvn", "normal"))
        for name in (
            "lr",
            "state_lr",
            "state_lr_final",
            "state_init_scale",
            "action_lr",
            "target_scale",
            "min_sigma",
        ):
            check_float(name, getattr(self, name), 0.0, open_low=True)
        for name in ("min_progress", "lookahead_margin", "goal_tolerance", "alpha", "babble_reach"):
            check_float(name, getattr(self, name), 0.0)
        check_float("babble_local", self.babble_local, 0.0, 1.0)
        ratio = (self.state_lr_final / self.state_lr) ** (1.0 / self.state_steps)
        travel = self.state_lr * (1 - ratio**self.state_steps) / max(1 - ratio, 1e-12)
        if travel < 0.45:
            log.warning(
                "state inference can move its guide only %.2f m from 0 in %d steps (lr %g -> %g); positions "
                "on the table reach 0.45 m, so estimates may be cut short: raise state_steps or state_lr",
                travel,
                self.state_steps,
                self.state_lr,
                self.state_lr_final,
            )
