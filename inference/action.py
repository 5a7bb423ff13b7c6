"""Action inference through do(action) (thesis Eq. 4.45-4.49, Alg. 4.2), with a sampling stage.

    L_act(a) = -log p(Phi(s, a, u) | C)
    a <- clip(a - eta * Adam(grad_a L_act), A)          for K_act steps

Phi is the forward query: the program under ``do(actions = a)`` with the state given and
residuals replayed (expected residuals by default, or abducted ones). The world-model
parameters stay fixed. Every (state, target) unit is optimised at once; the loss is a sum
over units, so each unit's actions follow their own Adam trajectory.

With ``sampling`` (a :class:`inference.planning.SamplingConfig`) a CEM / iCEM stage over the
action box comes first, for all units x candidates in one batch, starting from the thesis
start (one member of the first population); projected Adam then refines the best elites,
and each unit keeps its best candidate. ``horizon=H > 1`` plans H-step sequences through
:meth:`models.WorldModel.rollout`; ``risk`` weighs the disagreement of ensemble members
(:mod:`inference.action_objective`). Without them (``sampling=None, horizon=1, risk=None``)
this is the thesis protocol, Adam from one start through the Pyro program.
"""

from __future__ import annotations

import dataclasses
import logging
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyro
import torch
from pyro.poutine.runtime import _PYRO_STACK
from torch import Tensor
from tqdm import tqdm

from inference.action_objective import (
    TARGET_AT,
    ActionObjective,
    LogPreference,
    Risk,
    check_risk,
    gaussian_log_preference,
    scales,
)
from inference.frozen import frozen_parameters
from inference.handlers import Intervene, ProgramMessenger, ReplayNoise
from inference.planning import SamplingConfig, plan
from inference.program import Program, as_program, check_active_handlers
from models.checks import (
    check_bool,
    check_callable,
    check_choice,
    check_float,
    check_int,
    check_mapping,
    check_names,
    check_seed,
    describe,
)
from models.variables import Role
from models.world import WorldModel, as_values, check_action_bounds

