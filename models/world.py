"""The world model M^wm as a Pyro program (thesis Eq. 4.27-4.31, 4.39, 4.44, Alg. 4.1).

For every variable in topological order, inside ``pyro.plate("units", N)``:

    A_j  ~ Uniform(low_j, high_j)                      (action roots)
    R_k  ~ Normal(mu_k, s_k)                           (other roots; fitted from data)
    X_i  ~ Normal(f_i(pa_i), sigma_i)                  (every non-root, Eq. 5.4)

Values passed in ``data`` enter as ``obs=``. The program contains no ``do``, no
conditioning flags: :mod:`inference` adds those with handlers. Site names are the
variable names. Values have shape ``(N, dim)``.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import pyro
import pyro.distributions as dist
import torch
from pyro.nn import PyroModule
from torch import Tensor, nn

from models.checks import (
    as_float_tensor,
    check_bool,
    check_choice,
    check_finite_tensor,
    check_generator,
    check_hidden,
    check_int,
    check_mapping,
    check_names,
    describe,
)
from models.graph import CausalGraph
from models.mechanisms import ACTIVATIONS, LinearMechanism, Mechanism, MLPMechanism, Seed, as_generator
from models.variables import Role

__all__ = [
    "BOUNDS_TOLERANCE",
    "NoiseSpec",
    "WorldModel",
    "as_values",
    "check_action_bounds",
    "model_dtype",
    "module_key",
    "require_world_model",
]

NoiseSpec = str | Mapping[str, Tensor]

#: Relative tolerance of the action-bounds check, a few float32 ulps: a value v passes
#: when ``low - tol <= v <= high + tol`` with ``tol = BOUNDS_TOLERANCE * max(1, |bound|)``.
BOUNDS_TOLERANCE = 4 * torch.finfo(torch.float32).eps


def module_key(name: str) -> str:
    """ModuleDict key for a variable name ('.' is not allowed in module names)."""
    return name.replace(".", ":")


def as_values(
    graph: CausalGraph,
    values: Mapping[str, Any] | None,
    n: int | None = None,
    what: str = "data",
    extra_dims: int = 0,
    dtype: torch.dtype | None = None,
) -> tuple[dict[str, Tensor], int | None]:
    """Validate a mapping name -> array of shape ``(N, dim)`` (plus ``extra_dims`` after N).

    Floating tensors and arrays of any precision are converted to ``dtype`` (default:
    torch's default dtype, which is the model's); Python numbers and lists are accepted;
    integer, bool, string and object data are refused (see :func:`models.checks.as_float_tensor`).

    Returns:
        Float tensors of ``dtype`` and the common N (or ``n`` when ``values`` is empty).

    Raises:
        ValueError: not a mapping, unknown names, wrong dtype, rank or dim, no rows,
            mismatched N, NaN or inf.
    """
    out: dict[str, Tensor] = {}
    values = check_mapping(what, values, allow_none=True)
    for name, raw in values.items():
        graph.check_name(name, what=f"variable in {what}")
        var = graph[name]
        t = as_float_tensor(raw, f"{what}[{name!r}]", dtype)
        expected = f"(N, {', '.join(['T'] * extra_dims + [str(var.dim)])})"
        if t.ndim != 2 + extra_dims or t.shape[-1] != var.dim:
            hint = " (reshape a 1-d column with x[:, None])" if t.ndim == 1 + extra_dims else ""
            raise ValueError(f"{what}[{name!r}] has shape {tuple(t.shape)}, expected {expected}{hint}")
        if t.shape[0] == 0 or t.numel() == 0:
            raise ValueError(f"{what}[{name!r}] has shape {tuple(t.shape)}: no rows; expected at least one")
        if n is None:
            n = t.shape[0]
        elif t.shape[0] != n:
            raise ValueError(f"{what}[{name!r}] has {t.shape[0]} rows, expected {n} like the others")
        check_finite_tensor(f"{what}[{name!r}]", t)
        out[name] = t
    return out, n


def check_action_bounds(graph: CausalGraph, values: Mapping[str, Tensor], what: str = "values") -> None:
    """Refuse action values outside their bounds (up to :data:`BOUNDS_TOLERANCE`).

    Args:
        graph: the causal graph.
        values: name -> tensor whose last dim is the variable's dim; only actions are checked.
        what: the argument name for the message.

    Raises:
        ValueError: naming the site, the first offending value and the bounds.
    """
    for name, v in values.items():
        var = graph[name]
        if var.role is not Role.ACTION or not isinstance(v, Tensor):
            continue
        low = torch.tensor(var.low, dtype=v.dtype)
        high = torch.tensor(var.high, dtype=v.dtype)
        tol_low = BOUNDS_TOLERANCE * low.abs().clamp_min(1.0)
        tol_high = BOUNDS_TOLERANCE * high.abs().clamp_min(1.0)
        vd = v.detach()
        bad = (vd < low - tol_low) | (vd > high + tol_high)
        if bool(bad.any()):
            first = tuple(int(i) for i in torch.nonzero(bad)[0]) if vd.ndim else ()
            value = float(vd[first]) if first else float(vd)
            component = first[-1] if first else 0
            raise ValueError(
                f"{what}[{name!r}] has {int(bad.sum())} entries outside the action bounds "
                f"[{var.low[component]:g}, {var.high[component]:g}] (first: {value:g} at index {first}); "
                "actions must lie within their bounds"
            )


def model_dtype(model: Any) -> torch.dtype:
    """The floating dtype of a model's tensors (torch's default dtype for other programs)."""
    if isinstance(model, WorldModel):
        return model.dtype
    return torch.get_default_dtype()


def require_world_model(model: Any, what: str = "model") -> WorldModel:
    """``model`` if it is a :class:`WorldModel`, else a ValueError naming what it is."""
    if not isinstance(model, WorldModel):
        raise ValueError(f"{what} must be a WorldModel, got {describe(model)}")
    return model


class _RootPriors(nn.Module):
    """Buffers mu_k, s_k of the Normal priors of non-action roots."""

    def __init__(self, graph: CausalGraph) -> None:
        super().__init__()
        for name in graph.roots:
            var = graph[name]
            if var.role is Role.ACTION:
                continue
            self.register_buffer(f"{module_key(name)}_loc", torch.zeros(var.dim))
            self.register_buffer(f"{module_key(name)}_scale", torch.ones(var.dim))

    def get(self, name: str) -> tuple[Tensor, Tensor]:
        """``(mu_k, s_k)`` of root ``name``, each ``(dim,)``, in the variable's units."""
        return getattr(self, f"{module_key(name)}_loc"), getattr(self, f"{module_key(name)}_scale")


