"""Gated mechanisms: a discrete (Bernoulli) parent switches a site's effect on and off.

A gated site X has a Bernoulli parent c (the switch, an ordinary discrete sample site of
:mod:`models.discrete`) among its parents pa, and two branches:

    X | c = 0  ~ Normal(f_0(pa), sigma_0)         (off: f_0 = 0 unless given; sigma_0 a floor)
    X | c = 1  ~ Normal(f_1(pa), sigma_1(pa))     (on: any continuous mechanism, e.g. an MLP,
                                                   heteroscedastic or an ensemble)

so given its parents the site is location-scale,

    loc(pa) = where(c, f_1(pa), f_0(pa)),   scale(pa) = where(c, sigma_1(pa), sigma_0),

and everything that works for location-scale sites works here: the program's Normal
site, ``predict``, ``rollout``, abduction ``u = (x - f_c(pa)) / sigma_c(pa)`` (exact per
branch when c is observed) and replay ``x' = f_c'(pa') + sigma_c'(pa') u``. When c is latent,
it is enumerated like every discrete latent site (:mod:`inference.enumeration`).

``sigma_0`` is a documented floor, e.g. the measurement floor of the child (not learned blur):
the off rows of contact-driven motion are exactly 0, and no single smooth scale fits both
them and the rare pushes. :func:`inference.fit` trains the on branch on the rows where the
switch is on only, and recalibrates its scale on the validation rows where it is on; f_0 and
sigma_0 stay as given.

Both branches read the whole encoded parent vector ``(..., in_dim)`` (the switch's 0/1 column
included, constant within a branch). The switch's column is bound by
:class:`models.WorldModel` from the graph (:func:`bind_gated`), which also checks that the
switch is a parent of the site and a Bernoulli site.

**Expected value with the switch marginalised.** When ``predict`` / ``rollout`` run with
expected residuals and the switch is predicted in the same call (not given, no Gumbel
residual), the switch's own value is its mode, but the gated site's expected value is the
mixture mean over the switch (:meth:`GatedMechanism.mixture_loc`),

    E[X | pa_c, pa] = pi f_1(pa | c = 1) + (1 - pi) f_0(pa | c = 0),   pi = P(c = 1 | pa_c),

with ``pi`` from the switch's mechanism at its parents ``pa_c``: it is smooth in everything
upstream of the switch (e.g. the actions), so a planner gets a gradient through the
probability of contact instead of a step at pi = 1/2. Its predictive sd is that of the
two-component mixture (law of total variance, :meth:`GatedMechanism.mixture_scale`):

    Var = pi (sigma_1^2 + f_1^2) + (1 - pi) (sigma_0^2 + f_0^2) - E[X]^2
        = pi sigma_1^2 + (1 - pi) sigma_0^2 + pi (1 - pi) (f_1 - f_0)^2,

where ``sigma_1^2`` of an ensemble on branch is its aleatoric plus epistemic variance. Of the
components, the switch's uncertainty counts as aleatoric (``pi sigma_1,ale^2 + (1 - pi)
sigma_0^2 + pi (1 - pi) (f_1 - f_0)^2``) and the on branch's ensemble spread, weighted by pi,
as epistemic (``pi sigma_1,epi^2``). With the switch given, or its residual given, the site is
the exact branch of the previous paragraphs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from models.checks import as_float_tensor, check_int, describe
from models.mechanisms import Mechanism, Seed, make_mechanism

__all__ = ["DEFAULT_FLOOR", "GatedMechanism", "bind_gated", "switch_p_on"]

#: A default off-branch floor sigma_0, in the child's units (1e-4: a tenth of a millimetre).
DEFAULT_FLOOR = 1e-4


def _floor(value: Any, out_dim: int) -> Tensor:
    """``(out_dim,)`` floors > 0 and finite (a scalar fills all)."""
    t = as_float_tensor(value, "floor").detach()
    if t.ndim == 0:
        t = t.expand(out_dim)
    if t.ndim != 1 or t.numel() != out_dim:
        raise ValueError(f"floor has shape {tuple(t.shape)}, expected () or ({out_dim},)")
    if not bool(torch.isfinite(t).all()) or not bool((t > 0).all()):
        raise ValueError(
            f"floor (the off-branch sd sigma_0) must be finite and > 0, got {t.tolist()}; "
            "give the measurement floor of the child, e.g. 1e-4"
        )
    return t.clone()


def _check_branch(what: str, mech: Any) -> Mechanism:
    from models.discrete import DiscreteMechanism  # local: discrete imports mechanisms only

    if not isinstance(mech, Mechanism):
        raise ValueError(f"the {what} branch of a gated site must be a Mechanism, got {describe(mech)}")
    if isinstance(mech, (DiscreteMechanism, GatedMechanism)):
        raise ValueError(
            f"the {what} branch of a gated site must be a continuous mechanism, got a {type(mech).__name__}"
        )
    return mech


class GatedMechanism(Mechanism):
    """A site whose effect a Bernoulli parent ``switch`` turns on (see the module docstring).

    Args:
        switch: name of the switch parent, a Bernoulli (K = 2) discrete site.
        on: the on branch ``(f_1, sigma_1)``: a continuous mechanism (MLP, linear,
            heteroscedastic, ensemble) over the site's encoded parents.
        floor: the off branch's sd sigma_0 > 0 in the child's units, a scalar or ``(out_dim,)``.
        off: the off branch's mean f_0 (its own scale is not used); None for f_0 = 0.
        switch_index: the switch's column in the encoded parents; :class:`models.WorldModel`
            binds it from the graph, so it is only needed for a mechanism used on its own.

    Shapes:
        ``loc_scale``: ``(..., in_dim) -> ((..., out_dim), (..., out_dim))``.

    Raises:
        ValueError: a bad switch name, a branch that is not a continuous mechanism, branches
            of different dims, a floor <= 0 or NaN, or a bad ``switch_index``.
    """

    kind = "gated"
    serialisable = True
    config_keys = frozenset({"switch", "on", "off", "floor"})

    def __init__(
        self,
        switch: str,
        on: Mechanism,
        floor: Any = DEFAULT_FLOOR,
        off: Mechanism | None = None,
        *,
        switch_index: int | None = None,
    ) -> None:
        if not isinstance(switch, str) or not switch:
            raise ValueError(
                f"switch must be the name of the site's Bernoulli parent, got {describe(switch)}"
            )
        on = _check_branch("on", on)
        if off is not None:
            off = _check_branch("off", off)
            if (off.in_dim, off.out_dim) != (on.in_dim, on.out_dim):
                raise ValueError(
                    f"the off branch maps {off.in_dim} -> {off.out_dim}, the on branch {on.in_dim} -> "
                    f"{on.out_dim}; both read the site's parents"
                )
        super().__init__(on.in_dim, on.out_dim, sigma=None)
        self.switch = switch
        self.on = on
        self.off = off
        dtype = next(t.dtype for t in (*on.parameters(), *on.buffers()) if t.is_floating_point())
        self.register_buffer("floor", _floor(floor, self.out_dim).to(dtype))
        self.switch_index = -1
        self.site = "a gated site"
        if switch_index is not None:
            self.switch_index = check_int("switch_index", switch_index, minimum=0, maximum=self.in_dim - 1)

    def bind(self, site: str, switch_index: int) -> None:
        """Name the site and the switch's column in its encoded parents (done by the WorldModel)."""
        self.switch_index = check_int("switch_index", switch_index, minimum=0, maximum=self.in_dim - 1)
        self.site = f"gated site {site!r}"

    # ------------------------------------------------------------------ properties
    @property
    def heteroscedastic(self) -> bool:
        """True: the scale depends on the switch."""
        return True

    @property
    def size(self) -> int:
        """K, the on branch's number of members (1 unless it is an ensemble)."""
        return self.on.size

    @property
    def trainable(self) -> bool:
        """True when the on branch is trainable."""
        return self.on.trainable

    # ------------------------------------------------------------------ evaluation
    def check_input(self, parents: Any) -> Tensor:
        """``parents`` as a floating tensor of the on branch's dtype, last dim ``in_dim``."""
        return self.on.check_input(parents)

    def switch_on(self, parents: Tensor) -> Tensor:
        """``(...,)`` bool: the switch's value in the encoded parents is 1.

        Raises:
            ValueError: the mechanism is not bound to its switch's column, or a switch value
                is not 0 or 1 (naming the site, the switch and the value).
        """
        if self.switch_index < 0:
            raise ValueError(
                f"the gated mechanism's switch {self.switch!r} is not bound to a parent column; "
                "use it in a WorldModel or give switch_index"
            )
        c = parents[..., self.switch_index]
        bad = (c != 0) & (c != 1)
        if bool(bad.any()):
            first = float(c[bad][0])
            raise ValueError(
                f"{self.site}: switch {self.switch!r} has {int(bad.sum())} values that are not 0 or 1 "
                f"(first: {first:g}); a Bernoulli switch takes the codes 0 and 1"
            )
        return c == 1

    def loc_scale(self, parents: Tensor) -> tuple[Tensor, Tensor]:
        """``(where(c, f_1, f_0), where(c, sigma_1, sigma_0))``, each ``(..., out_dim)``."""
        parents = self.check_input(parents)
        c = self.switch_on(parents).unsqueeze(-1)
        loc1, scale1 = self.on.loc_scale(parents)
        loc0 = self.off(parents) if self.off is not None else torch.zeros_like(loc1)
        return torch.where(c, loc1, loc0), torch.where(c, scale1, self.floor.expand_as(scale1))

    def member_loc_scale(self, parents: Tensor, paired: bool = False) -> tuple[Tensor, Tensor]:
        """Per member of the on branch ``(where(c, m_k, f_0), where(c, s_k, sigma_0))``, each ``(K, ..., out_dim)``.

        Args:
            parents: ``(..., in_dim)`` shared by the members, or with ``paired``
                ``(K, ..., in_dim)`` where member k reads ``parents[k]``.
            paired: see ``parents``.
        """
        parents = self.check_input(parents)
        c = self.switch_on(parents).unsqueeze(-1)
        locs, scales = self.on.member_loc_scale(parents, paired)
        loc0 = self.off(parents) if self.off is not None else torch.zeros_like(locs)
        return torch.where(c, locs, loc0), torch.where(c, scales, self.floor.expand_as(scales))

    def variance(self, parents: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(loc, aleatoric, epistemic)`` of the site, each ``(..., out_dim)``.

        The on branch's (:meth:`models.ensemble.EnsembleMechanism.variance` for an ensemble)
        where the switch is on, ``(f_0, sigma_0^2, 0)`` where it is off.
        """
        parents = self.check_input(parents)
        c = self.switch_on(parents).unsqueeze(-1)
        loc1, ale1, epi1 = self._on_moments(parents)
        loc0 = self.off(parents) if self.off is not None else torch.zeros_like(loc1)
        floor2 = self.floor.pow(2).expand_as(ale1)
        return (
            torch.where(c, loc1, loc0),
            torch.where(c, ale1, floor2),
            torch.where(c, epi1, torch.zeros_like(epi1)),
        )

    # ------------------------------------------------------------------ the switch marginalised
    def at_switch(self, parents: Tensor, value: float) -> Tensor:
        """``parents`` with the switch's column set to ``value`` (0 or 1): ``(..., in_dim)``.

        Raises:
            ValueError: the mechanism is not bound to its switch's column.
        """
        if self.switch_index < 0:
            raise ValueError(
                f"the gated mechanism's switch {self.switch!r} is not bound to a parent column; "
                "use it in a WorldModel or give switch_index"
            )
        out = parents.clone()
        out[..., self.switch_index] = value
        return out

    def _check_p_on(self, p_on: Any, parents: Tensor) -> Tensor:
        """``p_on`` as a ``(..., 1)`` tensor in [0, 1] broadcastable against ``parents[..., :1]``."""
        p = as_float_tensor(p_on, "p_on", parents.dtype)
        if p.ndim == 0 or p.shape[-1] != 1:
            raise ValueError(f"{self.site}: p_on has shape {tuple(p.shape)}, expected (..., 1)")
        try:
            torch.broadcast_shapes(p.shape, (*parents.shape[:-1], 1))
        except RuntimeError as err:
            raise ValueError(
                f"{self.site}: p_on has shape {tuple(p.shape)}, which does not broadcast against the "
                f"parents' rows {tuple(parents.shape[:-1])}"
            ) from err
        ok = (p >= 0) & (p <= 1)
        if not bool(ok.all()):
            raise ValueError(
                f"{self.site}: p_on = P({self.switch} = 1) must lie in [0, 1], got {float(p[~ok][0]):g}"
            )
        return p

    def _branch_locs(self, parents: Tensor, members: bool, paired: bool) -> tuple[Tensor, Tensor]:
        """``(f_1(pa | c = 1), f_0(pa | c = 0))``; ``f_1`` per member ``(K, ..., out_dim)`` with ``members``."""
        on_pa = self.at_switch(parents, 1.0)
        loc1 = self.on.member_loc_scale(on_pa, paired)[0] if members else self.on(on_pa)
        if self.off is None:
            return loc1, torch.zeros_like(loc1)
        return loc1, self.off(self.at_switch(parents, 0.0))

    def mixture_loc(self, parents: Tensor, p_on: Any) -> Tensor:
        """``E[X] = pi f_1(pa | c = 1) + (1 - pi) f_0(pa | c = 0)`` (module docstring), ``(..., out_dim)``.

        Args:
            parents: ``(..., in_dim)`` encoded parents; the switch's column is ignored.
            p_on: ``(..., 1)`` pi = P(c = 1) in [0, 1], broadcast against the parents' rows.

        Raises:
            ValueError: bad parents, or ``p_on`` of a bad shape or outside [0, 1].
        """
        parents = self.check_input(parents)
        p = self._check_p_on(p_on, parents)
        loc1, loc0 = self._branch_locs(parents, members=False, paired=False)
        return loc0 + p * (loc1 - loc0)

    def member_mixture_loc(self, parents: Tensor, p_on: Any, paired: bool = False) -> Tensor:
        """Per member of the on branch ``pi_k m_k(pa | c = 1) + (1 - pi_k) f_0(pa | c = 0)``, ``(K, ..., out_dim)``.

        Args:
            parents: ``(..., in_dim)`` shared by the members, or with ``paired``
                ``(K, ..., in_dim)`` where member k reads ``parents[k]``.
            p_on: ``(..., 1)`` shared, or with ``paired`` ``(K, ..., 1)`` per member.
            paired: see ``parents``.
        """
        parents = self.check_input(parents)
        p = self._check_p_on(p_on, parents)
        locs, loc0 = self._branch_locs(parents, members=True, paired=paired)
        return loc0 + p * (locs - loc0)

    def mixture_variance(self, parents: Tensor, p_on: Any) -> tuple[Tensor, Tensor, Tensor]:
        """``(E[X], aleatoric, epistemic)`` variances of the switch mixture (module docstring), each ``(..., out_dim)``.

        ``aleatoric = pi s_ale^2 + (1 - pi) sigma_0^2 + pi (1 - pi) (f_1 - f_0)^2`` and
        ``epistemic = pi s_epi^2`` with ``(f_1, s_ale^2, s_epi^2)`` the on branch's at
        ``c = 1`` (``s_epi = 0`` unless it is an ensemble); their sum is the law of total variance.
        """
        parents = self.check_input(parents)
        p = self._check_p_on(p_on, parents)
        loc1, ale1, epi1 = self._on_moments(self.at_switch(parents, 1.0))
        loc0 = self.off(self.at_switch(parents, 0.0)) if self.off is not None else torch.zeros_like(loc1)
        gap = loc1 - loc0
        aleatoric = p * ale1 + (1 - p) * self.floor.pow(2) + p * (1 - p) * gap.pow(2)
        return loc0 + p * gap, aleatoric, p * epi1

    def mixture_scale(self, parents: Tensor, p_on: Any, component: str = "total") -> Tensor:
        """The mixture's sd, ``(..., out_dim)``: ``"total"``, ``"aleatoric"`` or ``"epistemic"`` (:meth:`mixture_variance`).

        A component that is 0 gives 0 with a zero gradient (no NaN from the square root).
        """
        _, aleatoric, epistemic = self.mixture_variance(parents, p_on)
        var = {"total": aleatoric + epistemic, "aleatoric": aleatoric, "epistemic": epistemic}.get(component)
        if var is None:
            raise ValueError(f"component must be 'total', 'aleatoric' or 'epistemic', got {component!r}")
        pos = var > 0
        return torch.where(pos, var.clamp_min(torch.finfo(var.dtype).tiny).sqrt(), torch.zeros_like(var))

    def _on_moments(self, parents: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The on branch's ``(loc, aleatoric, epistemic)`` at ``parents`` (epistemic 0 unless an ensemble)."""
        if hasattr(self.on, "variance"):
            return self.on.variance(parents)  # type: ignore[no-any-return]
        loc1, scale1 = self.on.loc_scale(parents)
        return loc1, scale1.pow(2), torch.zeros_like(scale1)

    def forward(self, parents: Tensor) -> Tensor:
        """The site's loc ``where(c, f_1(pa), f_0(pa))``: ``(..., in_dim) -> (..., out_dim)``."""
        parents = self.check_input(parents)
        c = self.switch_on(parents).unsqueeze(-1)
        loc1 = self.on(parents)
        loc0 = self.off(parents) if self.off is not None else torch.zeros_like(loc1)
        return torch.where(c, loc1, loc0)

    def core(self, z: Tensor) -> Tensor:
        """Not used: a gated site has no normalisers of its own (its branches have theirs)."""
        raise ValueError("a GatedMechanism has no core of its own; call it on the parents")

    def penalty(self) -> Tensor:
        """The on branch's penalty (the off branch is not trained)."""
        return self.on.penalty()

    def set_normalization(self, in_loc: Any, in_scale: Any, out_loc: Any, out_scale: Any) -> None:
        """Set the on branch's normalisers (:func:`inference.fit` passes the on rows' statistics)."""
        self.on.set_normalization(in_loc, in_scale, out_loc, out_scale)

    def input_weights(self) -> tuple[str, ...]:
        """The branches' input weights, prefixed ``on.`` / ``off.``; empty if a branch has none."""
        on = tuple(f"on.{k}" for k in self.on.input_weights())
        if self.off is None or not on:
            return on
        off = tuple(f"off.{k}" for k in self.off.input_weights())
        return on + off if off else ()

    # ------------------------------------------------------------------ persistence
    def config(self) -> dict[str, Any]:
        """``{"kind": "gated", "switch", "floor", "on": config, "off": config or None}``."""
        return {
            "kind": self.kind,
            "switch": self.switch,
            "floor": [float(f) for f in self.floor],
            "on": self.on.config(),
            "off": None if self.off is None else self.off.config(),
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> GatedMechanism:
        """Rebuild from :meth:`config` output (without ``kind``).

        Raises:
            ValueError: ``on`` missing or not a mechanism config (a gated site without its on
                branch), ``floor`` missing, or a bad entry.
        """
        on = config.get("on")
        if not isinstance(on, Mapping):
            raise ValueError(
                f"gated mechanism config of switch {config.get('switch')!r} lacks its on branch: "
                f"'on' must be a mechanism config, got {describe(on)}"
            )
        if "floor" not in config:
            raise ValueError(f"gated mechanism config of switch {config.get('switch')!r} lacks its floor")
        off = config.get("off")
        return cls(
            config.get("switch"),  # type: ignore[arg-type]
            make_mechanism(on, seed=seed),
            floor=config["floor"],
            off=None if off is None else make_mechanism(off, seed=seed),
        )


def bind_gated(
    site: str,
    mech: GatedMechanism,
    parents: Sequence[str],
    widths: Mapping[str, int],
    categories: Mapping[str, int],
) -> None:
    """Check a gated site's switch against the graph and bind its column.

    Args:
        site: the gated site's name.
        mech: its mechanism.
        parents: the site's parents in the graph, in order.
        widths: parent -> columns it takes in the encoded parents.
        categories: name -> K of the model's discrete sites.

    Raises:
        ValueError: the switch is not a parent of the site, or not a Bernoulli (K = 2) site.
    """
    switch = mech.switch
    if switch not in parents:
        raise ValueError(
            f"gated site {site!r} has switch {switch!r}, which is not among its parents {list(parents)}; "
            "add the edge switch -> site or name another parent"
        )
    k = categories.get(switch)
    if k != 2:
        what = "continuous" if k is None else f"categorical with {k} categories"
        raise ValueError(
            f"gated site {site!r} has switch {switch!r}, which is {what}; the switch must be a Bernoulli "
            f"site (discrete={{{switch!r}: 2}} or a BernoulliMechanism)"
        )
    if sum(widths[p] for p in parents) != mech.in_dim:
        return  # the WorldModel refuses the mechanism's dims
    index = 0
    for p in parents:
        if p == switch:
            break
        index += widths[p]
    mech.bind(site, index)


def switch_p_on(mech: Mechanism, at_mode: Mapping[str, Tensor]) -> Tensor | None:
    """The switch probability pi = P(c = 1 | pa_c), ``(..., 1)``, of a gated site, or None.

    None unless ``mech`` is gated and its switch is in ``at_mode``.

    Args:
        mech: a site's mechanism.
        at_mode: the logits ``(..., 2)`` of the discrete sites that a forward query predicted
            at their mode in the same call (expected residuals, not given).
    """
    if isinstance(mech, GatedMechanism) and mech.switch in at_mode:
        return at_mode[mech.switch].softmax(-1)[..., 1:]
    return None