__all__ = ["ActionOptions", "ActionResult", "SamplingConfig", "gaussian_log_preference", "infer_action"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ActionResult:
    """Inferred actions.

    Attributes:
        actions: name -> ``(N, dim)`` optimised actions a* (within bounds); ``(N, H, dim)``
            action sequences with ``horizon=H > 1``.
        predicted: name -> ``(N, dim)`` forward query Phi(s, a*, u) for every variable
            (``(N, H, dim)``, the simulated trajectory, with a horizon); the model's own
            prediction, also when a risk weighs its ensemble members.
        losses: mean over units (and refined elites) of L_act at each Adam step, before the
            update; length ``num_steps`` (the refinement's steps with sampling); ``loss`` is an alias.
        final_loss: ``(N,)`` L_act(a*) per unit, with the risk term if any.
        search_loss: mean over units of the best candidate's loss after each sampling
            iteration (empty without sampling); never increasing.
    """

    actions: dict[str, Tensor]
    predicted: dict[str, Tensor]
    losses: tuple[float, ...]
    final_loss: Tensor
    search_loss: tuple[float, ...] = ()

    @property
    def loss(self) -> tuple[float, ...]:
        """Alias of :attr:`losses`."""
        return self.losses

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible actions, predictions and losses."""
        return {
            "actions": {k: v.tolist() for k, v in self.actions.items()},
            "predicted": {k: v.tolist() for k, v in self.predicted.items()},
            "final_loss": self.final_loss.tolist(),
            "num_steps": len(self.losses),
            "losses_last": self.losses[-1] if self.losses else None,
            "search_loss": list(self.search_loss),
        }


def _initial(
    model: WorldModel,
    names: Sequence[str],
    n: int,
    init: str | Mapping[str, Any],
    generator: torch.Generator,
    horizon: int = 1,
) -> dict[str, Tensor]:
    """Start values: name -> ``(N, dim)``, or ``(N, H, dim)`` with ``horizon=H > 1``."""
    out = {}
    if isinstance(init, Mapping):
        unknown = sorted(str(k) for k in init if k not in names)
        if unknown:
            raise ValueError(f"init names {unknown}, which are not optimised actions {list(names)}")
    elif not isinstance(init, str):
        raise ValueError(f"init must be 'midpoint', 'random' or a mapping, got {describe(init)}")
    lead = (n,) if horizon == 1 else (n, horizon)
    for name in names:
        low, high = model.bounds(name)
        dim = low.shape[0]
        if isinstance(init, Mapping):
            if name not in init:
                raise ValueError(f"init has no value for action {name!r}")
            a = _given_init(model, name, init[name], n, horizon)
            if ((a < low) | (a > high)).any():
                raise ValueError(f"init[{name!r}] lies outside the bounds [{low.tolist()}, {high.tolist()}]")
        elif init == "midpoint":
            a = ((low + high) / 2).expand(*lead, dim).clone()
        elif init == "random":
            a = low + (high - low) * torch.rand(*lead, dim, generator=generator, dtype=model.dtype)
        else:
            raise ValueError(f"init {init!r} unknown; expected 'midpoint', 'random' or a mapping")
        out[name] = a
    return out


def _given_init(model: WorldModel, name: str, raw: Any, n: int, horizon: int) -> Tensor:
    """A given start ``(N, dim)`` (held on every step) or, with a horizon, ``(N, H, dim)``."""
    if horizon > 1 and getattr(raw, "ndim", None) == 3:
        given, _ = as_values(model.graph, {name: raw}, n=n, what="init", extra_dims=1, dtype=model.dtype)
        a = given[name].detach().clone()
        if a.shape[1] != horizon:
            raise ValueError(f"init[{name!r}] has {a.shape[1]} steps, expected horizon {horizon}")
        return a
    given, _ = as_values(model.graph, {name: raw}, n=n, what="init", dtype=model.dtype)
    a = given[name].detach().clone()
    return a if horizon == 1 else a.unsqueeze(1).expand(n, horizon, a.shape[-1]).clone()


def _noise_values(model: WorldModel, noise: Any, n: int, horizon: int) -> dict[str, Tensor]:
    """Residuals name -> ``(N, dim)``, or with a horizon also ``(N, H, dim)`` (one per step)."""
    noise = check_mapping("noise", noise, allow_none=True)
    steps = {k: v for k, v in noise.items() if horizon > 1 and getattr(v, "ndim", None) == 3}
    rest = {k: v for k, v in noise.items() if k not in steps}
    eps, _ = as_values(model.graph, rest, n=n, what="noise", dtype=model.dtype)
    per_step, _ = as_values(model.graph, steps, n=n, what="noise", extra_dims=1, dtype=model.dtype)
    for k, v in per_step.items():
        if v.shape[1] != horizon:
            raise ValueError(f"noise[{k!r}] has {v.shape[1]} steps, expected horizon {horizon}")
    return {**eps, **per_step}


def _preference(log_preference: LogPreference, predicted: Mapping[str, Tensor], n: int) -> Tensor:
    out = log_preference(predicted)
    if not isinstance(out, Tensor) or out.shape != (n,):
        got = tuple(out.shape) if isinstance(out, Tensor) else describe(out)
        raise ValueError(f"log_preference returned {got}, expected a tensor of shape ({n},)")
    return out


def _check_sampling(sampling: Any) -> SamplingConfig | None:
    if sampling is not None and not isinstance(sampling, SamplingConfig):
        raise ValueError(f"sampling must be None or a SamplingConfig, got {describe(sampling)}")
    return sampling


@dataclass(frozen=True)
class ActionOptions:
    """How :func:`infer_action` scores and searches actions.

    Attributes:
        scale: Gaussian preference scale > 0 (targets' units), scalar or one per target;
            also the unit of the disagreement term.
        log_preference: optional callable ``predicted -> (N,)`` log-preference replacing
            the Gaussian one (then ``targets`` may be None). With sampling, a horizon or a
            risk it gets values with leading candidate axes ``(..., N, dim)`` and must
            return ``(..., N)`` (broadcast like :func:`gaussian_log_preference`).
        lr: Adam learning rate eta_act (thesis B2: 0.05).
        init: ``"midpoint"`` (thesis B2), ``"random"`` or name -> ``(N, dim)`` within
            bounds (with a horizon also ``(N, H, dim)``).
        sampling: None (gradient only) or the sizes of the sampling stage. A model with a
            discrete site downstream of the actions gets ``SamplingConfig()`` when None:
            the argmax of a discrete site has no gradient.
        horizon: planning steps H >= 1 through the rollout (Alg. 4.1).
        target_at: with a horizon, ``"final"`` or ``"every"`` step.
        risk: None, ``"mean"`` or ``("disagreement", w)`` over ensemble members.
    """

    scale: float | Mapping[str, float] = 1.0
    log_preference: LogPreference | None = None
    lr: float = 0.05
    init: str | Mapping[str, Any] = "midpoint"
    sampling: SamplingConfig | None = None
    horizon: int = 1
    target_at: str = "final"
    risk: Risk = None


#: Keywords of the earlier signature, accepted with a DeprecationWarning.
_DEPRECATED = ("steps", "noise", *ActionOptions.__dataclass_fields__)


def _legacy_options(
    options: Any, deprecated: Mapping[str, Any], num_steps: int
) -> tuple[ActionOptions, int, Any]:
    unknown = sorted(k for k in deprecated if k not in _DEPRECATED)
    if unknown:
        raise TypeError(f"infer_action() got unexpected keyword arguments {unknown}")
    if options is not None and not isinstance(options, ActionOptions):
        raise ValueError(f"options must be an ActionOptions or None, got {describe(options)}")
    options = options or ActionOptions()
    fields = {k: v for k, v in deprecated.items() if k in ActionOptions.__dataclass_fields__}
    if deprecated:
        warnings.warn(
            f"infer_action({', '.join(f'{k}=' for k in deprecated)}) is deprecated: pass num_steps=, "
            "options=ActionOptions(...) and the residuals as ReplayNoise(noise)(model)",
            DeprecationWarning,
            stacklevel=3,
        )
    if fields:
        options = dataclasses.replace(options, **fields)
    return options, deprecated.get("steps", num_steps), deprecated.get("noise")


def infer_action(
    model: Any,
    state: Mapping[str, Any] | None,
    targets: Mapping[str, Any] | None = None,
    *,
    actions: Sequence[str] | None = None,
    num_steps: int = 200,
    options: ActionOptions | None = None,
    seed: int = 0,
    progress_bar: bool = False,
    **deprecated: Any,
) -> ActionResult:
    """Find actions whose predicted consequences match the targets (Alg. 4.2).

    Without ``sampling``, ``horizon`` and ``risk`` this is the thesis protocol: projected
    Adam from ``init`` through the Pyro program under ``do(actions)`` with residuals
    replayed (expected residuals u-bar, or those of a ``ReplayNoise`` the program carries).
    Otherwise the loss of :mod:`inference.action_objective` is evaluated with the torch twins
    :meth:`~models.WorldModel.predict` / :meth:`~models.WorldModel.rollout` of that program
    (or, for a program with handlers, the program itself over a candidate plate): with
    ``sampling`` a CEM / iCEM stage (:mod:`inference.planning`) starts from ``init`` (one
    member of the first population), projected Adam refines the best
    ``sampling.refine_elites`` elites, and each unit keeps its lowest-loss candidate.

    Args:
        model: the world model (fixed), or a program made from one (e.g.
            ``ReplayNoise(abducted)(model)`` to plan with abducted residuals, or
            ``do(model, ...)``); handlers entered with ``with`` act too.
        state: name -> ``(N, dim)`` current state estimate s(t) (e.g. ``q_prev``), and
            any actions that are held fixed (within their bounds); None if the graph has
            no other roots. With a horizon only roots: lag-1 ones are the initial values of
            the rollout, lag-0 ones are held on every step.
        targets: name -> ``(N, dim)`` desired values of non-action variables; with the
            default Gaussian preference the loss is ``sum 0.5 ((Phi - target) / scale)^2``.
        actions: action variables to optimise (default: every action not in ``state``).
        num_steps: Adam iterations K_act (thesis B2: 200); the refinement's unless
            ``sampling.refine_steps`` is set.
        options: :class:`ActionOptions` (preference, lr, init, sampling, horizon, risk).
        seed: seeds ``init="random"`` and the sampling stage (local generator).
        progress_bar: show a tqdm bar over the Adam steps.
        **deprecated: ``steps`` (use ``num_steps``), ``noise`` (use ``ReplayNoise``) and
            the fields of :class:`ActionOptions` as keywords.

    Returns:
        :class:`ActionResult`. After each Adam step the actions are clipped to their
        bounds, and sampled candidates are clipped to them, so ``actions`` always lies
        within them.

    Raises:
        ValueError: bad state, targets, init or noise values (see
            :func:`models.world.as_values`), fixed actions outside their bounds, unknown or
            non-action ``actions``, a bad scale, log-preference, optimiser argument,
            sampling config, horizon, target_at or risk, non-roots in the state with a
            horizon, a disagreement risk without targets, or a horizon or risk for a
            program with handlers.
        FloatingPointError: the final loss is NaN or inf.
    """
    opts, num_steps, noise = _legacy_options(options, deprecated, num_steps)
    scale, log_preference, lr, init = opts.scale, opts.log_preference, opts.lr, opts.init
    sampling, horizon, target_at, risk = opts.sampling, opts.horizon, opts.target_at, opts.risk
    steps = num_steps
    program = as_program(model)
    model = program.world
    check_active_handlers(program.graph)
    plain = not program.handlers and not any(isinstance(f, ProgramMessenger) for f in _PYRO_STACK)
    graph = model.graph
    steps = check_int("num_steps", steps, minimum=1)
    lr = check_float("lr", lr, minimum=0.0, min_open=True)
    seed = check_seed("seed", seed)
    progress_bar = check_bool("progress_bar", progress_bar)
    sampling = _check_sampling(sampling)
    horizon = check_int("horizon", horizon)
    target_at = check_choice("target_at", target_at, TARGET_AT)
    risk_kind = check_risk(risk)
    if log_preference is not None:
        check_callable("log_preference", log_preference)
    given, n = as_values(graph, state, what="state", dtype=model.dtype)
    tgt, n = as_values(graph, targets, n=n, what="targets", dtype=model.dtype)
    if n is None:
        raise ValueError("state and targets are empty; cannot tell the number of units")
    check_action_bounds(graph, given, "state")
    if actions is None:
        actions = [a for a in graph.actions if a not in given]
    actions = check_names("actions", actions)
    for a in actions:
        graph.check_name(a, what="action")
        if graph[a].role is not Role.ACTION:
            raise ValueError(f"{a!r} has role {graph[a].role.value!r}; only actions can be optimised")
        if a in given:
            raise ValueError(f"action {a!r} is both given in state and optimised")
    if not actions:
        raise ValueError("no action to optimise: the graph has no actions, or all are given in state")
    for name in tgt:
        if name in actions:
            raise ValueError(f"target {name!r} is an optimised action; targets must be consequences")
    if log_preference is None:
        if not tgt:
            raise ValueError("give targets or a log_preference")
        log_preference = gaussian_log_preference(tgt, scale)
    fixed_acts = {k: v for k, v in given.items() if graph[k].role is Role.ACTION}
    evidence = {k: v for k, v in given.items() if k not in fixed_acts}
    eps = _noise_values(model, noise, n, horizon)
    clash = sorted(k for k in eps if k in given or k in actions)
    if clash:
        raise ValueError(
            f"noise names {clash}, which are given in state or optimised; residuals are for the other variables"
        )
    generator = torch.Generator().manual_seed(seed)
    downstream = set().union(*(graph.descendants(a) for a in actions))
    if sampling is None and downstream & set(model.discrete):
        log.info(
            "infer_action: discrete sites %s follow the actions; using the sampling stage",
            sorted(downstream & set(model.discrete)),
        )
        sampling = SamplingConfig()
    if not plain and (horizon > 1 or risk_kind[0] is not None):
        raise ValueError(
            "a horizon or a risk plans through the torch twin of a plain WorldModel; pass the model "
            "itself (fixed values in state, residuals as noise) instead of a program with handlers"
        )
    if sampling is None and horizon == 1 and risk_kind[0] is None:
        return _through_program(
            program,
            evidence,
            fixed_acts,
            actions,
            eps,
            log_preference,
            n,
            init,
            steps,
            lr,
            generator,
            progress_bar,
        )
    roots = [k for k in eps if graph.is_root(k)]
    if roots:
        raise ValueError(f"noise names roots {roots}; residuals are replayed for non-root variables only")
    if horizon > 1:
        not_roots = [k for k in given if not graph.is_root(k)]
        if not_roots:
            raise ValueError(
                f"with horizon {horizon} the state may give roots only (rollout initial values and held "
                f"inputs); {not_roots} are not roots"
            )
    if risk_kind[0] == "disagreement" and not tgt:
        raise ValueError("risk ('disagreement', w) needs targets: the sites whose member spread is weighed")
    if not plain:
        return _sampled_program(
            program,
            given,
            actions,
            eps,
            log_preference,
            n,
            init,
            sampling,
            steps,
            lr,
            generator,
            progress_bar,
        )
    objective = ActionObjective(
        model,
        given,
        actions,
        eps,
        log_preference,
        n,
        horizon,
        target_at,
        risk_kind,
        scales(scale, list(tgt)) if tgt else {},
    )
    start = _initial(model, actions, n, init, generator, horizon)
    start_t = torch.cat([v if horizon > 1 else v.unsqueeze(1) for v in start.values()], -1)
    low = torch.cat([model.bounds(a)[0] for a in actions])
    high = torch.cat([model.bounds(a)[1] for a in actions])
    with frozen_parameters(model):
        best, history, search, final = plan(
            objective, start_t, low, high, sampling, steps, lr, generator, progress_bar
        )
        with torch.no_grad():
            predicted = {k: v[0] for k, v in objective.predict(best[None]).items()}
    if not torch.isfinite(final).all():
        raise FloatingPointError("action inference produced a non-finite loss; check targets and scales")
    parts = torch.split(best, objective.dims, dim=-1)
    acts = {k: (v if horizon > 1 else v[:, 0]).clone() for k, v in zip(actions, parts, strict=True)}
    return ActionResult(acts, predicted, history, final, search)


def _sampled_program(
    program: Program,
    given: Mapping[str, Tensor],
    actions: Sequence[str],
    eps: Mapping[str, Tensor],
    log_preference: LogPreference,
    n: int,
    init: str | Mapping[str, Any],
    sampling: SamplingConfig | None,
    steps: int,
    lr: float,
    generator: torch.Generator,
    progress_bar: bool,
) -> ActionResult:
    """Sampling stage and Adam through a program with handlers: candidates are a plate of the program."""
    model = program.world
    graph = model.graph
    fixed_acts = {k: v for k, v in given.items() if graph[k].role is Role.ACTION}
    evidence = {k: v for k, v in given.items() if k not in fixed_acts}
    dims = [graph[a].dim for a in actions]

    def predict(a: Tensor) -> dict[str, Tensor]:
        r = a.shape[0]
        parts = dict(zip(actions, torch.split(a[:, :, 0], dims, dim=-1), strict=True))
        run = Intervene({**fixed_acts, **parts})(ReplayNoise(eps, default="expected")(program))
        with pyro.validation_enabled(False), pyro.plate("_candidates", r, dim=-2):
            out = run(evidence, n)
        return {k: v.expand(r, n, v.shape[-1]) for k, v in out.items()}

    def objective(a: Tensor) -> Tensor:
        return -log_preference(predict(a))

    start = _initial(model, actions, n, init, generator)
    start_t = torch.cat(list(start.values()), -1).unsqueeze(1)
    low = torch.cat([model.bounds(a)[0] for a in actions])
    high = torch.cat([model.bounds(a)[1] for a in actions])
    with frozen_parameters(model):
        best, history, search, final = plan(
            objective, start_t, low, high, sampling, steps, lr, generator, progress_bar
        )
        with torch.no_grad():
            predicted = {k: v[0] for k, v in predict(best[None]).items()}
    if not torch.isfinite(final).all():
        raise FloatingPointError("action inference produced a non-finite loss; check targets and scales")
    parts = torch.split(best[:, 0], dims, dim=-1)
    acts = {k: v.clone() for k, v in zip(actions, parts, strict=True)}
    return ActionResult(acts, predicted, history, final, search)


def _through_program(
    model: Any,
    evidence: Mapping[str, Tensor],
    fixed_acts: Mapping[str, Tensor],
    actions: Sequence[str],
    eps: Mapping[str, Tensor],
    log_preference: LogPreference,
    n: int,
    init: str | Mapping[str, Any],
    steps: int,
    lr: float,
    generator: torch.Generator,
    progress_bar: bool,
) -> ActionResult:
    """The thesis protocol: projected Adam from one start through the program under do(actions)."""
    world = model.world
    params = {k: v.requires_grad_(True) for k, v in _initial(world, actions, n, init, generator).items()}
    bounds = {k: world.bounds(k) for k in actions}
    optim = torch.optim.Adam(list(params.values()), lr=lr)

    def forward() -> dict[str, Tensor]:
        program = Intervene({**fixed_acts, **params})(ReplayNoise(eps, default="expected")(model))
        return program(evidence, n)

    history: list[float] = []
    with frozen_parameters(world):
        for _ in tqdm(range(steps), desc="infer_action", disable=not progress_bar, leave=False):
            optim.zero_grad()
            per_unit = -_preference(log_preference, forward(), n)
            loss = per_unit.sum()
            loss.backward()
            optim.step()
            with torch.no_grad():
                for k, p in params.items():
                    p.copy_(torch.clamp(p, *bounds[k]))
            history.append(float(loss.detach()) / n)
        with torch.no_grad():
            predicted = forward()
            final = -_preference(log_preference, predicted, n)
    if not torch.isfinite(final).all():
        raise FloatingPointError("action inference produced a non-finite loss; check targets and scales")
    acts = {k: v.detach().clone() for k, v in params.items()}
    return ActionResult(acts, {k: v.detach() for k, v in predicted.items()}, tuple(history), final.detach())
