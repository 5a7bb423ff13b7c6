"""Ensemble members evaluated in one batched pass: stacked weights and batched matmul.

K members of one kind (:class:`models.MLPMechanism` or :class:`models.HeteroscedasticMechanism`
with the same widths and activation) have their weights stacked layer by layer,
``W_l: (K, in, out)``, ``b_l: (K, 1, out)``, and member k's rows go through

    z     = (pa_k - in_loc_k) / in_scale_k
    h_l   = act(h_{l-1} @ W_l[k] + b_l[k])                       all k at once (torch.baddbmm)
    loc_k = out_loc_k + out_scale_k * m_k,   scale_k = sigma_k  or  out_scale_k * exp(s_k)

with the heteroscedastic loc and log-scale heads fused into one matmul and the log-scale soft
clamped as in :mod:`models.heteroscedastic`. The result equals each member's own
:meth:`~models.mechanisms.Mechanism.loc_scale` up to float rounding: one batched call replaces K
Python calls of K small networks, which is what a planner pays for at every rollout step.

The stacked weights are a snapshot. :func:`stacked_members` takes it for every ensemble of a
model for the duration of a ``with`` block in which the parameters stay fixed (action
inference runs its search in one, with the parameters frozen), and
:meth:`models.ensemble.EnsembleMechanism.member_loc_scale` uses it there.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import torch
from torch import Tensor, nn

from models.ensemble import EnsembleMechanism
from models.heteroscedastic import HeteroscedasticMechanism, soft_clamp
from models.mechanisms import ACTIVATIONS, Mechanism, MLPMechanism

__all__ = ["StackedMembers", "stackable", "stacked_members"]


def stackable(members: Sequence[Mechanism]) -> bool:
    """True when the members are all MLP or all heteroscedastic mechanisms of one shape."""
    first = members[0]
    if type(first) not in (MLPMechanism, HeteroscedasticMechanism):
        return False
    shape = (type(first), first.in_dim, first.out_dim, tuple(first.hidden), first.activation)
    return all((type(m), m.in_dim, m.out_dim, tuple(m.hidden), m.activation) == shape for m in members)


def _stack(tensors: Sequence[Tensor]) -> Tensor:
    """``(K, 1, n)`` from K ``(n,)`` tensors, detached."""
    return torch.stack([t.detach() for t in tensors])[:, None, :].contiguous()


def _layers(module: nn.Module) -> list[nn.Linear]:
    return [m for m in module if isinstance(m, nn.Linear)]  # type: ignore[attr-defined]


class StackedMembers:
    """A snapshot of K members' weights, evaluated for all members in one pass (module docstring).

    Args:
        members: K >= 1 mechanisms for which :func:`stackable` holds.

    Raises:
        ValueError: members of different kinds or shapes, or of a kind that does not stack.
    """

    def __init__(self, members: Sequence[Mechanism]) -> None:
        members = list(members)
        if not members or not stackable(members):
            kinds = sorted({type(m).__name__ for m in members})
            raise ValueError(
                f"members {kinds} do not stack: give MLP or heteroscedastic mechanisms of one shape and activation"
            )
        first = members[0]
        self.k, self.in_dim, self.out_dim = len(members), first.in_dim, first.out_dim
        self.hetero = isinstance(first, HeteroscedasticMechanism)
        self.act = ACTIVATIONS[first.activation]()
        with torch.no_grad():
            self.in_loc = _stack([m.in_loc for m in members])
            self.in_scale = _stack([m.in_scale for m in members])
            self.out_loc = _stack([m.out_loc for m in members])
            self.out_scale = _stack([m.out_scale for m in members])
            if self.hetero:
                stacks = [_layers(m.trunk) for m in members]
                heads = [torch.cat([m.loc_head.weight, m.log_scale_head.weight]).T for m in members]
                head_bias = [torch.cat([m.loc_head.bias, m.log_scale_head.bias]) for m in members]
                self.low = _stack([m.scale_bounds()[0] for m in members])
                self.high = _stack([m.scale_bounds()[1] for m in members])
                self.offset = _stack([m.log_scale_offset for m in members])
            else:
                stacks = [_layers(m.net)[:-1] for m in members]
                heads = [_layers(m.net)[-1].weight.T for m in members]
                head_bias = [_layers(m.net)[-1].bias for m in members]
                self.sigma = _stack([m.sigma for m in members])
            self.hidden = [
                (
                    torch.stack([s[i].weight.detach().T for s in stacks]).contiguous(),
                    _stack([s[i].bias for s in stacks]),
                )
                for i in range(len(stacks[0]))
            ]
            self.head = (torch.stack([h.detach() for h in heads]).contiguous(), _stack(head_bias))

    def loc_scale(self, parents: Tensor) -> tuple[Tensor, Tensor]:
        """Member k's ``(loc, scale)`` at ``parents[k]``: ``(K, ..., in_dim) -> 2 x (K, ..., out_dim)``.

        Raises:
            ValueError: parents whose leading dim is not K or last dim not ``in_dim``.
        """
        if parents.ndim < 2 or parents.shape[0] != self.k or parents.shape[-1] != self.in_dim:
            raise ValueError(
                f"stacked parents have shape {tuple(parents.shape)}, expected ({self.k}, ..., {self.in_dim})"
            )
        lead = parents.shape[1:-1]
        h = ((parents.reshape(self.k, -1, self.in_dim) - self.in_loc) / self.in_scale).to(self.in_loc.dtype)
        for weight, bias in self.hidden:
            h = self.act(torch.baddbmm(bias, h, weight))
        out = torch.baddbmm(self.head[1], h, self.head[0])
        if self.hetero:
            m, s = out.split(self.out_dim, dim=-1)
            loc = self.out_loc + self.out_scale * m
            scale = self.out_scale * (soft_clamp(s, self.low, self.high) + self.offset).exp()
        else:
            loc = self.out_loc + self.out_scale * out
            scale = self.sigma.expand_as(loc)
        return loc.reshape(self.k, *lead, self.out_dim), scale.reshape(self.k, *lead, self.out_dim)


@contextmanager
def stacked_members(module: nn.Module) -> Iterator[nn.Module]:
    """Within the block, every stackable ensemble of ``module`` evaluates its members in one pass.

    The stacked weights are taken on entry: the parameters must not change inside the block
    (e.g. action inference with the parameters frozen). Ensembles whose members do not stack,
    and everything outside the block, keep the member-by-member path. Nested blocks restore the
    outer snapshot on exit.
    """
    saved: list[tuple[EnsembleMechanism, StackedMembers | None]] = []
    for m in module.modules():
        if isinstance(m, EnsembleMechanism) and m.size > 1 and stackable(list(m.members)):
            saved.append((m, m.stacked))
            m.stacked = StackedMembers(list(m.members))
    try:
        yield module
    finally:
        for m, previous in saved:
            m.stacked = previous
