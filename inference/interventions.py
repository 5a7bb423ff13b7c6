"""The do-operator (thesis §1.3.2, Eq. 4.48) as a handler around a Pyro program.

``do(model, {"x": 0.0})`` returns a callable with the model's signature in which the
mechanism of ``x`` is replaced by the assignment ``x := 0``. Values may be scalars (for
dim-1 variables), ``(dim,)`` vectors applied to every unit, ``(N, dim)`` batched tensors,
or callables ``g(x) -> x'`` of the pre-intervention value (shift interventions such as
``lambda x: x + 0.1``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import pyro
import torch
from torch import Tensor

from inference.handlers import Intervene, InterventionSpec
from models.graph import CausalGraph

__all__ = ["check_interventions", "do"]


def check_interventions(
    graph: CausalGraph | None, interventions: Mapping[str, Any]
) -> dict[str, InterventionSpec]:
    """Validate intervention names against ``graph`` and values for NaN/inf.

    Returns a dict with array values converted to tensors; callables are kept.
    """
    if not isinstance(interventions, Mapping):
        raise ValueError(f"interventions must be a mapping name -> value, got {type(interventions).__name__}")
    out: dict[str, InterventionSpec] = {}
    for name, spec in interventions.items():
        if graph is not None:
            graph.check_name(name, what="intervention target")
        if callable(spec) and not isinstance(spec, torch.Tensor):
            out[name] = spec
            continue
        try:
            t = torch.as_tensor(spec, dtype=torch.get_default_dtype())
        except (TypeError, ValueError, RuntimeError) as err:
            raise ValueError(f"intervention on {name!r} is not numeric: {spec!r} ({err})") from None
        if not torch.isfinite(t).all():
            raise ValueError(f"intervention on {name!r} contains NaN or inf")
        if graph is not None:
            dim = graph[name].dim
            if t.ndim > 2 or (t.ndim == 0 and dim != 1) or (t.ndim >= 1 and t.shape[-1] != dim):
                raise ValueError(
                    f"intervention on {name!r} has shape {tuple(t.shape)}, expected a scalar (dim 1), "
                    f"({dim},) or (N, {dim})"
                )
        out[name] = t
    return out


def do(model: Callable[..., Any], interventions: Mapping[str, InterventionSpec]) -> Callable[..., Any]:
    """Intervene on a Pyro program.

    Args:
        model: a Pyro program, e.g. a :class:`models.WorldModel`.
        interventions: site name -> hard value, batched tensor, or shift callable.

    Returns:
        The intervened program (same call signature). If ``model`` has a ``graph``,
        unknown names and wrong dims raise here rather than at run time.
    """
    specs = check_interventions(getattr(model, "graph", None), interventions)
    return Intervene(specs)(model)


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
        n: number of units.
        interventions: as for :func:`do`; None samples the observational distribution.
        seed: seeds Pyro inside an isolated RNG context.

    Returns:
        name -> ``(n, dim)`` tensors without autograd history.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be a positive int, got {n!r}")
    program = do(model, interventions) if interventions else model
    with torch.random.fork_rng(), torch.no_grad():
        pyro.set_rng_seed(seed)
        return program(None, n)
