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
(:mod:`inference.action_objective`). The ensembles' members are evaluated in one batched pass
there (:func:`models.stacked.stacked_members`). Without them (``sampling=None, horizon=1, risk=None``)
this is the thesis protocol, Adam from one start through the Pyro program. Options, result
and input checks live in :mod:`inference.action_options`.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyro
import torch
from torch import Tensor
from tqdm import tqdm

from inference.action_objective import (
    TARGET_AT,
    ActionObjective,
    LogPreference,
    check_risk,
    gaussian_log_preference,
    scales,
)
from inference.action_options import (
    ActionOptions,
    ActionResult,
    _check_sampling,
    _initial,
)
from inference.active import no_handler_active
from inference.frozen import frozen_parameters
from inference.handlers import Intervene, ReplayNoise
from inference.planning import SamplingConfig, plan
from inference.program import Program, as_program, check_active_handlers
from models.checks import (
    check_bool,
    check_callable,
    check_choice,
    check_float,
    check_int,
    check_names,
    check_seed,
    describe,
)
from models.stacked import stacked_members
from models.variables import Role
from models.world import WorldModel, as_values, check_action_bounds

__all__ = ["ActionOptions", "ActionResult", "SamplingConfig", "gaussian_log_preference", "infer_action"]

log = logging.getLogger(__name__)


def _preference(log_preference: LogPreference, predicted: Mapping[str, Tensor], n: int) -> Tensor:
    out = log_preference(predicted)
    if not isinstance(out, Tensor) or out.shape != (n,):
        got = tuple(out.shape) if isinstance(out, Tensor) else describe(out)
        raise ValueError(f"log_preference returned {got}, expected a tensor of shape ({n},)")
    return out


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
) -> ActionResult:
    """Find actions whose predicted consequences match the targets (Alg. 4.2).

    Without ``sampling``, ``horizon`` and ``risk`` this is the thesis protocol: projected
    Adam from ``init`` through the Pyro program under ``do(actions)`` with residuals
    replayed (expected residuals u-bar, or those of a ``ReplayNoise`` the program carries).
    Otherwise the loss of :mod:`inference.action_objective` is evaluated with the torch twins
    :meth:`~models.WorldModel.predict` / :meth:`~models.WorldModel.rollout` of that program
    (or, for a program with handlers or under any active handler, the program itself over
    a candidate plate; :mod:`inference.active`): with
    ``sampling`` a CEM / iCEM stage (:mod:`inference.planning`) starts from ``init`` (one
    member of the first population), projected Adam refines the best
    ``sampling.refine_elites`` elites, and each unit keeps its lowest-loss candidate.

    Args:
        model: the world model (fixed), or a program made from one (e.g.
            ``ReplayNoise(abducted, default="expected")(model)`` to plan with abducted residuals,
            also through the torch twin with a horizon: ``(N, dim)`` held or ``(N, H, dim)``; or
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

    Returns:
        :class:`ActionResult`. After each Adam step the actions are clipped to their
        bounds, and sampled candidates are clipped to them, so ``actions`` always lies
        within them.

    Raises:
        ValueError: bad state, targets or init values (see
            :func:`models.world.as_values`), fixed actions outside their bounds, unknown or
            non-action ``actions``, a bad scale, log-preference, optimiser argument,
            sampling config, horizon, target_at or risk, non-roots in the state with a
            horizon, a disagreement risk without targets, or a horizon or risk for a
            program with handlers or under an active handler.
        FloatingPointError: the final loss is NaN or inf.
    """
    program = as_program(model)
    check_active_handlers(program.graph)
    noise = _replayed(program)
    plain = (not program.handlers or noise is not None) and no_handler_active()
    opts, risk_kind = _checked_options(options)
    steps = check_int("num_steps", num_steps, minimum=1)
    seed = check_seed("seed", seed)
    progress_bar = check_bool("progress_bar", progress_bar)
    query = _query(program.world, state, targets, actions, opts)
    generator = torch.Generator().manual_seed(seed)
    opts = _search_options(program.world, query, opts, risk_kind, plain)
    thesis = opts.sampling is None and opts.horizon == 1 and risk_kind[0] is None
    if thesis:
        return _through_program(program, query, opts.init, steps, opts.lr, generator, progress_bar)
    _check_planning(program.world.graph, query, opts.horizon, risk_kind)
    if not plain:
        return _sampled_program(
            program, query, opts.init, opts.sampling, steps, opts.lr, generator, progress_bar
        )
    given = _check_noise(program.world, noise, query.n, opts.horizon)
    return _through_twin(program.world, query, opts, risk_kind, steps, generator, progress_bar, given)


