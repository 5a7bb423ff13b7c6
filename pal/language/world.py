"""Worlds that queries are answered in: start situations, outcomes, and the world model's world.

A world plays K action plans from N start situations, S samples each, and returns the paths of
its variables. In the model world (:class:`ModelWorld`) the exogenous noise is drawn once per
(situation, sample, step, site) and shared by every plan, so the K outcomes are twin worlds
(Eq. 4.43): two plans' outcomes differ only through the plans. A simulator world restores each
start state and steps the simulator (S = 1); it implements the same :class:`World` protocol.

Shapes: start values ``(N, d)``; plans ``(N, T, A)`` with ``A`` the concatenated action
variables of the graph in ``graph.actions`` order; paths ``(N, S, T + 1, d)`` with index 0 the
start and index -1 the end of the plan. Units are the variables' units.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor

from models.checks import as_float_tensor, check_finite_tensor, check_generator, check_int, describe
from models.discrete import gumbel
from models.variables import Role
from models.world import WorldModel, require_world_model

__all__ = ["ModelWorld", "Outcome", "Situations", "World", "action_layout"]


@dataclass(frozen=True)
class Situations:
    """N start situations.

    Attributes:
        values: variable name (lag-0 names of the world model: ``"ee"``, ``"q"``, ``"pos.box"``,
            ...) -> ``(N, d)`` float tensor of the start values (float64 or the model dtype;
            numpy arrays are converted to float64 tensors). Finite, one N.
        states: ``(N, n_state)`` float64 simulator state vectors for replay, or None.

    Raises:
        ValueError: no values, a value that is not ``(N, d)`` floats, NaN or inf, mismatched
            N, or states of the wrong shape.
    """

    values: Mapping[str, Tensor]
    states: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.values, Mapping) or not self.values:
            raise ValueError(
                f"Situations.values must be a non-empty mapping name -> (N, d), got {describe(self.values)}"
            )
        out: dict[str, Tensor] = {}
        n = None
        for name, raw in self.values.items():
            if not isinstance(name, str):
                raise ValueError(f"Situations.values keys must be variable names, got {describe(name)}")
            dtype = raw.dtype if isinstance(raw, Tensor) and raw.is_floating_point() else torch.float64
            v = as_float_tensor(raw, f"Situations.values[{name!r}]", dtype).detach()
            if v.ndim != 2:
                raise ValueError(f"Situations.values[{name!r}] has shape {tuple(v.shape)}, expected (N, d)")
            check_finite_tensor(f"Situations.values[{name!r}]", v)
            if n is not None and v.shape[0] != n:
                raise ValueError(
                    f"Situations.values[{name!r}] has {v.shape[0]} rows, expected N = {n} like the others"
                )
            n = v.shape[0]
            out[name] = v
        if n == 0:
            raise ValueError("Situations.values have no rows; expected N >= 1 situations")
        object.__setattr__(self, "values", MappingProxyType(out))
        if self.states is not None:
            states = np.asarray(self.states)
            if states.ndim != 2 or states.shape[0] != n or states.dtype.kind != "f":
                raise ValueError(
                    f"Situations.states has shape {states.shape} and dtype {states.dtype}, expected ({n}, n_state) floats"
                )
            object.__setattr__(self, "states", states.astype(np.float64))

    @property
    def n(self) -> int:
        """N, the number of situations."""
        return next(iter(self.values.values())).shape[0]

    def select(self, index: Sequence[int] | Tensor) -> Situations:
        """The situations at ``index`` (a sequence of row numbers), values and states alike."""
        idx = torch.as_tensor(index, dtype=torch.long)
        states = None if self.states is None else self.states[idx.numpy()]
        return Situations({k: v[idx] for k, v in self.values.items()}, states)


@dataclass(frozen=True)
class Outcome:
    """What a world did under one plan.

    Attributes:
        paths: name -> ``(N, S, T + 1, d)``: index 0 is the start, -1 the end of the plan.
        unknown_start: names whose start value the situations did not give; their index 0 is
            NaN and :meth:`at` / :meth:`window` leave them out (a predicate that reads them
            then fails naming the variable).
    """

    paths: Mapping[str, Tensor]
    unknown_start: frozenset[str] = field(default_factory=frozenset)

    def __post_init__(self) -> None:
        shapes = {tuple(v.shape[:3]) for v in self.paths.values()}
        bad = [k for k, v in self.paths.items() if not isinstance(v, Tensor) or v.ndim != 4]
        if bad or len(shapes) > 1:
            got = {k: tuple(getattr(v, "shape", ())) for k, v in self.paths.items()}
            raise ValueError(f"Outcome.paths must all be (N, S, T + 1, d) with one N, S, T; got {got}")
        object.__setattr__(self, "paths", MappingProxyType(dict(self.paths)))
        object.__setattr__(self, "unknown_start", frozenset(self.unknown_start))

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(N, S, T + 1)``."""
        return tuple(next(iter(self.paths.values())).shape[:3])  # type: ignore[return-value]

    def at(self, time: str | int) -> dict[str, Tensor]:
        """Values ``(N, S, d)`` by name at ``"start"`` (index 0), ``"end"`` (index -1) or an integer step."""
        if time == "start":
            time = 0
        elif time == "end":
            time = -1
        elif isinstance(time, bool) or not isinstance(time, int):
            raise ValueError(f"time must be 'start', 'end' or a step index, got {time!r}")
        steps = self.shape[2]
        if not -steps <= time < steps:
            raise ValueError(f"step {time} is outside the outcome's {steps} times (0 .. {steps - 1})")
        at_start = time in (0, -steps)
        return {k: v[:, :, time] for k, v in self.paths.items() if not (at_start and k in self.unknown_start)}

    def window(self) -> dict[str, Tensor]:
        """The full paths name -> ``(N, S, T + 1, d)`` of the variables with a known start."""
        return {k: v for k, v in self.paths.items() if k not in self.unknown_start}


