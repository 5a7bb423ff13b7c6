"""The do-operator (thesis §1.3.2, Eq. 4.48) as a handler around a Pyro program.

``do(model, {"x": 0.0})`` returns a callable with the model's signature in which the
mechanism of ``x`` is replaced by the assignment ``x := 0``. Values may be scalars (for
dim-1 variables), ``(dim,)`` vectors applied to every unit, ``(N, dim)`` batched tensors,
or callables ``g(x) -> x'`` of the pre-intervention value (shift interventions such as
``lambda x: x + 0.1``). Values on action sites must lie within the action bounds, and
values on discrete sites must be category codes ``0 .. K-1``.

Applied to a :class:`models.WorldModel` or a :class:`inference.program.Program`, ``do`` returns
a ``Program`` that keeps the model's graph, so ``infer_state(do(m, {...}), obs)``,
``counterfactual(do(m, {...}), ...)`` and ``do(do(m, a), b)`` work.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from inference.handlers import Intervene, InterventionSpec
from inference.program import Program
from models.checks import as_float_tensor, check_callable, check_int, check_mapping, check_seed, describe
from models.discrete import check_codes
from models.graph import CausalGraph
from models.variables import Role
from models.world import WorldModel, check_action_bounds, model_dtype

__all__ = ["action_bounds", "check_interventions", "do", "simulate"]


def check_interventions(
    graph: CausalGraph | None,
    interventions: Mapping[str, Any],
    dtype: torch.dtype | None = None,
    categories: Mapping[str, int] | None = None,
) -> dict[str, InterventionSpec]:
    """Validate intervention names against ``graph`` and values for dtype, shape, NaN/inf and bounds.

    Args:
        graph: the program's graph, or None for a program without one (names unchecked).
        interventions: name -> scalar, ``(dim,)``, ``(N, dim)`` or callable.
        dtype: floating dtype of the values (default: torch's default dtype).
        categories: name -> K of the discrete sites, whose values must be codes ``0 .. K-1``.

    Returns:
        A dict with array values converted to tensors of ``dtype``; callables are kept.

    Raises:
        ValueError: not a mapping, unknown names, non-numeric, integer or bool values,
            wrong shapes, NaN or inf, or action values outside the bounds.
    """
    interventions = check_mapping("interventions", interventions)
    out: dict[str, InterventionSpec] = {}
    for name, spec in interventions.items():
        if graph is not None:
            graph.check_name(name, what="intervention target")
        elif not isinstance(name, str):
            raise ValueError(f"intervention targets must be site names (str), got {describe(name)}")
        if callable(spec) and not isinstance(spec, Tensor):
            out[name] = spec
            continue
        t = as_float_tensor(spec, f"intervention on {name!r}", dtype)
        if not torch.isfinite(t).all():
            raise ValueError(f"intervention on {name!r} contains NaN or inf: {describe(t)}")
        if graph is not None:
            dim = graph[name].dim
            if t.ndim > 2 or (t.ndim == 0 and dim != 1) or (t.ndim >= 1 and t.shape[-1] != dim):
                raise ValueError(
                    f"intervention on {name!r} has shape {tuple(t.shape)}, expected a scalar (dim 1), "
                    f"({dim},) or (N, {dim})"
                )
            if t.ndim == 2 and t.shape[0] == 0:
                raise ValueError(f"intervention on {name!r} has shape {tuple(t.shape)}: no rows")
            check_action_bounds(graph, {name: t}, "interventions")
        if categories and name in categories:
            check_codes(f"intervention on {name!r}", t, categories[name])
        out[name] = t
    return out


def action_bounds(graph: CausalGraph | None, names: Any) -> dict[str, tuple[Tensor, Tensor]]:
    """``(low, high)`` tensors of the action sites among ``names`` (for :class:`Intervene`)."""
    if graph is None:
        return {}
    return {
        k: (torch.tensor(graph[k].low), torch.tensor(graph[k].high))
        for k in names
        if graph[k].role is Role.ACTION
    }


def do(model: Callable[..., Any], interventions: Mapping[str, InterventionSpec]) -> Callable[..., Any]:
    """Intervene on a Pyro program: ``do(X := v)`` or ``do(X := g(x))``.

    Args:
        model: a Pyro program, e.g. a :class:`models.WorldModel`.
        interventions: site name -> hard value (scalar, ``(dim,)`` or ``(N, dim)``) or
            shift callable. Action values must lie within the action bounds.

    Returns:
        The intervened program (same call signature): a :class:`inference.program.Program`
        with the model's ``graph`` for a WorldModel or Program. Unknown names, wrong dims,
        out-of-bounds actions and invalid category codes raise here rather than at run
        time (for callables, at run time).
    """
    check_callable("model", model)
    graph = getattr(model, "graph", None)
    world = model.world if isinstance(model, Program) else model
    categories = world.discrete if isinstance(world, WorldModel) else None
    dtype = world.dtype if isinstance(world, WorldModel) else model_dtype(model)
    specs = check_interventions(graph, interventions, dtype, categories)
    return Intervene(specs, bounds=action_bounds(graph, specs))(model)


def simulate(
    model: Callable[..., Any],
    n: int,
    interventions: Mapping[str, InterventionSpec] | None = None,
    *,
    seed: int = 0,
) -> dict[str, Tensor]:
    """Draw n units from p(V) or, with interventions, from p(V | do(...)).

    Args:
        model: the program.
        n: number of units, >= 1.
        interventions: as for :func:`do`; None samples the observational distribution.
        seed: seeds Pyro's sampling (torch's RNG) inside a forked RNG context; the
            caller's torch, numpy and Python RNG states are left as they were.

    Returns:
        name -> ``(n, dim)`` tensors without autograd history.
    """
    check_callable("model", model)
    n = check_int("n", n, minimum=1)
    seed = check_seed("seed", seed)
    interventions = check_mapping("interventions", interventions, allow_none=True)
    program = do(model, interventions) if interventions else model
    with torch.random.fork_rng(), torch.no_grad():
        torch.manual_seed(seed)
        return program(None, n)
