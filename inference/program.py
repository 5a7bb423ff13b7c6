"""Programs: a world model under a stack of handlers that keeps the model's graph.

``do(model, ...)`` and every pal handler applied to a model (``Intervene(...)(model)``,
``MeasurementScale(...)(do(model, ...))``) return a :class:`Program`. A program has the call
signature of :class:`models.WorldModel` (``program(data, n)``), its ``graph`` and its
``world`` (the model underneath), so every query accepts it in place of the model, and the
queries also run under handlers entered with ``with``. Which sites are observed, latent,
intervened or discrete is read from a trace of the program actually run
(:func:`read_sites`), not from the graph: under ``do(x := v)`` the site ``x`` is a
``Delta``, so it is neither latent nor evidence.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from typing import Any

import pyro
import torch
from pyro import poutine
from pyro.poutine.messenger import Messenger
from pyro.poutine.subsample_messenger import _Subsample
from torch import Tensor

from inference.active import active_handlers
from models.checks import describe
from models.discrete import CategoricalCode
from models.graph import CausalGraph
from models.world import WorldModel

__all__ = [
    "Program",
    "SiteRoles",
    "as_program",
    "check_active_handlers",
    "log_joint",
    "read_sites",
    "same_graph",
]


class Program:
    """A :class:`models.WorldModel` run under handlers (innermost first), with its graph.

    ``Program(model, (h1, h2))(data, n)`` runs ``h2(h1(model))(data, n)``.

    Args:
        model: the world model underneath.
        handlers: Pyro messengers, innermost first.

    Attributes:
        world: the model.
        graph: the model's :class:`models.CausalGraph`.
        handlers: the messengers, innermost first.
    """

    def __init__(self, model: WorldModel, handlers: Sequence[Messenger] = ()) -> None:
        if not isinstance(model, WorldModel):
            raise ValueError(f"a Program wraps a WorldModel, got {describe(model)}")
        self.world = model
        self.handlers = tuple(handlers)

    @property
    def graph(self) -> CausalGraph:
        """The causal graph of the model underneath."""
        return self.world.graph

    @property
    def dtype(self) -> torch.dtype:
        """The model's floating dtype."""
        return self.world.dtype

    def with_handler(self, messenger: Messenger) -> Program:
        """This program under one more (outermost) handler."""
        return Program(self.world, (*self.handlers, messenger))

    def __call__(
        self, data: Mapping[str, Any] | None = None, n: int | None = None
    ) -> dict[str, torch.Tensor]:
        """Run the program: the model's ``forward(data, n)`` inside the handlers."""
        with ExitStack() as stack:
            for handler in reversed(self.handlers):
                stack.enter_context(handler)
            return self.world(data, n)

    def __repr__(self) -> str:
        inner = " <- ".join(type(h).__name__ for h in reversed(self.handlers)) or "no handlers"
        return f"Program({inner} <- {self.graph!r})"


def as_program(model: Any, what: str = "model") -> Program:
    """``model`` as a :class:`Program` (a WorldModel gets an empty handler stack).

    Raises:
        ValueError: anything else, naming what it got.
    """
    if isinstance(model, Program):
        return model
    if isinstance(model, WorldModel):
        return Program(model)
    raise ValueError(
        f"{what} must be a WorldModel or a program made from one (do(model, ...), or a pal handler "
        f"applied to it, e.g. MeasurementScale(...)(model)), got {describe(model)}"
    )


def same_graph(graph: CausalGraph, other: CausalGraph, what: str) -> None:
    """Refuse to compose two things made for different graphs.

    Raises:
        ValueError: naming ``what``, both graphs and the variables and edges that differ.
    """
    if graph == other:
        return
    names, other_names = set(graph.names), set(other.names)
    edges, other_edges = set(graph.edges), set(other.edges)
    raise ValueError(
        f"{what} was made for another graph ({other.fingerprint()[:12]}) than the program "
        f"({graph.fingerprint()[:12]}): variables only in the program {sorted(names - other_names)}, only in "
        f"{what} {sorted(other_names - names)}; edges only in the program {sorted(edges - other_edges)}, "
        f"only in {what} {sorted(other_edges - edges)}. Use results of the same model"
    )


def check_active_handlers(graph: CausalGraph) -> None:
    """Refuse pal handlers entered with ``with`` that name sites the graph does not have.

    Raises:
        ValueError: naming the handler and the unknown sites.
    """
    for frame in active_handlers():
        names = getattr(frame, "site_names", None)
        if callable(names):
            unknown = sorted(n for n in names() if n not in graph)
            if unknown:
                raise ValueError(
                    f"an active {type(frame).__name__} handler names {unknown}, which are not sites of the "
                    f"program; its sites: {list(graph.names)}"
                )


@dataclass(frozen=True)
class SiteRoles:
    """The variable sites of one run of a program, in the order they ran.

    Attributes:
        observed: sites given as evidence (``obs=``), not intervened on.
        intervened: sites fixed by ``do`` or replayed (``Delta``).
        latent: sites sampled from their distribution.
        discrete: name -> K for the latent sites that are discrete.
        dims: name -> trailing dim of every site.
    """

    observed: tuple[str, ...]
    intervened: tuple[str, ...]
    latent: tuple[str, ...]
    discrete: dict[str, int]
    dims: dict[str, int]

    @property
    def continuous(self) -> tuple[str, ...]:
        """Latent sites that are not discrete."""
        return tuple(n for n in self.latent if n not in self.discrete)


def _base(fn: Any) -> Any:
    while isinstance(fn, torch.distributions.Independent):
        fn = fn.base_dist
    return fn


def read_sites(program: Callable[..., Any], data: Mapping[str, Any], n: int) -> SiteRoles:
    """Run ``program(data, n)`` once in a trace and sort its sites (see :class:`SiteRoles`).

    Latent sites are sampled with torch's global RNG inside a forked context, so the
    caller's RNG stream (e.g. the SVI steps that follow) is the same as without this trace.
    """
    with torch.no_grad(), pyro.validation_enabled(False), torch.random.fork_rng():
        trace = poutine.trace(program).get_trace(data, n)
    observed, intervened, latent, discrete, dims = [], [], [], {}, {}
    for name, site in trace.nodes.items():
        if site["type"] != "sample" or isinstance(site["fn"], _Subsample):
            continue
        dims[name] = int(site["value"].shape[-1])
        infer = site.get("infer") or {}
        if infer.get("pal_intervened") or infer.get("pal_replayed"):
            intervened.append(name)
        elif site["is_observed"]:
            observed.append(name)
        else:
            latent.append(name)
            base = _base(site["fn"])
            if isinstance(base, CategoricalCode):
                discrete[name] = base.categories
    return SiteRoles(tuple(observed), tuple(intervened), tuple(latent), discrete, dims)


def log_joint(trace: Any, skip: Collection[str] = ()) -> Tensor | float:
    """Sum of the log-densities of the variable sites of ``trace``: ``(..., N)``, or 0.0 without any.

    Intervened and replayed sites (``Delta``), the sites in ``skip`` and the latent vectors
    that joint autoguides replay into the model (``_Auto...``) are left out.
    """
    total: Tensor | float = 0.0
    for name, site in trace.nodes.items():
        if site["type"] != "sample" or name in skip or isinstance(site["fn"], _Subsample):
            continue
        if name.startswith("_Auto"):
            continue
        infer = site.get("infer") or {}
        if infer.get("pal_intervened") or infer.get("pal_replayed"):
            continue
        total = total + site["fn"].log_prob(site["value"])
    return total