class WorldModel(PyroModule):
    """A structural causal world model written as a Pyro program.

    For every variable in topological order, inside ``pyro.plate("units", N)``:
    actions ``A_j ~ Uniform(low_j, high_j)``, other roots ``R_k ~ Normal(mu_k, s_k)`` and
    non-roots ``X_i ~ Normal(f_i(pa_i), sigma_i)`` (Eq. 4.31, 5.4). Values are
    ``(N, dim)`` tensors of the model's dtype (:attr:`dtype`), in the variables' units.

    Args:
        graph: the validated causal graph.
        mechanisms: optional name -> :class:`Mechanism` for some non-roots; the others
            get a default mechanism.
        seed: int or ``torch.Generator`` for the weights of the default mechanisms, drawn
            from a local generator in topological order; None draws them from the global
            torch RNG (``WorldModel(g, seed=s)`` equals ``torch.manual_seed(s); WorldModel(g)``
            without touching the global RNG).
        kind: default mechanism class, ``"mlp"`` or ``"linear"``.
        hidden: MLP hidden widths (default 2 x 32, §5.2.1).
        activation: MLP activation (default tanh).

    Attributes:
        graph: the :class:`CausalGraph`.
        mechanisms: ``nn.ModuleDict`` of f_i, keyed by :func:`module_key`.
        root_priors: buffers ``(mu_k, s_k)`` of the non-action roots; ``root_priors.get(name)``.
        provenance: JSON-compatible record of how the model was made (seed, config,
            versions); :func:`models.io.load` restores it.

    Raises:
        ValueError: a graph that is not a :class:`CausalGraph`, mechanisms that are not a
            mapping of :class:`Mechanism`, a mechanism for a root or of the wrong dims, an
            unknown kind or activation, bad hidden widths or seed.
    """

    def __init__(
        self,
        graph: CausalGraph,
        mechanisms: Mapping[str, Mechanism] | None = None,
        *,
        seed: Seed = None,
        kind: str = "mlp",
        hidden: Sequence[int] = (32, 32),
        activation: str = "tanh",
    ) -> None:
        super().__init__()
        if not isinstance(graph, CausalGraph):
            raise ValueError(f"graph must be a CausalGraph, got {type(graph).__name__}")
        kind = check_choice("kind", kind, ("mlp", "linear"))
        hidden = check_hidden(hidden)
        activation = check_choice("activation", activation, sorted(ACTIVATIONS))
        given = dict(check_mapping("mechanisms", mechanisms, allow_none=True))
        for name in given:
            graph.check_name(name, what="mechanism target")
            if graph.is_root(name):
                raise ValueError(f"{name!r} is a root; roots have no mechanism")
        generator = as_generator(seed)
        self.graph = graph
        mods: dict[str, Mechanism] = {}
        for name in graph.non_roots:
            in_dim = sum(graph[p].dim for p in graph.parents(name))
            out_dim = graph[name].dim
            mech = given.get(name)
            if mech is None:
                mech = (
                    MLPMechanism(in_dim, out_dim, hidden=hidden, activation=activation, seed=generator)
                    if kind == "mlp"
                    else LinearMechanism(in_dim, out_dim, seed=generator)
                )
            if not isinstance(mech, Mechanism):
                raise ValueError(f"mechanism for {name!r} must be a Mechanism, got {type(mech).__name__}")
            if (mech.in_dim, mech.out_dim) != (in_dim, out_dim):
                raise ValueError(
                    f"mechanism for {name!r} maps {mech.in_dim} -> {mech.out_dim}, expected "
                    f"{in_dim} (parents {list(graph.parents(name))}) -> {out_dim}"
                )
            mods[module_key(name)] = mech
        self.mechanisms = nn.ModuleDict(mods)
        self.root_priors = _RootPriors(graph)
        # Plain references for the program. PyroModule.__getattr__ would lift every
        # parameter of a plain submodule into the Pyro param store on each access, which
        # is slow and would let SVI train the world model during state inference.
        self.__dict__["_mech_by_name"] = {n: mods[module_key(n)] for n in graph.non_roots}
        self.__dict__["_priors"] = self.root_priors
        self.__dict__["_defaults"] = {"kind": kind, "hidden": hidden, "activation": activation}
        self.provenance: dict[str, Any] = {}

    # ------------------------------------------------------------------ structure
    @property
    def dtype(self) -> torch.dtype:
        """Floating dtype of the model's parameters and buffers; inputs are converted to it."""
        for t in self.parameters():
            return t.dtype
        for t in self.buffers():
            return t.dtype
        return torch.get_default_dtype()

    def parent_dim(self, name: str) -> int:
        """Total dimension of concat(pa_i)."""
        return sum(self.graph[p].dim for p in self.graph.parents(name))

    def mechanism(self, name: str) -> Mechanism:
        """f_i of a non-root variable."""
        self.graph.check_name(name)
        mech = self._mech_by_name.get(name)
        if mech is None:
            raise ValueError(f"{name!r} is a root and has no mechanism")
        return mech

    def sigma(self, name: str) -> Tensor:
        """sigma_i, shape ``(dim,)``, in the variable's units."""
        return self.mechanism(name).sigma

    def _loc(self, name: str, values: Mapping[str, Tensor]) -> Tensor:
        parents = self.graph.parents(name)
        if len(parents) == 1:
            return self._mech_by_name[name](values[parents[0]])
        pas = [values[p] for p in parents]
        batch = torch.broadcast_shapes(*(p.shape[:-1] for p in pas))
        pa = torch.cat([p.expand(*batch, p.shape[-1]) for p in pas], -1)
        return self._mech_by_name[name](pa)

    def loc(self, name: str, values: Mapping[str, Any]) -> Tensor:
        """f_i(pa_i) from the parent values in ``values`` (name -> ``(..., dim)``); shape ``(..., dim)``.

        Raises:
            ValueError: ``name`` is a root or unknown, or a parent value is missing or not
                a floating array.
        """
        self.mechanism(name)
        values = check_mapping("values", values)
        parents = self.graph.parents(name)
        missing = [p for p in parents if p not in values]
        if missing:
            raise ValueError(f"loc of {name!r} needs values of its parents; missing {missing}")
        vals = {p: as_float_tensor(values[p], f"values[{p!r}]", self.dtype) for p in parents}
        for p, v in vals.items():
            if v.ndim == 0 or v.shape[-1] != self.graph[p].dim:
                raise ValueError(
                    f"values[{p!r}] has shape {tuple(v.shape)}, expected (..., {self.graph[p].dim})"
                )
        return self._loc(name, vals)

    def bounds(self, name: str) -> tuple[Tensor, Tensor]:
        """``(low, high)`` tensors of shape ``(dim,)``; raises if the variable has none."""
        var = self.graph[name]
        if var.bounds is None:
            raise ValueError(f"variable {name!r} has no bounds")
        return torch.tensor(var.low, dtype=self.dtype), torch.tensor(var.high, dtype=self.dtype)

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

    def copy_root_priors_from(self, other: WorldModel, names: Iterable[str] | None = None) -> tuple[str, ...]:
        """Copy the Normal priors of non-action roots from ``other``.

        Args:
            other: the model to copy from.
            names: the roots to copy; default every non-action root of this model that is
                also a non-action root of ``other`` with the same dim.

        Returns:
            The names whose prior was copied.

        Raises:
            ValueError: a named variable is not a non-action root of both models.
        """
        other = require_world_model(other, "other")
        shared = [
            r
            for r in self.graph.roots
            if self.graph[r].role is not Role.ACTION
            and r in other.graph
            and other.graph.is_root(r)
            and other.graph[r].role is not Role.ACTION
            and other.graph[r].dim == self.graph[r].dim
        ]
        if names is None:
            chosen = shared
        else:
            chosen = check_names("names", names)
            bad = [r for r in chosen if r not in shared]
            if bad:
                raise ValueError(
                    f"cannot copy root priors of {bad}: not non-action roots of the same dim in both "
                    f"models; shared: {shared}"
                )
        for r in chosen:
            loc, scale = other.root_priors.get(r)
            self.set_root_prior(r, loc, scale)
        return tuple(chosen)

    def site_distribution(self, name: str, values: Mapping[str, Tensor], n: int) -> dist.Distribution:
        """The distribution of site ``name`` given earlier values; batch ``(N,)``, event ``(dim,)``."""
        var = self.graph[name]
        if self.graph.is_root(name):
            if var.role is Role.ACTION:
                low, high = self.bounds(name)
                return dist.Uniform(low, high).expand([n, var.dim]).to_event(1)
            loc, scale = self._priors.get(name)
            return dist.Normal(loc, scale).expand([n, var.dim]).to_event(1)
        return dist.Normal(self._loc(name, values), self.sigma(name)).to_event(1)

    # ------------------------------------------------------------------ the program
    def forward(self, data: Mapping[str, Any] | None = None, n: int | None = None) -> dict[str, Tensor]:
        """Run the generative program.

        Args:
            data: name -> ``(N, dim)`` observed values, passed as ``obs=``; actions must lie
                within their bounds.
            n: number of units N when ``data`` is empty (else must agree with it).

        Returns:
            name -> value of every site, shape ``(N, dim)`` (with any outer batch dims
            that enclosing plates add).
        """
        if n is not None:
            n = check_int("n", n, minimum=1)
        data, n = as_values(self.graph, data, n, dtype=self.dtype)
        if n is None:
            raise ValueError("the program needs data or n (the number of units)")
        check_action_bounds(self.graph, data, "data")
        values: dict[str, Tensor] = {}
        with pyro.plate("units", n, dim=-1):
            for name in self.graph.topological_order():
                values[name] = pyro.sample(name, self.site_distribution(name, values, n), obs=data.get(name))
        return values

    # ------------------------------------------------------------------ forward queries
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
            dim = self.graph[name].dim
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
        if isinstance(noise, str):
            if noise == "expected":
                return None
            return torch.randn(shape, generator=generator, dtype=self.dtype)
        if name not in noise:
            raise ValueError(
                f"noise mapping has no residual for {name!r}; give eps for every predicted variable"
            )
        eps = noise[name]
        if eps.shape != shape:
            raise ValueError(f"noise[{name!r}] has shape {tuple(eps.shape)}, expected {tuple(shape)}")
        return eps

    def predict(
        self,
        values: Mapping[str, Any],
        noise: NoiseSpec = "expected",
        generator: torch.Generator | None = None,
        grad: bool = False,
    ) -> dict[str, Tensor]:
        """The forward query Phi (Eq. 4.39, 4.44): one step of Alg. 4.1.

        Given values are kept (an assignment replaces the mechanism, as ``do`` does);
        every other variable is ``x_i = f_i(pa_i) + sigma_i * eps_i`` in topological order.

        Args:
            values: name -> ``(N, dim)``; must assign every root (actions and observed
                roots). Actions must lie within their bounds.
            noise: ``"expected"`` (eps = 0), ``"sampled"`` (eps ~ N(0, I) from
                ``generator``), or name -> ``(N, dim)`` standardised residuals, e.g.
                abducted ones (Eq. 4.43), for every predicted variable.
            generator: torch generator for ``"sampled"`` (None: the global torch RNG).
            grad: keep the autograd graph (for planning through the model); by default
                the outputs are plain tensors.

        Returns:
            name -> ``(N, dim)`` for every variable.

        Raises:
            ValueError: bad values (see :func:`as_values`), a missing root, an action out of
                bounds, or bad noise.
        """
        grad = check_bool("grad", grad)
        generator = check_generator("generator", generator)
        out, n = as_values(self.graph, values, what="values", dtype=self.dtype)
        missing = [r for r in self.graph.roots if r not in out]
        if missing:
            raise ValueError(f"predict needs a value for every root; missing {missing}")
        check_action_bounds(self.graph, out, "values")
        noise = self._check_noise(noise, n)
        with torch.set_grad_enabled(grad):
            return self._predict(out, noise, generator)

    def _predict(
        self, values: Mapping[str, Tensor], noise: NoiseSpec, generator: torch.Generator | None
    ) -> dict[str, Tensor]:
        out = dict(values)
        for name in self.graph.non_roots:
            if name in out:
                continue
            loc = self._loc(name, out)
            eps = self._noise(name, noise, loc.shape, generator)
            out[name] = loc if eps is None else loc + self.sigma(name) * eps
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
                else:
                    loc, scale = self._priors.get(name)
                    roots[name] = loc + scale * torch.randn(n, var.dim, generator=generator, dtype=self.dtype)
            return self._predict(roots, "sampled", generator)

    def residuals(self, values: Mapping[str, Any]) -> dict[str, Tensor]:
        """Standardised residuals eps_i = (x_i - f_i(pa_i)) / sigma_i (Eq. 4.43).

        Args:
            values: name -> ``(N, dim)`` for every variable of the graph.

        Returns:
            name -> ``(N, dim)`` for every non-root variable.
        """
        vals, _ = as_values(self.graph, values, what="values", dtype=self.dtype)
        missing = [v for v in self.graph.names if v not in vals]
        if missing:
            raise ValueError(f"residuals need every variable; missing {missing}")
        return {n: (vals[n] - self._loc(n, vals)) / self.sigma(n) for n in self.graph.non_roots}

    def rollout(
        self,
        initial: Mapping[str, Any],
        inputs: Mapping[str, Any],
        noise: NoiseSpec = "expected",
        generator: torch.Generator | None = None,
        grad: bool = False,
    ) -> dict[str, Tensor]:
        """Mental simulation over h' steps (Alg. 4.1, Eq. 4.40).

        At step tau the lag-1 slots take the previous step's values of their ``lag_of``
        variables (``initial`` at tau = 0); the per-step ``inputs`` (actions and any other
        lag-0 roots) are assigned; the rest is ``x_i = f_i(pa_i) + sigma_i * eps_i``.

        Args:
            initial: name -> ``(N, dim)`` for every lag-1 root.
            inputs: name -> ``(N, H, dim)`` for every lag-0 root, e.g. the action sequence
                (within the action bounds).
            noise: ``"expected"``, ``"sampled"``, or name -> residuals of shape
                ``(N, dim)`` (reused at every step, the thesis's abduction scheme) or
                ``(N, H, dim)`` (one per step).
            generator: torch generator for ``"sampled"``.
            grad: keep the autograd graph.

        Returns:
            name -> ``(N, H, dim)``: the simulated trajectory T^sim.
        """
        grad = check_bool("grad", grad)
        generator = check_generator("generator", generator)
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
        noise = self._check_noise(noise, n, extra_dims=(0, 1))
        if isinstance(noise, Mapping):
            for k, e in noise.items():
                if e.ndim == 3 and e.shape[1] != horizon:
                    raise ValueError(
                        f"noise[{k!r}] has {e.shape[1]} steps, expected {horizon} like the inputs"
                    )
        state = dict(init)
        steps: list[dict[str, Tensor]] = []
        with torch.set_grad_enabled(grad):
            for tau in range(horizon):
                values = {**state, **{k: v[:, tau] for k, v in seq.items()}}
                step_noise: NoiseSpec = noise
                if isinstance(noise, Mapping):
                    step_noise = {k: (e[:, tau] if e.ndim == 3 else e) for k, e in noise.items()}
                pred = self._predict(values, step_noise, generator)
                steps.append(pred)
                state = {r: pred[lagged[r]] for r in lag1_roots if r in lagged}
            return {k: torch.stack([s[k] for s in steps], 1) for k in self.graph.names}

    # ------------------------------------------------------------------ editing
    def with_graph(self, graph: CausalGraph, *, seed: Seed = None) -> WorldModel:
        """A new model on an edited ``graph`` that warm-starts from this one.

        For every non-root X_i of ``graph``:

        - same parents as here: a copy of f_i (weights, normalisers, sigma_i) - "kept";
        - other parents, and f_i is an MLP or linear mechanism: a copy whose first layer
          keeps the weight columns of the parents that remain and has zero columns for the
          new ones, so f_i is unchanged when parents are only added - "rewired";
        - otherwise (new variable, root here, or a function mechanism): a fresh default
          mechanism - "new".

        Root priors of variables that stay roots are copied. The new model's provenance
        records the per-variable outcome under ``"warm_start"``. This model is not changed.

        Args:
            graph: the edited graph.
            seed: int or ``torch.Generator`` for the weights of new mechanisms; None draws
                them from the global torch RNG.

        Raises:
            ValueError: a variable of ``graph`` exists here with another dim.
        """
        if not isinstance(graph, CausalGraph):
            raise ValueError(f"graph must be a CausalGraph, got {type(graph).__name__}")
        generator = as_generator(seed)
        for name in graph.names:
            if name in self.graph and self.graph[name].dim != graph[name].dim:
                raise ValueError(
                    f"variable {name!r} has dim {graph[name].dim} in the new graph, expected "
                    f"{self.graph[name].dim} as in the model"
                )
        mechs: dict[str, Mechanism] = {}
        outcome: dict[str, str] = {}
        for name in graph.non_roots:
            old = self._mech_by_name.get(name) if name in self.graph else None
            new_parents = graph.parents(name)
            if old is None:
                outcome[name] = "new"
                continue
            if self.graph.parents(name) == new_parents:
                mechs[name] = copy.deepcopy(old)
                outcome[name] = "kept"
                continue
            rewired = _rewire(old, self.graph, self.graph.parents(name), graph, new_parents, generator)
            if rewired is None:
                outcome[name] = "new"
            else:
                mechs[name] = rewired
                outcome[name] = "rewired"
        model = WorldModel(graph, mechs, seed=generator, **self._defaults)
        model.copy_root_priors_from(self)
        model.provenance = {**copy.deepcopy(self.provenance), "warm_start": outcome}
        return model

    def extra_repr(self) -> str:
        """The graph's repr, shown inside ``repr(model)``."""
        return repr(self.graph)


