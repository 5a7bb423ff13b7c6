"""Compiling action terms to action plans (thesis Eq. 6.10: ``do[a(o_1..o_n)]``).

The compile contract of :class:`~pal.language.signature.ActionTermDef`::

    term.compile(context: CompileContext, constants: tuple[Constant, ...]) -> Tensor (N, T, A)

one plan per start situation: T steps, A the concatenated action variables of the world model
in ``graph.actions`` order (:func:`pal.language.world.action_layout`), within their bounds. An
action variable the term does not set is held at its start value in the situations (an error
names it when the situations do not give one).

Two factories cover the usual terms:

- :func:`fixed_action_term`: a sequence computed from the start values (e.g. ``hold``: keep
  the current joint targets);
- :func:`inferred_action_term`: action inference (Alg. 4.2, :func:`inference.infer_action`,
  CEM then Adam over a horizon) towards targets computed from the start values, e.g. "bring
  the hand's position to the box's position", for all situations at once (a batch of units).

The number of model evaluations an inference takes is counted (:attr:`CompileContext.evaluations`:
candidate action sequences scored per situation, each a rollout over the horizon).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from inference import ActionOptions, SamplingConfig, infer_action
from models.variables import Role
from models.world import WorldModel
from pal.language.signature import ActionTermDef, Constant, LanguageError
from pal.language.world import Situations, action_layout

__all__ = ["CompileContext", "fixed_action_term", "inferred_action_term", "model_state"]

Values = Mapping[str, Tensor]

#: The default sampling stage of inferred terms.
DEFAULT_SAMPLING = SamplingConfig(population=64, elites=8, iterations=3, refine_steps=20)


@dataclass
class CompileContext:
    """What an action term compiles against.

    Attributes:
        model: the world model (its graph gives the plan layout; inferred terms plan with it),
            or None when ``layout`` is given and no term needs the model.
        situations: the N start situations.
        generator: randomness of the compilation (seeds of action inference).
        horizon: T, the plan's steps, >= 1.
        layout: ``(action, dim)`` columns of a plan; default the model's graph order.
        evaluations: filled by compilation: term text -> model evaluations per situation.
    """

    model: WorldModel | None
    situations: Situations
    generator: torch.Generator
    horizon: int = 1
    layout: tuple[tuple[str, int], ...] | None = None
    evaluations: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, int) or self.horizon < 1:
            raise LanguageError(f"horizon must be an int >= 1 steps, got {self.horizon!r}")
        if self.layout is None:
            if self.model is None:
                raise LanguageError("a CompileContext needs a model or a layout of the plans' action columns")
            self.layout = action_layout(self.model)

    @property
    def dtype(self) -> torch.dtype:
        """The plans' dtype (the model's, else float64)."""
        return self.model.dtype if self.model is not None else torch.float64

    def assemble(self, values: Values, what: str) -> Tensor:
        """A plan ``(N, T, A)`` from name -> ``(N, T, d)`` or ``(N, d)`` (held) action values.

        Actions not in ``values`` are held at their start value in the situations.

        Raises:
            LanguageError: an unknown action name, a value of the wrong shape, or an action
                neither set nor given in the situations.
        """
        n, t = self.situations.n, self.horizon
        assert self.layout is not None
        known = dict(self.layout)
        unknown = sorted(k for k in values if k not in known)
        if unknown:
            raise LanguageError(
                f"{what} sets {unknown}, which are not action variables; they are {list(known)}"
            )
        cols = []
        for name, d in self.layout:
            v = values.get(name, self.situations.values.get(name))
            if v is None:
                raise LanguageError(
                    f"{what} does not set the action {name!r} and the situations give no start value to hold"
                )
            v = torch.as_tensor(v).to(self.dtype)
            if v.ndim == 2:
                v = v.unsqueeze(1).expand(v.shape[0], t, v.shape[-1])
            if tuple(v.shape) != (n, t, d):
                raise LanguageError(
                    f"{what}: action {name!r} has shape {tuple(v.shape)}, expected ({n}, {t}, {d}) or ({n}, {d})"
                )
            cols.append(v)
        return torch.cat(cols, -1)

    def require_model(self, what: str) -> WorldModel:
        """The model, or a LanguageError saying ``what`` needs one."""
        if self.model is None:
            raise LanguageError(f"{what} infers actions with the world model; pass model=")
        return self.model


def _term_text(name: str, constants: Sequence[Constant]) -> str:
    return f"{name}({', '.join(c.name for c in constants)})"


def _roles(
    actions: Callable[[tuple[Constant, ...]], tuple[str, ...]] | Sequence[str],
) -> Callable[..., tuple[str, ...]]:
    return actions if callable(actions) else (lambda constants: tuple(actions))


def fixed_action_term(
    name: str,
    sorts: tuple[str, ...],
    actions: Callable[[tuple[Constant, ...]], tuple[str, ...]] | Sequence[str],
    fn: Callable[[CompileContext, tuple[Constant, ...]], Values],
    *,
    aims: Callable[[tuple[Constant, ...]], tuple[str, ...]] = lambda constants: (),
    doc: str = "",
) -> ActionTermDef:
    """An action term whose plan is ``fn(context, constants)``: action -> ``(N, T, d)`` or ``(N, d)``.

    Args:
        name: as in :class:`ActionTermDef`.
        sorts: as in :class:`ActionTermDef`.
        actions: the action variables it sets (names, or constants -> names).
        fn: the sequence from the start values (``context.situations.values``).
        aims: as in :class:`ActionTermDef`.
        doc: as in :class:`ActionTermDef`.
    """
    acts = _roles(actions)

    def compile_(context: CompileContext, constants: tuple[Constant, ...]) -> Tensor:
        what = f"do({_term_text(name, constants)})"
        values = fn(context, constants)
        extra = sorted(set(values) - set(acts(constants)))
        if extra:
            raise LanguageError(f"{what} returned values for {extra}, which it does not declare in actions")
        context.evaluations[_term_text(name, constants)] = 0.0
        return context.assemble(values, what)

    return ActionTermDef(name, tuple(sorts), acts, aims, compile_, doc)


def model_state(model: WorldModel, situations: Situations, optimised: Sequence[str]) -> dict[str, Tensor]:
    """The roots a rollout from the situations needs.

    Lag-1 slots (from their ``lag_of`` start value), given lag-0 non-action roots, and the
    given actions that are not optimised.
    """
    graph, out = model.graph, {}
    for r in graph.roots:
        var = graph[r]
        if var.lag == 1:
            src = var.lag_of if var.lag_of in situations.values else r
            if src not in situations.values:
                raise LanguageError(f"planning needs the start value of {var.lag_of or r!r} (for {r!r})")
            out[r] = situations.values[src].to(model.dtype)
        elif r in situations.values and r not in optimised:
            out[r] = situations.values[r].to(model.dtype)
    return out


@contextlib.contextmanager
def _counting(model: WorldModel, n: int, counter: list[float]) -> Iterator[None]:
    """Count candidate rollouts per unit: rows of every predict/rollout call on ``model`` over n."""
    originals = {k: getattr(model, k) for k in ("predict", "rollout")}

    def wrap(fn: Callable[..., Any]) -> Callable[..., Any]:
        def counted(*args: Any, **kwargs: Any) -> Any:
            out = fn(*args, **kwargs)
            first = next(iter(out.values()))
            rows = first.shape[1] if kwargs.get("members") else first.shape[0]
            counter[0] += rows / n
            return out

        return counted

    for k, fn in originals.items():
        model.__dict__[k] = wrap(fn)
    try:
        yield
    finally:
        for k in originals:
            model.__dict__.pop(k, None)


def inferred_action_term(
    name: str,
    sorts: tuple[str, ...],
    actions: Callable[[tuple[Constant, ...]], tuple[str, ...]] | Sequence[str],
    aims: Callable[[tuple[Constant, ...]], tuple[str, ...]],
    target_fn: Callable[[CompileContext, tuple[Constant, ...]], Values],
    horizon: int | None = None,
    *,
    scale: float | Mapping[str, float] = 0.05,
    sampling: SamplingConfig | None = DEFAULT_SAMPLING,
    num_steps: int = 20,
    target_at: str = "final",
    doc: str = "",
) -> ActionTermDef:
    """An action term compiled by action inference towards ``target_fn(context, constants)``.

    ``target_fn`` returns name -> ``(N, d)`` desired values of non-action variables (e.g. the
    box's start position plus an offset for the hand); ``infer_action`` minimises
    ``sum 0.5 ((x(T) - target) / scale)²`` over the plan, from the situations' start values,
    with expected residuals, for the N situations as N units.

    Args:
        name: as in :class:`ActionTermDef`.
        sorts: as in :class:`ActionTermDef`.
        actions: the action variables it optimises (others are held at their start values).
        aims: as in :class:`ActionTermDef`.
        target_fn: the targets.
        horizon: T of the plan (default the context's horizon).
        scale: preference scale (targets' units).
        sampling: as in :class:`inference.ActionOptions`.
        num_steps: as in ``infer_action``.
        target_at: as in :class:`inference.ActionOptions`.
        doc: as in :class:`ActionTermDef`.
    """
    acts = _roles(actions)

    def compile_(context: CompileContext, constants: tuple[Constant, ...]) -> Tensor:
        text = _term_text(name, constants)
        model = context.require_model(f"do({text})")
        h = context.horizon if horizon is None else horizon
        optimised = list(acts(constants))
        bad = [a for a in optimised if a not in model.graph or model.graph[a].role is not Role.ACTION]
        if bad:
            raise LanguageError(f"do({text}) optimises {bad}, which are not action variables of the model")
        targets = {k: torch.as_tensor(v).to(model.dtype) for k, v in target_fn(context, constants).items()}
        state = model_state(model, context.situations, optimised)
        seed = int(torch.randint(0, 2**31 - 1, (1,), generator=context.generator))
        counter = [0.0]
        with _counting(model, context.situations.n, counter):
            result = infer_action(
                model,
                state,
                targets,
                actions=optimised,
                num_steps=num_steps,
                options=ActionOptions(scale=scale, sampling=sampling, horizon=h, target_at=target_at),
                seed=seed,
            )
        # the thesis protocol (no sampling, H = 1) runs the Pyro program once per Adam step and once after
        context.evaluations[text] = counter[0] if counter[0] else float(num_steps + 1)
        values = {k: v if h > 1 else v.unsqueeze(1) for k, v in result.actions.items()}
        sub = CompileContext(context.model, context.situations, context.generator, h, context.layout)
        return sub.assemble(values, f"do({text})")

    return ActionTermDef(name, tuple(sorts), acts, aims, compile_, doc)