def _replayed(program: Program) -> dict[str, Tensor] | None:
    """The residuals of a program whose only handler is ``ReplayNoise(u, default="expected")``, else None.

    The torch twin replays them (``x = f(pa) + sigma(pa) u``, 0 elsewhere), so such a program plans
    with a horizon or a risk too: e.g. residuals abducted from executed steps, carried forward.
    """
    if len(program.handlers) != 1:
        return None
    handler = program.handlers[0]
    if not isinstance(handler, ReplayNoise) or handler.default != "expected":
        return None
    return dict(handler.noise)


def _search_options(
    model: WorldModel, query: _Query, opts: ActionOptions, risk_kind: tuple[str | None, float], plain: bool
) -> ActionOptions:
    """A sampling stage when a discrete site lies downstream of the actions; a horizon or risk needs a plain model."""
    if opts.sampling is None and _discrete_downstream(model, query.actions):
        opts = dataclasses.replace(opts, sampling=SamplingConfig())
    if not plain and (opts.horizon > 1 or risk_kind[0] is not None):
        raise ValueError(
            "a horizon or a risk plans through the torch twin of a plain WorldModel; pass the model "
            "itself (fixed values in state) instead of a program with handlers, and enter no handler with "
            "``with`` around the call"
        )
    return opts


def _check_noise(
    model: WorldModel, noise: Mapping[str, Any] | None, n: int, horizon: int
) -> dict[str, Tensor]:
    """The replayed residuals of a ``ReplayNoise`` program, checked: non-roots, ``(N, dim)`` or ``(N, H, dim)``."""
    out: dict[str, Tensor] = {}
    graph = model.graph
    for name, raw in dict(noise or {}).items():
        if not isinstance(name, str) or name not in graph or graph.is_root(name):
            raise ValueError(f"noise names {name!r}, not a non-root site; non-roots: {list(graph.non_roots)}")
        eps = torch.as_tensor(raw, dtype=model.dtype)
        shapes = [(n, graph[name].dim)] + ([(n, horizon, graph[name].dim)] if horizon > 1 else [])
        if tuple(eps.shape) not in shapes:
            raise ValueError(
                f"ReplayNoise: noise[{name!r}] has shape {tuple(eps.shape)}, expected one of {shapes}"
            )
        if not torch.isfinite(eps).all():
            raise ValueError(f"noise[{name!r}] is not finite")
        out[name] = eps
    return out


@dataclass(frozen=True)
class _Query:
    """The checked inputs of one action query.

    Attributes:
        given: name -> ``(N, dim)`` the state, fixed actions included.
        targets: name -> ``(N, dim)`` the targets (may be empty with a log-preference).
        n: the number of units N.
        actions: the optimised actions.
        log_preference: ``predicted -> (N,)`` (by default the Gaussian one of the targets).
        fixed_acts: the actions given in the state (held fixed).
        evidence: the state without the fixed actions.
    """

    given: dict[str, Tensor]
    targets: dict[str, Tensor]
    n: int
    actions: list[str]
    log_preference: LogPreference
    fixed_acts: dict[str, Tensor]
    evidence: dict[str, Tensor]


def _checked_options(options: Any) -> tuple[ActionOptions, tuple[str | None, float]]:
    """The options with their values checked, and the parsed risk."""
    if options is not None and not isinstance(options, ActionOptions):
        raise ValueError(f"options must be an ActionOptions or None, got {describe(options)}")
    opts = options or ActionOptions()
    lr = check_float("lr", opts.lr, minimum=0.0, min_open=True)
    sampling = _check_sampling(opts.sampling)
    horizon = check_int("horizon", opts.horizon)
    target_at = check_choice("target_at", opts.target_at, TARGET_AT)
    risk_kind = check_risk(opts.risk)
    if opts.log_preference is not None:
        check_callable("log_preference", opts.log_preference)
    opts = dataclasses.replace(opts, lr=lr, sampling=sampling, horizon=horizon, target_at=target_at)
    return opts, risk_kind