def _columns(graph: CausalGraph, parents: Sequence[str]) -> dict[str, slice]:
    out, start = {}, 0
    for p in parents:
        out[p] = slice(start, start + graph[p].dim)
        start += graph[p].dim
    return out


def _rewire(
    mech: Mechanism,
    old_graph: CausalGraph,
    old_parents: Sequence[str],
    new_graph: CausalGraph,
    new_parents: Sequence[str],
    generator: torch.Generator | None = None,
) -> Mechanism | None:
    """A copy of ``mech`` reading ``new_parents``, or None if it cannot be rewired.

    Kept parents keep their input columns (first-layer weights and input normalisers), new
    ones start with zero weights.
    """
    if isinstance(mech, MLPMechanism):
        first = "net.0"
    elif isinstance(mech, LinearMechanism):
        first = "linear"
    else:
        return None
    new_dim = sum(new_graph[p].dim for p in new_parents)
    if isinstance(mech, MLPMechanism):
        out = MLPMechanism(
            new_dim, mech.out_dim, hidden=mech.hidden, activation=mech.activation, seed=generator
        )
    else:
        out = LinearMechanism(new_dim, mech.out_dim, seed=generator)
    state = {k: v.clone() for k, v in mech.state_dict().items()}
    old_cols, new_cols = _columns(old_graph, old_parents), _columns(new_graph, new_parents)
    weight = torch.zeros(state[f"{first}.weight"].shape[0], new_dim)
    in_loc, in_scale = torch.zeros(new_dim), torch.ones(new_dim)
    for p, cols in new_cols.items():
        if p in old_cols:
            weight[:, cols] = state[f"{first}.weight"][:, old_cols[p]]
            in_loc[cols] = state["in_loc"][old_cols[p]]
            in_scale[cols] = state["in_scale"][old_cols[p]]
    state[f"{first}.weight"], state["in_loc"], state["in_scale"] = weight, in_loc, in_scale
    out.load_state_dict(state, strict=True)
    return out
