"""The forward queries of a world model in plain torch (thesis Eq. 4.39-4.40, 4.44, Alg. 4.1).

Every non-root is ``x_i = loc_i(pa_i) + scale_i(pa_i) * eps_i`` in topological order, with
``(loc_i, scale_i)`` from :meth:`models.mechanisms.Mechanism.loc_scale`. This is the fast
twin of running the Pyro program under ``Intervene`` (given values) and ``ReplayNoise``
(residuals); the tests hold them equal.

With ``members=True`` every value carries a leading member axis K: member k of a site reads
member k of its parents (an ensemble's member k, see :mod:`models.ensemble`), and sites
without an ensemble apply their one mechanism to each member's parents. The residuals
``eps_i`` are shared by the members, so members differ only by their mechanisms. With
residuals, an ensemble's member k is the k-th component of its calibrated mixture,
``loc + c (m_k - loc) + c s_k eps`` (:meth:`models.ensemble.EnsembleMechanism.mixture_members`),
so the members' draws have the site's calibrated variance.
A discrete site is ``x_i = argmax_k (l_ik(pa_i) + g_ik)`` (Gumbel-max, :mod:`models.discrete`):
its residual is ``(N, K)`` standard Gumbel noise, expected residuals (g = 0) give the mode,
and ``"sampled"`` draws the Gumbels.

A gated site (:mod:`models.gated`) whose switch is predicted in the same call with expected
residuals (the switch not given, no Gumbel residual for it) has as its expected value the
mixture mean over the switch, ``pi f_1(pa | c = 1) + (1 - pi) f_0(pa | c = 0)`` with
``pi = P(c = 1 | pa_c)`` from the switch's mechanism, and ``predict_scale`` gives that
mixture's sd (law of total variance); the switch's own value stays its mode, so its other
children are unchanged. This keeps the expected prediction smooth in the actions through pi.
With the switch given or its residual given, the site is the branch the switch's value picks.
With ``members=True``, member k mixes with member k's pi. :class:`ForwardQueries` is a mixin
of :class:`models.WorldModel`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from models.checks import (
    as_float_tensor,
    check_bool,
    check_choice,
    check_finite_tensor,
    check_generator,
    check_int,
    describe,
)
from models.discrete import gumbel, gumbel_max
from models.driven import roll_driven
from models.ensemble import EnsembleMechanism
from models.gated import switch_p_on
from models.values import as_values, check_action_bounds
from models.variables import Role

if TYPE_CHECKING:
    from models.graph import CausalGraph
    from models.mechanisms import Mechanism

__all__ = ["SCALE_COMPONENTS", "ForwardQueries", "NoiseSpec"]

NoiseSpec = str | Mapping[str, Tensor]

#: What :meth:`ForwardQueries.predict_scale` can report.
SCALE_COMPONENTS = ("total", "aleatoric", "epistemic")


class ForwardQueries:
    """predict, predict_scale, rollout, sample and residuals of a :class:`models.WorldModel`."""

    graph: CausalGraph
    _mech_by_name: dict[str, Mechanism]
    _categories: dict[str, int]

    # provided by WorldModel: dtype, bounds(name), _parents(name, values), _priors

    # ------------------------------------------------------------------ members
    @property
    def ensemble_size(self) -> int:
        """K, the number of members of the model's ensembles (1 when it has none).

        Raises:
            ValueError: ensembles of different sizes (> 1) at different sites.
        """
        sizes = {m.size for m in self._mech_by_name.values() if m.size > 1}
        if len(sizes) > 1:
            by_site = {n: m.size for n, m in self._mech_by_name.items() if m.size > 1}
            raise ValueError(
                f"the model's ensembles have different sizes {by_site}; members=True needs one K"
            )
        return sizes.pop() if sizes else 1

    # ------------------------------------------------------------------ noise
    def _check_noise(self, noise: Any, n: int, extra_dims: Sequence[int] = (0,)) -> NoiseSpec:
        """Validate ``noise``: a known mode string or name -> residuals of non-root variables."""
        if isinstance(noise, str):
            return check_choice("noise", noise, ("expected", "sampled"))
        if not isinstance(noise, Mapping):
            raise ValueError(
                f"noise must be 'expected', 'sampled' or a mapping name -> residuals, got {describe(noise)}"
            )
        unknown = [k for k in noise if not isinstance(k, str) or k not in self.graph or self.graph.is_root(k)]
        if unknown:
            raise ValueError(
                f"noise names {unknown} are not non-root variables of the graph; non-roots: {list(self.graph.non_roots)}"
            )
        out: dict[str, Tensor] = {}
        for name, raw in noise.items():
            eps = as_float_tensor(raw, f"noise[{name!r}]", self.dtype)
            dim = self._categories.get(name, self.graph[name].dim)  # K Gumbels for a discrete site
            shapes = [(n, *([-1] * e), dim) for e in extra_dims]
            ok = any(eps.ndim == len(s) and eps.shape[0] == n and eps.shape[-1] == dim for s in shapes)
            if not ok:
                expected = " or ".join(f"({n}, {', '.join(['T'] * e + [str(dim)])})" for e in extra_dims)
                raise ValueError(f"noise[{name!r}] has shape {tuple(eps.shape)}, expected {expected}")
            check_finite_tensor(f"noise[{name!r}]", eps)
            out[name] = eps
        return out

    def _noise(
        self, name: str, noise: NoiseSpec, shape: torch.Size, generator: torch.Generator | None
    ) -> Tensor | None:
        """The residuals of one site, ``shape`` = ``(N, dim)`` (``(N, K)`` Gumbels for a discrete site); None for expected."""
        if isinstance(noise, str):
            if noise == "expected":
                return None
            if name in self._categories:
                return gumbel(shape, generator, self.dtype)
            return torch.randn(shape, generator=generator, dtype=self.dtype)
        if name not in noise:
            raise ValueError(
                f"noise mapping has no residual for {name!r}; give eps for every predicted variable"
            )
        eps = noise[name]
        if eps.shape != shape:
            raise ValueError(f"noise[{name!r}] has shape {tuple(eps.shape)}, expected {tuple(shape)}")
        return eps

    # ------------------------------------------------------------------ one step
    def _check_roots(self, values: Mapping[str, Any], what: str) -> tuple[dict[str, Tensor], int]:
        out, n = as_values(self.graph, values, what="values", dtype=self.dtype)
        missing = [r for r in self.graph.roots if r not in out]
        if missing or n is None:
            raise ValueError(f"{what} needs a value for every root; missing {missing}")
        check_action_bounds(self.graph, out, "values")
        self.check_codes(out, "values")
        return out, n

    def predict(
        self,
        values: Mapping[str, Any],
        noise: NoiseSpec = "expected",
        generator: torch.Generator | None = None,
        grad: bool = False,
        members: bool = False,
    ) -> dict[str, Tensor]:
        """The forward query Phi (Eq. 4.39, 4.44): one step of Alg. 4.1.

        Given values are kept (an assignment replaces the mechanism, as ``do`` does);
        every other variable is ``x_i = loc_i(pa_i) + scale_i(pa_i) * eps_i`` in
        topological order (``scale_i = sigma_i`` for homoscedastic mechanisms).

        Args:
            values: name -> ``(N, dim)``; must assign every root (actions and observed
                roots). Actions must lie within their bounds.
            noise: ``"expected"`` (eps = 0: a discrete site's mode, and a gated site over a
                predicted switch its mixture mean, see the module docstring), ``"sampled"``
                (eps ~ N(0, I) from ``generator``), or name -> ``(N, dim)`` standardised
                residuals, e.g. abducted ones (Eq. 4.43), for every predicted variable.
            generator: torch generator for ``"sampled"`` (None: the global torch RNG).
            grad: keep the autograd graph (for planning through the model); by default
                the outputs are plain tensors.
            members: evaluate each ensemble member: member k of a site is fed by member k
                of its parents, with the member's own scale and residuals shared by the
                members (see the module docstring).

        Returns:
            name -> ``(N, dim)`` for every variable; with ``members``, ``(K, N, dim)``
            with K = :attr:`ensemble_size` (1 for a model without ensembles; given values
            are broadcast over K).

        Raises:
            ValueError: bad values (see :func:`models.values.as_values`), a missing root, an
                action out of bounds, bad noise, or (with ``members``) ensembles of
                different sizes.
        """
        grad = check_bool("grad", grad)
        members = check_bool("members", members)
        generator = check_generator("generator", generator)
        out, n = self._check_roots(values, "predict")
        noise = self._check_noise(noise, n)
        k = self.ensemble_size if members else 0
        with torch.set_grad_enabled(grad):
            return (
                self._predict_members(out, noise, generator, k)
                if members
                else self._predict(out, noise, generator)
            )

    def _predict(
        self,
        values: Mapping[str, Tensor],
        noise: NoiseSpec,
        generator: torch.Generator | None,
        at_mode: dict[str, Tensor] | None = None,
    ) -> dict[str, Tensor]:
        """One step without a member axis; ``at_mode`` collects the logits of the discrete sites taken at their mode."""
        out = dict(values)
        at_mode = {} if at_mode is None else at_mode
        for name in self.graph.non_roots:
            if name in out:
                continue
            pa = self._parents(name, out)
            mech = self._mech_by_name[name]
            if name in self._categories:
                logits = mech.logits(pa)
                out[name] = _code(name, logits, self._noise(name, noise, logits.shape, generator), at_mode)
                continue
            if isinstance(noise, str) and noise == "expected":
                p_on = switch_p_on(mech, at_mode)
                out[name] = mech(pa) if p_on is None else mech.mixture_loc(pa, p_on)  # type: ignore[attr-defined]
                continue
            loc, scale = mech.loc_scale(pa)
            eps = self._noise(name, noise, loc.shape, generator)
            out[name] = loc + scale * eps
        return out

    def _predict_members(
        self, values: Mapping[str, Tensor], noise: NoiseSpec, generator: torch.Generator | None, k: int
    ) -> dict[str, Tensor]:
        """One step with a member axis: values ``(N, dim)`` or ``(K, N, dim)``; returns ``(K, N, dim)``.

        A single mechanism (a known law, not an ensemble) whose parents are the same for every
        member (``(N, dim)`` values, or ``(K, N, dim)`` ones equal along K) runs once on member
        0's rows and is shared: a body given by its MJCF is stepped once, not K times.
        """
        shared = {n for n, v in values.items() if v.ndim != 3 or bool((v == v[:1]).all())}
        out = {name: (v if v.ndim == 3 else v.expand(k, *v.shape)) for name, v in values.items()}
        at_mode: dict[str, Tensor] = {}
        for name in self.graph.non_roots:
            if name in out:
                continue
            pa = self._parents(name, out)  # (K, N, in)
            mech = self._mech_by_name[name]
            if name in self._categories:
                logits = mech.logits(pa)
                eps = self._noise(name, noise, logits.shape[1:], generator)
                out[name] = _code(name, logits, eps, at_mode)
                continue
            p_on = switch_p_on(mech, at_mode) if isinstance(noise, str) and noise == "expected" else None
            if p_on is not None:  # (K, N, 1): member k's pi
                out[name] = mech.member_mixture_loc(pa, p_on, paired=True)  # type: ignore[attr-defined]
                continue
            eps = self._noise(name, noise, torch.Size((*pa.shape[1:-1], mech.out_dim)), generator)
            if eps is not None and isinstance(mech, EnsembleMechanism) and mech.size > 1:
                loc, scale = mech.mixture_members(pa, paired=True)  # draws: the calibrated mixture
            elif mech.size > 1:  # an ensemble, or a gated site whose on branch is one
                loc, scale = mech.member_loc_scale(pa, paired=True)
            elif all(p in shared for p in self.graph.parents(name)):
                loc, scale = (t.expand(k, *t.shape) for t in mech.loc_scale(pa[0]))
                shared.add(name)
            else:
                loc, scale = mech.loc_scale(pa)
            out[name] = loc if eps is None else loc + scale * eps
        return out

    def predict_scale(
        self, values: Mapping[str, Any], component: str = "total", grad: bool = False
    ) -> dict[str, Tensor]:
        """Each non-root's predictive sd given its parents' values.

        For a site ``X_i ~ Normal(loc_i(pa_i), scale_i(pa_i))`` this is ``scale_i(pa_i)``:
        sigma_i for homoscedastic mechanisms, sigma_i(pa_i) for heteroscedastic ones, and
        for an ensemble the sd of the moment-matched member mixture (aleatoric and
        epistemic, :mod:`models.ensemble`). It is the one-step sd at the given parents,
        not propagated through unobserved ancestors, except for a gated site whose switch is
        not given: its sd is that of the mixture over the switch (law of total variance,
        :meth:`models.gated.GatedMechanism.mixture_scale`; the switch's uncertainty is
        aleatoric, the on branch's ensemble spread weighted by pi epistemic).

        Args:
            values: name -> ``(N, dim)``; every root must be given (actions within their
                bounds). Non-roots that are not given are filled by ``predict`` with
                expected residuals before their children's scales are computed.
            component: ``"total"``; ``"aleatoric"`` (``sqrt(mean_k s_k^2)``, the scale
                itself without ensembles) or ``"epistemic"`` (``sqrt(mean_k (m_k - loc)^2)``,
                0 without ensembles).
            grad: keep the autograd graph.

        Returns:
            name -> ``(N, dim)`` for every non-root, in the variable's units.
        """
        component = check_choice("component", component, SCALE_COMPONENTS)
        grad = check_bool("grad", grad)
        given, _ = self._check_roots(values, "predict_scale")
        with torch.set_grad_enabled(grad):
            at_mode: dict[str, Tensor] = {}
            full = self._predict(given, "expected", None, at_mode)
            out: dict[str, Tensor] = {}
            for name in self.graph.non_roots:
                pa = self._parents(name, full)
                mech = self._mech_by_name[name]
                if name in self._categories:  # the sd of the code under the site's categorical
                    sd = mech.distribution(pa).variance.clamp_min(0).sqrt()
                    out[name] = torch.zeros_like(sd) if component == "epistemic" else sd
                    continue
                p_on = switch_p_on(mech, at_mode)
                if p_on is not None:  # a gated site over its predicted switch: the mixture's sd
                    out[name] = mech.mixture_scale(pa, p_on, component)  # type: ignore[attr-defined]
                    continue
                if mech.size > 1 and component != "total":  # an ensemble, or gated over one
                    _, aleatoric, epistemic = mech.variance(pa)  # type: ignore[attr-defined]
                    out[name] = (aleatoric if component == "aleatoric" else epistemic).sqrt()
                else:
                    loc, scale = mech.loc_scale(pa)
                    out[name] = torch.zeros_like(loc) if component == "epistemic" else scale
            return out

    def sample(self, n: int, generator: torch.Generator | None = None) -> dict[str, Tensor]:
        """Draw n units from the observational distribution; name -> ``(n, dim)``.

        Roots come from their priors, the rest from ``predict(noise="sampled")``.

        Args:
            n: number of units, >= 1.
            generator: torch generator (None: the global torch RNG).
        """
        n = check_int("n", n, minimum=1)
        generator = check_generator("generator", generator)
        roots: dict[str, Tensor] = {}
        with torch.no_grad():
            for name in self.graph.roots:
                var = self.graph[name]
                if var.role is Role.ACTION:
                    low, high = self.bounds(name)
                    u = torch.rand(n, var.dim, generator=generator, dtype=self.dtype)
                    roots[name] = low + (high - low) * u
                elif name in self._categories:
                    logits = self._priors.logits(name).expand(n, self._categories[name])
                    roots[name] = gumbel_max(logits, gumbel(logits.shape, generator, self.dtype))
                else:
                    loc, scale = self._priors.get(name)
                    roots[name] = loc + scale * torch.randn(n, var.dim, generator=generator, dtype=self.dtype)
            return self._predict(roots, "sampled", generator)

    def residuals(self, values: Mapping[str, Any]) -> dict[str, Tensor]:
        """Standardised residuals eps_i = (x_i - loc_i(pa_i)) / scale_i(pa_i) (Eq. 4.43).

        Args:
            values: name -> ``(N, dim)`` for every variable of the graph.

        Returns:
            name -> ``(N, dim)`` for every non-root variable.
        """
        vals, _ = as_values(self.graph, values, what="values", dtype=self.dtype)
        missing = [v for v in self.graph.names if v not in vals]
        if missing:
            raise ValueError(f"residuals need every variable; missing {missing}")
        discrete = [v for v in self.graph.non_roots if v in self._categories]
        if discrete:
            raise ValueError(
                f"residuals are not determined for the discrete sites {discrete}: their Gumbel noise has a "
                "posterior given the values; draw it with inference.abduct"
            )
        out = {}
        for name in self.graph.non_roots:
            loc, scale = self._mech_by_name[name].loc_scale(self._parents(name, vals))
            out[name] = (vals[name] - loc) / scale
        return out

    # ------------------------------------------------------------------ rollout
    def rollout(
        self,
        initial: Mapping[str, Any],
        inputs: Mapping[str, Any],
        noise: NoiseSpec = "expected",
        generator: torch.Generator | None = None,
        grad: bool = False,
        members: bool = False,
        assign: Mapping[str, Any] | None = None,
        driven: bool = True,
    ) -> dict[str, Tensor]:
        """Mental simulation over h' steps (Alg. 4.1, Eq. 4.40).

        At step tau the lag-1 slots take the previous step's values of their ``lag_of``
        variables (``initial`` at tau = 0); the per-step ``inputs`` (actions and any other
        lag-0 roots) are assigned; the rest is ``x_i = loc_i(pa_i) + scale_i(pa_i) * eps_i``.

        Args:
            initial: name -> ``(N, dim)`` for every lag-1 root.
            inputs: name -> ``(N, H, dim)`` for every lag-0 root, e.g. the action sequence
                (within the action bounds).
            noise: ``"expected"``, ``"sampled"``, or name -> residuals of shape
                ``(N, dim)`` (reused at every step, the thesis's abduction scheme) or
                ``(N, H, dim)`` (one per step).
            generator: torch generator for ``"sampled"``.
            grad: keep the autograd graph.
            members: roll each ensemble member forward on its own trajectory (member k's
                state feeds member k's next step; see :meth:`predict`).
            assign: name -> ``(N, H, dim)`` values of non-root variables set at every step,
                ``do(x_tau = assign[x][:, tau])`` (e.g. a body's recorded motion, so that only
                the rest is simulated); their lagged slots carry the assigned values on.
            driven: roll the sites that the inputs alone determine (a body given by its MJCF)
                over the whole horizon before the step loop (:mod:`models.driven`; the same
                values); False: every site in the step loop.

        Returns:
            name -> ``(N, H, dim)``: the simulated trajectory T^sim; with ``members``,
            ``(K, N, H, dim)``.
        """
        grad, members = check_bool("grad", grad), check_bool("members", members)
        driven_first = check_bool("driven", driven)
        generator = check_generator("generator", generator)
        seq, init, n, horizon = self._rollout_inputs(initial, inputs)
        fixed = self._rollout_assign(assign, n, horizon)
        noise = self._check_noise(noise, n, extra_dims=(0, 1))
        if isinstance(noise, Mapping):
            for key, e in noise.items():
                if e.ndim == 3 and e.shape[1] != horizon:
                    raise ValueError(
                        f"noise[{key!r}] has {e.shape[1]} steps, expected {horizon} like the inputs"
                    )
        lagged = self.graph.lagged
        lag1_roots = [r for r in self.graph.roots if self.graph[r].lag == 1]
        k = self.ensemble_size if members else 0
        state = dict(init)
        steps: list[dict[str, Tensor]] = []
        with torch.set_grad_enabled(grad):
            if driven_first:
                known = {**seq, **fixed}
                fixed |= roll_driven(
                    self.graph, self._mech_by_name, set(self._categories), self._parents, known, init, noise
                )
            for tau in range(horizon):
                values = {**state, **{key: v[:, tau] for key, v in {**seq, **fixed}.items()}}
                step_noise: NoiseSpec = noise
                if isinstance(noise, Mapping):
                    step_noise = {key: (e[:, tau] if e.ndim == 3 else e) for key, e in noise.items()}
                if members:
                    pred = self._predict_members(values, step_noise, generator, k)
                else:
                    pred = self._predict(values, step_noise, generator)
                steps.append(pred)
                state = {r: pred[lagged[r]] for r in lag1_roots if r in lagged}
            axis = 2 if members else 1
            return {key: torch.stack([s[key] for s in steps], axis) for key in self.graph.names}

    def _rollout_inputs(
        self, initial: Mapping[str, Any], inputs: Mapping[str, Any]
    ) -> tuple[dict[str, Tensor], dict[str, Tensor], int, int]:
        """Check the rollout's inputs and initial values: ``(inputs, initial, N, H)``."""
        seq, n = as_values(self.graph, inputs, what="inputs", extra_dims=1, dtype=self.dtype)
        init, n = as_values(self.graph, initial, n=n, what="initial", dtype=self.dtype)
        lagged = self.graph.lagged
        lag1_roots = [r for r in self.graph.roots if self.graph[r].lag == 1]
        lag0_roots = [r for r in self.graph.roots if self.graph[r].lag == 0]
        missing = [r for r in lag1_roots if r not in init] + [r for r in lag0_roots if r not in seq]
        if missing:
            raise ValueError(
                f"rollout needs initial values of lag-1 roots and inputs of lag-0 roots; missing {missing}"
            )
        extra = [k for k in init if k not in lag1_roots] + [k for k in seq if k not in lag0_roots]
        if extra:
            raise ValueError(f"rollout got values for {extra}, which are not roots of the right lag")
        if n is None:
            raise ValueError("rollout needs inputs; the graph has no lag-0 root to drive it")
        horizons = {v.shape[1] for v in seq.values()}
        if len(horizons) != 1:
            raise ValueError(f"inputs have different horizons {sorted(horizons)}")
        (horizon,) = horizons
        for r in lag1_roots:
            if r not in lagged and horizon > 1:
                raise ValueError(f"lag-1 root {r!r} has no lag_of variable, so it cannot be rolled forward")
        check_action_bounds(self.graph, seq, "inputs")
        self.check_codes({**seq, **init}, "inputs")
        return seq, init, n, horizon

    def _rollout_assign(self, assign: Mapping[str, Any] | None, n: int, horizon: int) -> dict[str, Tensor]:
        """Check a rollout's assigned non-root values ``(N, H, dim)``."""
        if assign is None:
            return {}
        fixed, _ = as_values(self.graph, assign, n=n, what="assign", extra_dims=1, dtype=self.dtype)
        roots = [k for k in fixed if self.graph.is_root(k)]
        if roots:
            raise ValueError(f"assign sets roots {roots}; give roots as initial values or inputs")
        for key, v in fixed.items():
            if v.shape[0] != n or v.shape[1] != horizon:
                raise ValueError(
                    f"assign[{key!r}] has shape {tuple(v.shape)}, expected ({n}, {horizon}, dim) like the inputs"
                )
        self.check_codes(fixed, "assign")
        return fixed


def _code(name: str, logits: Tensor, eps: Tensor | None, at_mode: dict[str, Tensor]) -> Tensor:
    """A discrete site's code ``(..., 1)``: Gumbel-max with ``eps``, or (eps None) the mode, whose logits go to ``at_mode``."""
    if eps is not None:
        return gumbel_max(logits, eps)
    at_mode[name] = logits
    return logits.argmax(-1, keepdim=True).to(logits.dtype)
