"""How a :class:`models.world.WorldModel` lays out its sites.

The default mechanism kinds (:data:`KINDS`) and the default continuous and discrete
mechanisms, which sites are discrete (name -> K categories), and how a parent enters its
children's inputs (its width: K one-hot columns for a categorical parent with K > 2, else its dim).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from models.checks import check_int, check_mapping
from models.discrete import BernoulliMechanism, CategoricalMechanism, DiscreteMechanism
from models.ensemble import EnsembleMechanism
from models.graph import CausalGraph
from models.heteroscedastic import HeteroscedasticMechanism
from models.mechanisms import LinearMechanism, Mechanism, MLPMechanism
from models.variables import Role

__all__ = ["KINDS"]

#: Default mechanism kinds of :class:`models.world.WorldModel`.
KINDS = ("mlp", "linear", "hetero")


def _default_mechanism(
    kind: str,
    in_dim: int,
    out_dim: int,
    hidden: tuple[int, ...],
    activation: str,
    members: int,
    generator: torch.Generator | None,
) -> Mechanism:
    """The default mechanism of ``kind``; an ensemble of ``members`` of them when > 1."""

    def make(gen: torch.Generator | None) -> Mechanism:
        if kind == "mlp":
            return MLPMechanism(in_dim, out_dim, hidden=hidden, activation=activation, seed=gen)
        if kind == "linear":
            return LinearMechanism(in_dim, out_dim, seed=gen)
        return HeteroscedasticMechanism(in_dim, out_dim, hidden=hidden, activation=activation, seed=gen)

    if members == 1:
        return make(generator)
    return EnsembleMechanism.replicate(make, members, generator)


def _categories(
    graph: CausalGraph, discrete: Mapping[str, int] | None, given: Mapping[str, Mechanism]
) -> dict[str, int]:
    """Name -> K of every discrete site, from ``discrete`` and the given discrete mechanisms."""
    out: dict[str, int] = {}
    for name, k in check_mapping("discrete", discrete, allow_none=True).items():
        graph.check_name(name, what="discrete site")
        out[name] = check_int(f"discrete[{name!r}] (number of categories)", k, minimum=2)
    for name, mech in given.items():
        if isinstance(mech, DiscreteMechanism):
            if name in out and out[name] != mech.categories:
                raise ValueError(
                    f"discrete[{name!r}] = {out[name]} categories, but its mechanism has {mech.categories}"
                )
            out[name] = mech.categories
        elif name in out:
            raise ValueError(
                f"{name!r} is listed in discrete but its mechanism is a continuous {type(mech).__name__}; "
                "give a BernoulliMechanism or CategoricalMechanism, or leave it to the default"
            )
    for name in out:
        var = graph[name]
        if var.role is Role.ACTION:
            raise ValueError(f"{name!r} is an action; actions are continuous boxes and cannot be discrete")
        if var.dim != 1:
            raise ValueError(
                f"discrete site {name!r} has dim {var.dim}; a discrete variable holds one code (dim 1)"
            )
    return {n: out[n] for n in graph.names if n in out}


def _width(graph: CausalGraph, categories: Mapping[str, int], name: str) -> int:
    k = categories.get(name, 0)
    return k if k > 2 else graph[name].dim


def _one_hot(value: Tensor, k: int) -> Tensor:
    """``(..., 1)`` codes -> ``(..., k)`` one-hot rows of the same dtype."""
    return torch.nn.functional.one_hot(value[..., 0].long().clamp(0, k - 1), k).to(value.dtype)


def _default_discrete(
    kind: str,
    in_dim: int,
    k: int,
    hidden: tuple[int, ...],
    activation: str,
    generator: torch.Generator | None,
) -> DiscreteMechanism:
    """Logistic / softmax regression for ``kind="linear"``, an MLP of ``hidden`` otherwise."""
    widths = () if kind == "linear" else hidden
    if k == 2:
        return BernoulliMechanism(in_dim, hidden=widths, activation=activation, seed=generator)
    return CategoricalMechanism(in_dim, k, hidden=widths, activation=activation, seed=generator)
