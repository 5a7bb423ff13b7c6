"""Ensembles of K mechanisms at one site: aleatoric and epistemic uncertainty.

Member k is a mechanism ``X = m_k(pa) + s_k(pa) * eps`` (homoscedastic or heteroscedastic).
The site is **the moment-matched Normal of the equally weighted member mixture**:

    loc(pa)     = (1/K) sum_k m_k(pa)
    scale(pa)^2 = c^2 (1/K) sum_k s_k(pa)^2              (aleatoric)
                + c^2 (1/K) sum_k (m_k(pa) - loc(pa))^2  (epistemic: the members' disagreement)

with ``c`` = 1 until :func:`inference.fit` recalibrates the site on validation rows
(:meth:`EnsembleMechanism.recalibrate`). So ``X ~ Normal(loc(pa), scale(pa))`` stays an ordinary location-scale Pyro site: its
log-density, ``do``, abduction ``u = (x - loc(pa)) / scale(pa)`` and replay
``x' = loc(pa') + scale(pa') * u`` are exact for that Normal, with no member index to
infer. The members themselves are exposed by :meth:`EnsembleMechanism.member_loc_scale`
and by ``WorldModel.predict(..., members=True)`` (member k of a site fed by member k of
its parents, as PETS propagates particles). Draws with residuals (``noise`` not
``"expected"``) come from the components of the calibrated mixture,
``loc + c (m_k - loc) + c s_k eps`` (:meth:`EnsembleMechanism.mixture_members`), whose
mixture has the site's variance. With K = 1 the site is the member's own.

:func:`inference.fit` trains each member on its own bootstrap of the training rows.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from models.checks import check_int, describe
from models.heteroscedastic import shift_log_scale
from models.mechanisms import Mechanism, Seed, as_generator, make_mechanism

__all__ = ["EnsembleMechanism", "member_seeds"]


def member_seeds(seed: Seed, k: int) -> list[torch.Generator | None]:
    """K independent seed streams derived from ``seed`` (None: K times the global RNG).

    Each stream is a fresh generator seeded with a number drawn from ``seed``'s generator,
    so member k's weights do not depend on how many draws the others make.
    """
    k = check_int("members", k, minimum=1)
    generator = as_generator(seed)
    if generator is None:
        return [None] * k
    seeds = torch.randint(0, 2**62, (k,), generator=generator)
    return [torch.Generator().manual_seed(int(s)) for s in seeds]


class EnsembleMechanism(Mechanism):
    """K mechanisms of one kind at one site; the site is their moment-matched Normal.

    See the module docstring for the site distribution and the abduction rule. An ensemble
    holds no normalisers or sigma of its own: each member has its own.

    Args:
        members: K >= 1 mechanisms of the same kind and the same ``in_dim`` and ``out_dim``
            (not ensembles themselves).

    Raises:
        ValueError: no members, a member that is not a Mechanism or is an ensemble, or
            members of different kinds or dims.
    """

    kind = "ensemble"
    serialisable = True
    config_keys = frozenset({"members"})

    def __init__(self, members: Sequence[Mechanism]) -> None:
        nn.Module.__init__(self)
        if isinstance(members, (str, bytes, Mechanism)) or not isinstance(members, Sequence):
            raise ValueError(f"members must be a list of Mechanism, got {describe(members)}")
        members = list(members)
        if len(members) < 1:
            raise ValueError("an ensemble needs at least 1 member (ensemble size must be >= 1), got 0")
        for k, m in enumerate(members):
            if not isinstance(m, Mechanism):
                raise ValueError(f"ensemble member {k} must be a Mechanism, got {describe(m)}")
            if isinstance(m, EnsembleMechanism):
                raise ValueError(f"ensemble member {k} is itself an ensemble; give its members instead")
        kinds = sorted({type(m).__name__ for m in members})
        if len(kinds) > 1:
            raise ValueError(f"ensemble members must be of one kind, got {kinds}")
        dims = sorted({(m.in_dim, m.out_dim) for m in members})
        if len(dims) > 1:
            raise ValueError(f"ensemble members must share in_dim and out_dim, got (in, out) {dims}")
        self.in_dim, self.out_dim = dims[0]
        self.members = nn.ModuleList(members)
        self.register_parameter("log_sigma", None)
        self.register_buffer("log_scale_offset", torch.zeros(self.out_dim, dtype=members[0].out_loc.dtype))
        #: A snapshot of the members' stacked weights (:func:`models.stacked.stacked_members`), or None.
        self.stacked: Any = None

    @classmethod
    def replicate(
        cls, make: Callable[[torch.Generator | None], Mechanism], k: int, seed: Seed = None
    ) -> EnsembleMechanism:
        """An ensemble of ``k`` members ``make(generator_m)``, one seed stream each (:func:`member_seeds`).

        Raises:
            ValueError: ``k`` < 1 (the ensemble size).
        """
        return cls([make(g) for g in member_seeds(seed, k)])

    # ------------------------------------------------------------------ properties
    @property
    def size(self) -> int:
        """Number of members K."""
        return len(self.members)

    @property
    def heteroscedastic(self) -> bool:
        """True unless K = 1 and the member is homoscedastic (disagreement depends on pa)."""
        return self.size > 1 or self.members[0].heteroscedastic

    @property
    def trainable(self) -> bool:
        """True when the members are trainable."""
        return self.members[0].trainable

    @property
    def sigma(self) -> Tensor:
        """The member's sigma when K = 1.

        Raises:
            ValueError: K > 1 (the scale depends on the parents) or a heteroscedastic member.
        """
        if self.size == 1:
            return self.members[0].sigma
        raise ValueError(
            f"an ensemble of {self.size} members has a scale that depends on the parents (member "
            "disagreement); use loc_scale(parents) (or WorldModel.predict_scale) instead of sigma"
        )

    def set_sigma(self, sigma: Any) -> None:
        """Set the member's sigma when K = 1; refused for K > 1 (set each member's)."""
        if self.size == 1:
            self.members[0].set_sigma(sigma)
            return
        raise ValueError(f"an ensemble of {self.size} members has no single sigma; set members[k].set_sigma")

    # ------------------------------------------------------------------ evaluation
    def check_input(self, parents: Any) -> Tensor:
        """``parents`` as a floating tensor of the members' dtype, last dim ``in_dim``."""
        return self.members[0].check_input(parents)

    def member_loc_scale(self, parents: Tensor, paired: bool = False) -> tuple[Tensor, Tensor]:
        """Each member's ``(m_k(pa), s_k(pa))``, stacked to ``(K, ..., out_dim)``.

        Args:
            parents: ``(..., in_dim)`` shared by the members, or with ``paired``
                ``(K, ..., in_dim)`` where member k reads ``parents[k]``.
            paired: see ``parents``.

        Raises:
            ValueError: paired parents whose leading dim is not K.
        """
        parents = self.check_input(parents)
        if paired:
            if parents.ndim < 2 or parents.shape[0] != self.size:
                raise ValueError(
                    f"paired parents have shape {tuple(parents.shape)}, expected ({self.size}, ..., {self.in_dim})"
                )
            if self.stacked is not None:  # one batched pass (models.stacked)
                return self.stacked.loc_scale(parents)  # type: ignore[no-any-return]
            pairs = [m.loc_scale(parents[k]) for k, m in enumerate(self.members)]
        elif self.stacked is not None:
            return self.stacked.loc_scale(parents.expand(self.size, *parents.shape))  # type: ignore[no-any-return]
        else:
            pairs = [m.loc_scale(parents) for m in self.members]
        return torch.stack([p[0] for p in pairs]), torch.stack([p[1] for p in pairs])

    def mixture_members(self, parents: Tensor, paired: bool = False) -> tuple[Tensor, Tensor]:
        """The components of the site's calibrated mixture, ``(K, ..., out_dim)`` each.

        Component k is ``(loc + c (m_k - loc), c s_k)``, ``loc`` the member mean and ``c`` the
        site's recalibration factor, so the equally weighted mixture has the site's mean and
        variance, ``c^2 (mean_k s_k^2 + mean_k (m_k - loc)^2)``. The raw members (c = 1) are
        calibrated one by one, so their mixture counts each member's own error twice, in its
        scale and in the members' spread, and over-covers. With ``paired`` parents, member k's
        component is centred on the member mean at ``parents[k]`` (K member passes over all K
        parents, unless these are all equal). Arguments as :meth:`member_loc_scale`.
        """
        locs, scales = self.member_loc_scale(parents, paired)
        c = self.log_scale_offset.exp().to(locs.dtype)
        if self.size == 1 or bool((c == 1).all()):
            return locs, scales
        parents = self.check_input(parents)
        if paired and not bool((parents == parents[:1]).all()):
            flat = parents.reshape(-1, self.in_dim)
            center = self.member_loc_scale(flat)[0].mean(0).reshape(locs.shape)
        else:
            center = locs.mean(0, keepdim=True)
        return center + c * (locs - center), c * scales

    def forward(self, parents: Tensor) -> Tensor:
        """The site's loc, the member mean: ``(..., in_dim) -> (..., out_dim)``."""
        if self.size == 1:
            return self.members[0](parents)
        parents = self.check_input(parents)
        if self.stacked is not None:
            return self.member_loc_scale(parents)[0].mean(0)
        return torch.stack([m(parents) for m in self.members]).mean(0)

    def loc_scale(self, parents: Tensor) -> tuple[Tensor, Tensor]:
        """The moment-matched ``(loc(pa), scale(pa))``, each ``(..., out_dim)`` (see the module docstring)."""
        if self.size == 1:
            return self.members[0].loc_scale(parents)
        loc, aleatoric, epistemic = self.variance(parents)
        return loc, (aleatoric + epistemic).sqrt()

    def variance(self, parents: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(loc, aleatoric, epistemic)``: the mean, ``c^2 mean_k s_k^2`` and ``c^2 mean_k (m_k - loc)^2``.

        ``c`` is the ensemble's recalibration factor (1 until :meth:`recalibrate`). All
        ``(..., out_dim)``; variances in the child's units squared.
        """
        locs, scales = self.member_loc_scale(parents)
        loc = locs.mean(0)
        c2 = (2 * self.log_scale_offset).exp()
        return loc, c2 * scales.pow(2).mean(0), c2 * (locs - loc).pow(2).mean(0)

    def recalibrate(self, factor: Any) -> None:
        """Multiply the site's scale (both variance terms) by ``factor`` ``(out_dim,)`` > 0, K > 1.

        ``fit`` sets ``factor^2 = mean(z^2)`` over validation rows, ``z = (x - loc(pa)) / scale(pa)``:
        members calibrated one by one over-cover together, because the mean of K members errs
        less than each member. The members' own scales (``member_loc_scale``) are unchanged.

        Raises:
            ValueError: K = 1 (recalibrate the member), or a bad ``factor``.
        """
        if self.size == 1:
            raise ValueError("an ensemble of 1 member has the member's scale; recalibrate members[0]")
        shift_log_scale(self.log_scale_offset, factor)

    def reset_recalibration(self) -> None:
        """Set the site's recalibration factor back to 1 (the members keep theirs)."""
        with torch.no_grad():
            self.log_scale_offset.zero_()

    def penalty(self) -> Tensor:
        """The sum of the members' penalties."""
        return torch.stack([m.penalty() for m in self.members]).sum()

    def set_normalization(self, in_loc: Any, in_scale: Any, out_loc: Any, out_scale: Any) -> None:
        """Set every member's normalisers (see :meth:`Mechanism.set_normalization`)."""
        for m in self.members:
            m.set_normalization(in_loc, in_scale, out_loc, out_scale)

    # ------------------------------------------------------------------ persistence
    def config(self) -> dict[str, Any]:
        """``{"kind": "ensemble", "members": [member configs]}``."""
        return {"kind": self.kind, "members": [m.config() for m in self.members]}

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> EnsembleMechanism:
        """Rebuild from :meth:`config` output (without ``kind``); member m is seeded from ``seed``.

        Raises:
            ValueError: ``members`` missing, empty, not a list of configs, or holding an ensemble.
        """
        configs = config.get("members")
        if not isinstance(configs, list) or not configs:
            raise ValueError(
                f"ensemble config needs 'members', a non-empty list of configs, got {describe(configs)}"
            )
        for k, c in enumerate(configs):
            if isinstance(c, Mapping) and c.get("kind") == cls.kind:
                raise ValueError(
                    f"ensemble member {k} is itself an ensemble; members must be plain mechanisms"
                )
        seeds = member_seeds(seed, len(configs))
        return cls([make_mechanism(c, seed=g) for c, g in zip(configs, seeds, strict=True)])

    def input_weights(self) -> tuple[str, ...]:
        """Every member's input weights, prefixed ``members.<k>.``; empty if one member has none."""
        keys = [m.input_weights() for m in self.members]
        if not all(keys):
            return ()
        return tuple(f"members.{k}.{key}" for k, ks in enumerate(keys) for key in ks)