def _query(
    model: WorldModel,
    state: Mapping[str, Any] | None,
    targets: Mapping[str, Any] | None,
    actions: Sequence[str] | None,
    opts: ActionOptions,
) -> _Query:
    """Check the state, the targets and the optimised actions; build the default preference."""
    graph = model.graph
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
    log_preference = opts.log_preference
    if log_preference is None:
        if not tgt:
            raise ValueError("give targets or a log_preference")
        log_preference = gaussian_log_preference(tgt, opts.scale)
    fixed_acts = {k: v for k, v in given.items() if graph[k].role is Role.ACTION}
    evidence = {k: v for k, v in given.items() if k not in fixed_acts}
    return _Query(dict(given), dict(tgt), n, list(actions), log_preference, fixed_acts, evidence)


def _discrete_downstream(model: WorldModel, actions: Sequence[str]) -> bool:
    """True (and logged) when a discrete site follows the actions: its argmax has no gradient."""
    downstream = set().union(*(model.graph.descendants(a) for a in actions))
    if downstream & set(model.discrete):
        log.info(
            "infer_action: discrete sites %s follow the actions; using the sampling stage",
            sorted(downstream & set(model.discrete)),
        )
        return True
    return False


def _check_planning(graph: Any, query: _Query, horizon: int, risk_kind: tuple[str | None, float]) -> None:
    """Refuse non-roots in the state with a horizon, and a disagreement risk without targets."""
    if horizon > 1:
        not_roots = [k for k in query.given if not graph.is_root(k)]
        if not_roots:
            raise ValueError(
                f"with horizon {horizon} the state may give roots only (rollout initial values and held "
                f"inputs); {not_roots} are not roots"
            )
    if risk_kind[0] == "disagreement" and not query.targets:
        raise ValueError("risk ('disagreement', w) needs targets: the sites whose member spread is weighed")


def _through_twin(
    model: WorldModel,
    query: _Query,
    opts: ActionOptions,
    risk_kind: tuple[str | None, float],
    steps: int,
    generator: torch.Generator,
    progress_bar: bool,
    noise: Mapping[str, Tensor] | None = None,
) -> ActionResult:
    """Sampling stage and Adam through the torch twins (predict, rollout) of a plain model."""
    actions, horizon, n = query.actions, opts.horizon, query.n
    objective = ActionObjective(
        model,
        query.given,
        actions,
        dict(noise or {}),
        query.log_preference,
        n,
        horizon,
        opts.target_at,
        risk_kind,
        scales(opts.scale, list(query.targets)) if query.targets else {},
    )
    start = _initial(model, actions, n, opts.init, generator, horizon)
    start_t = torch.cat([v if horizon > 1 else v.unsqueeze(1) for v in start.values()], -1)
    low = torch.cat([model.bounds(a)[0] for a in actions])
    high = torch.cat([model.bounds(a)[1] for a in actions])
    with frozen_parameters(model), stacked_members(model):
        best, history, search, final = plan(
            objective, start_t, low, high, opts.sampling, steps, opts.lr, generator, progress_bar
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
    query: _Query,
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
    actions, n, log_preference = query.actions, query.n, query.log_preference
    fixed_acts, evidence = query.fixed_acts, query.evidence
    dims = [graph[a].dim for a in actions]

    def predict(a: Tensor) -> dict[str, Tensor]:
        r = a.shape[0]
        parts = dict(zip(actions, torch.split(a[:, :, 0], dims, dim=-1), strict=True))
        run = Intervene({**fixed_acts, **parts})(ReplayNoise({}, default="expected")(program))
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
    query: _Query,
    init: str | Mapping[str, Any],
    steps: int,
    lr: float,
    generator: torch.Generator,
    progress_bar: bool,
) -> ActionResult:
    """The thesis protocol: projected Adam from one start through the program under do(actions)."""
    world, n, log_preference = model.world, query.n, query.log_preference
    params = {
        k: v.requires_grad_(True) for k, v in _initial(world, query.actions, n, init, generator).items()
    }
    bounds = {k: world.bounds(k) for k in query.actions}
    optim = torch.optim.Adam(list(params.values()), lr=lr)

    def forward() -> dict[str, Tensor]:
        program = Intervene({**query.fixed_acts, **params})(ReplayNoise({}, default="expected")(model))
        return program(query.evidence, n)

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
