"""The priors of the non-action roots of a :class:`models.world.WorldModel`.

``R_k ~ Normal(mu_k, s_k)`` for a continuous root, ``Categorical(softmax(logits))`` for a
discrete one: the buffers (:class:`_RootPriors`) and the setters that
:func:`inference.fit` uses (:class:`RootPriorSetters`, a mixin of the WorldModel).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor, nn

from models.checks import as_float_tensor
from models.graph import CausalGraph
from models.values import module_key
from models.variables import Role

__all__ = ["RootPriorSetters"]


class _RootPriors(nn.Module):
    """Buffers mu_k, s_k of the Normal priors of non-action roots; logits of discrete roots."""

    def __init__(self, graph: CausalGraph, categories: Mapping[str, int]) -> None:
        super().__init__()
        for name in graph.roots:
            var = graph[name]
            if var.role is Role.ACTION:
                continue
            if name in categories:
                self.register_buffer(f"{module_key(name)}_logits", torch.zeros(categories[name]))
                continue
            self.register_buffer(f"{module_key(name)}_loc", torch.zeros(var.dim))
            self.register_buffer(f"{module_key(name)}_scale", torch.ones(var.dim))

    def logits(self, name: str) -> Tensor:
        """``(K,)`` prior logits of the discrete root ``name``."""
        return getattr(self, f"{module_key(name)}_logits")

    def get(self, name: str) -> tuple[Tensor, Tensor]:
        """``(mu_k, s_k)`` of root ``name``, each ``(dim,)``, in the variable's units."""
        return getattr(self, f"{module_key(name)}_loc"), getattr(self, f"{module_key(name)}_scale")


class RootPriorSetters:
    """set_root_prior and set_root_probs of a :class:`models.world.WorldModel`."""

    graph: CausalGraph
    _priors: _RootPriors
    _categories: dict[str, int]

    # provided by WorldModel: dtype

    def set_root_probs(self, name: str, probs: Any) -> None:
        """Set the categorical prior of a discrete root: ``(K,)`` probabilities > 0 (renormalised)."""
        k = self._categories.get(name)
        if k is None or not self.graph.is_root(name):
            raise ValueError(f"{name!r} is not a discrete root; only those have category probabilities")
        p = as_float_tensor(probs, f"root probabilities of {name!r}", self.dtype).detach().reshape(-1)
        if p.numel() != k or not bool(torch.isfinite(p).all()) or not bool((p > 0).all()):
            raise ValueError(
                f"root probabilities of {name!r} must be {k} finite values > 0, got {p.tolist()}"
            )
        self._priors.logits(name).copy_((p / p.sum()).log())

    def set_root_prior(self, name: str, loc: Any, scale: Any) -> None:
        """Set the prior ``R ~ Normal(loc, scale)`` of a non-action root (:func:`inference.fit` does this from data).

        Args:
            name: a non-action root.
            loc: prior mean, a scalar or ``(dim,)`` in the variable's units; finite.
            scale: prior sd, a scalar or ``(dim,)`` in the variable's units; finite, > 0.
        """
        var = self.graph[name]
        if not self.graph.is_root(name) or var.role is Role.ACTION:
            raise ValueError(f"{name!r} is not a non-action root; only those have a Normal prior")
        if name in self._categories:
            raise ValueError(
                f"{name!r} is a discrete root; set its category probabilities with set_root_probs"
            )
        loc_t, scale_t = (
            as_float_tensor(v, f"root prior {what} of {name!r}", self.dtype).detach().reshape(-1)
            for v, what in ((loc, "loc"), (scale, "scale"))
        )
        if loc_t.numel() == 1:
            loc_t = loc_t.expand(var.dim)
        if scale_t.numel() == 1:
            scale_t = scale_t.expand(var.dim)
        if loc_t.numel() != var.dim or scale_t.numel() != var.dim:
            raise ValueError(
                f"root prior of {name!r} needs {var.dim} loc and scale entries, got "
                f"{loc_t.numel()} and {scale_t.numel()}"
            )
        if not (torch.isfinite(loc_t).all() and (scale_t > 0).all() and torch.isfinite(scale_t).all()):
            raise ValueError(
                f"root prior of {name!r} needs finite loc and positive finite scale, got "
                f"{loc_t.tolist()}, {scale_t.tolist()}"
            )
        cur_loc, cur_scale = self._priors.get(name)
        cur_loc.copy_(loc_t)
        cur_scale.copy_(scale_t)