@runtime_checkable
class World(Protocol):
    """Something that plays action plans from start situations."""

    def play(
        self, situations: Situations, plans: Sequence[Tensor], samples: int, generator: torch.Generator
    ) -> list[Outcome]:
        """Play K plans, each ``(N, T_k, A)``; returns K outcomes.

        Plan k's outcome shares the exogenous noise of every other plan's (twin worlds).
        A deterministic simulator returns S = 1.
        """
        ...


def action_layout(model: WorldModel) -> tuple[tuple[str, int], ...]:
    """``(action name, dim)`` in ``graph.actions`` order: the columns of a plan's last axis."""
    return tuple((a, model.graph[a].dim) for a in model.graph.actions)


class ModelWorld:
    """The world model as a world: plans are rolled out with sampled, shared residuals (Alg. 4.1).

    Every situation is replicated S times. For each (situation, sample) the residuals
    ``eps_i(t) ~ N(0, I)`` (standard Gumbels for a discrete site) of every non-root site i and
    step t, and draws ``r(t) ~ Normal(mu_r, s_r)`` of lag-0 non-action roots the situations do not
    give, are drawn once from the generator and replayed for every plan, so

        x_i(t) = loc_i(pa_i(t)) + scale_i(pa_i(t)) * eps_i(t)

    differs between plans only through the actions. Lag-1 slots start at the situations' value
    of their ``lag_of`` variable (or of the slot itself) and then take the previous step's
    values. Lag-0 non-action roots given in the situations are held on every step.

    Situation values that are not variables of the model (e.g. the goal marker of Pusher-v5,
    sensed but not modelled, which nothing moves) may be named in ``held``: their paths are
    the start value at every time.

    Args:
        model: the world model (its parameters are not changed).
        held: names of situation values outside the model's graph, held constant.

    Raises:
        ValueError: a ``held`` name that is a variable of the graph, or not a str.
    """

    def __init__(self, model: WorldModel, held: Sequence[str] = ()) -> None:
        self.model = require_world_model(model)
        self.graph = model.graph
        if isinstance(held, str) or not all(isinstance(h, str) for h in held):
            raise ValueError(f"held must be a sequence of variable names, got {describe(held)}")
        inside = sorted(h for h in held if h in self.graph)
        if inside:
            raise ValueError(f"held names {inside}, which are variables of the model; they are rolled out")
        self.held = tuple(held)
        self.layout = action_layout(model)
        self.action_dim = sum(d for _, d in self.layout)
        #: rollout steps taken by :meth:`play` so far (one step = one pass over the mechanisms per unit batch).
        self.steps_played = 0

    def _initial(self, situations: Situations) -> dict[str, Tensor]:
        graph, out = self.graph, {}
        for r in (r for r in graph.roots if graph[r].lag == 1):
            src = graph[r].lag_of
            if src is not None and src in situations.values:
                out[r] = situations.values[src]
            elif r in situations.values:
                out[r] = situations.values[r]
            else:
                raise ValueError(
                    f"the rollout starts the lag-1 slot {r!r} from the start value of {src!r}; "
                    f"Situations.values has neither (it gives {sorted(situations.values)})"
                )
        return out

    def _check(
        self, situations: Situations, plans: Sequence[Tensor], samples: int
    ) -> tuple[list[Tensor], int]:
        if not isinstance(situations, Situations):
            raise TypeError(f"situations must be Situations, got {describe(situations)}")
        unknown = sorted(k for k in situations.values if k not in self.graph and k not in self.held)
        if unknown:
            raise ValueError(
                f"Situations.values names {unknown}, which are not variables of the model graph nor "
                f"held (ModelWorld(model, held=...)); known: {list(self.graph.names)}"
            )
        samples = check_int("samples", samples, minimum=1)
        if isinstance(plans, Tensor) or not isinstance(plans, Sequence) or not plans:
            raise ValueError(
                f"plans must be a non-empty sequence of (N, T, A) tensors, got {describe(plans)}"
            )
        out = []
        n, a = situations.n, self.action_dim
        names = ", ".join(f"{k}: {d}" for k, d in self.layout)
        for k, raw in enumerate(plans):
            p = as_float_tensor(raw, f"plans[{k}]", self.model.dtype).detach()
            if p.ndim != 3 or p.shape[0] != n or p.shape[2] != a or p.shape[1] < 1:
                raise ValueError(
                    f"plans[{k}] has shape {tuple(p.shape)}, expected ({n}, T >= 1, {a}): N situations, "
                    f"T steps, the actions ({names}) concatenated in graph order"
                )
            check_finite_tensor(f"plans[{k}]", p)
            out.append(p)
        return out, samples

    def play(
        self, situations: Situations, plans: Sequence[Tensor], samples: int, generator: torch.Generator
    ) -> list[Outcome]:
        """Play K plans in twin worlds (class docstring).

        Args:
            situations: N start situations; must give the lag-0 variable of every lag-1 slot.
            plans: K tensors ``(N, T_k, A)``, actions within their bounds.
            samples: S >= 1 noise draws per situation.
            generator: the source of the exogenous noise.

        Returns:
            K :class:`Outcome`; paths of every lag-0 variable ``(N, S, T_k + 1, d)``, index 0 the
            situations' start values (NaN and listed in ``unknown_start`` when not given), and
            of every ``held`` value the situations give, constant.

        Raises:
            ValueError: bad situations, plans of the wrong shape, actions out of bounds, a
                missing start value of a lag-1 slot's variable.
        """
        generator = check_generator("generator", generator)
        if generator is None:
            raise ValueError("generator must be a torch.Generator: the exogenous noise is drawn from it")
        plans, s = self._check(situations, plans, samples)
        model, graph, n = self.model, self.graph, situations.n
        horizon = max(p.shape[1] for p in plans)
        dtype = model.dtype
        rep = lambda v: v.to(dtype).repeat_interleave(s, dim=0)  # noqa: E731  (N, d) -> (N * S, d)
        initial = {k: rep(v) for k, v in self._initial(situations).items()}
        noise: dict[str, Tensor] = {}
        for site in graph.non_roots:
            k = model.categories(site)
            if k is not None:
                noise[site] = gumbel((n * s, horizon, k), generator, dtype)
            else:
                noise[site] = torch.randn(n * s, horizon, graph[site].dim, generator=generator, dtype=dtype)
        held: dict[str, Tensor] = {}
        for r in graph.roots:
            var = graph[r]
            if var.lag != 0 or var.role is Role.ACTION:
                continue
            if r in situations.values:
                held[r] = rep(situations.values[r]).unsqueeze(1).expand(n * s, horizon, var.dim)
            else:
                loc, scale = model.root_priors.get(r)
                held[r] = loc + scale * torch.randn(n * s, horizon, var.dim, generator=generator, dtype=dtype)
        lag0 = [v for v in graph.names if graph[v].lag == 0]
        outcomes = []
        for plan in plans:
            t = plan.shape[1]
            cols = torch.split(
                plan.to(dtype).repeat_interleave(s, dim=0), [d for _, d in self.layout], dim=-1
            )
            inputs = {
                **{k: v[:, :t] for k, v in held.items()},
                **{a: c for (a, _), c in zip(self.layout, cols, strict=True)},
            }
            with torch.no_grad():
                traj = model.rollout(initial, inputs, noise={k: v[:, :t] for k, v in noise.items()})
            self.steps_played += t
            paths, unknown = {}, set()
            for v in lag0:
                start = situations.values.get(v)
                if start is None:
                    unknown.add(v)
                    first = torch.full((n * s, 1, graph[v].dim), float("nan"), dtype=dtype)
                else:
                    first = rep(start).unsqueeze(1)
                path = torch.cat([first, traj[v]], dim=1)
                paths[v] = path.reshape(n, s, t + 1, graph[v].dim)
            for v in self.held:
                if v in situations.values:
                    start = rep(situations.values[v]).reshape(n, s, 1, -1)
                    paths[v] = start.expand(n, s, t + 1, start.shape[-1])
            outcomes.append(Outcome(paths, frozenset(unknown)))
        return outcomes
