"""The world model M^wm as a Pyro program (thesis Eq. 4.27-4.31, 4.39, 4.44, Alg. 4.1).

For every variable in topological order, inside ``pyro.plate("units", N)``:

    A_j  ~ Uniform(low_j, high_j)                      (action roots)
    R_k  ~ Normal(mu_k, s_k)                           (other roots; fitted from data)
    X_i  ~ Normal(f_i(pa_i), sigma_i(pa_i))            (every continuous non-root, Eq. 5.4)
    D_j  ~ Categorical(softmax(l_j(pa_j)))             (discrete sites, :mod:`models.discrete`)

with ``(f_i, sigma_i) = mechanism_i.loc_scale(pa_i)``: ``sigma_i`` is one learned constant for
homoscedastic mechanisms, a function of the parents for heteroscedastic ones
(:mod:`models.heteroscedastic`), and the moment-matched mixture sd for ensembles
(:mod:`models.ensemble`). A discrete site (``discrete={name: K}``, or a Bernoulli or
categorical mechanism) takes float codes ``0 .. K-1``; a discrete root has a categorical
prior; children read a categorical parent with K > 2 one-hot (K columns), a Bernoulli parent
as its 0/1 code. Values passed in ``data`` enter as ``obs=``. The program contains
no ``do``, no conditioning flags: :mod:`inference` adds those with handlers. Site names are
the variable names. Values have shape ``(N, dim)``. The forward queries (predict, rollout,
predict_scale, sample, residuals) are in :mod:`models.forward`, the root priors and their
setters in :mod:`models.root_priors`, the default mechanisms, discrete categories and parent
encodings in :mod:`models.world_sites`.
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
    check_choice,
    check_hidden,
    check_int,
    check_mapping,
    check_names,
    describe,
)
from models.discrete import CategoricalCode, DiscreteMechanism, check_codes
from models.forward import ForwardQueries, NoiseSpec
from models.gated import GatedMechanism, bind_gated
from models.graph import CausalGraph
from models.mechanisms import ACTIVATIONS, Mechanism, Seed, as_generator
from models.root_priors import RootPriorSetters, _RootPriors
from models.values import BOUNDS_TOLERANCE, as_values, check_action_bounds, module_key
from models.variables import Role
from models.warmstart import rewire_mechanism
from models.world_sites import KINDS, _categories, _default_discrete, _default_mechanism, _one_hot, _width

__all__ = [
    "BOUNDS_TOLERANCE",
    "KINDS",
    "NoiseSpec",
    "WorldModel",
    "as_values",
    "check_action_bounds",
    "model_dtype",
    "module_key",
    "require_world_model",
]


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


class WorldModel(PyroModule, ForwardQueries, RootPriorSetters):
    """A structural causal world model written as a Pyro program.

    For every variable in topological order, inside ``pyro.plate("units", N)``:
    actions ``A_j ~ Uniform(low_j, high_j)``, other roots ``R_k ~ Normal(mu_k, s_k)`` and
    non-roots ``X_i ~ Normal(f_i(pa_i), sigma_i(pa_i))`` (Eq. 4.31, 5.4), where
    ``(f_i, sigma_i)`` is the mechanism's :meth:`Mechanism.loc_scale`. Values are
    ``(N, dim)`` tensors of the model's dtype (:attr:`dtype`), in the variables' units.

    Args:
        graph: the validated causal graph.
        mechanisms: optional name -> :class:`Mechanism` for some non-roots; the others
            get a default mechanism. A :class:`models.gated.GatedMechanism` is bound to its
            switch, which must be a Bernoulli parent of its site.
        seed: int or ``torch.Generator`` for the weights of the default mechanisms, drawn
            from a local generator in topological order; None draws them from the global
            torch RNG (``WorldModel(g, seed=s)`` equals ``torch.manual_seed(s); WorldModel(g)``
            without touching the global RNG).
        kind: default mechanism class: ``"mlp"`` (:class:`MLPMechanism`), ``"linear"``
            (:class:`LinearMechanism`) or ``"hetero"``
            (:class:`models.heteroscedastic.HeteroscedasticMechanism`, which predicts its
            own scale).
        hidden: MLP (or heteroscedastic trunk) hidden widths (default 2 x 32, §5.2.1).
        activation: MLP activation (default tanh).
        members: K >= 1; with K > 1 every default mechanism is an
            :class:`models.ensemble.EnsembleMechanism` of K members of ``kind``, each drawn
            from its own seed stream (:func:`models.ensemble.member_seeds`). Given
            ``mechanisms`` are used as they are. Discrete sites are never ensembles.
        discrete: name -> number of categories K >= 2 (2: Bernoulli) for dim-1 non-action
            variables whose values are codes ``0 .. K-1``. A non-root listed here gets a
            :class:`models.discrete.BernoulliMechanism` (K = 2) or
            :class:`models.discrete.CategoricalMechanism` (logistic / softmax regression
            for ``kind="linear"``, an MLP with ``hidden`` otherwise); a root gets a
            categorical prior (uniform until :func:`inference.fit` sets it from data). A
            given discrete mechanism makes its site discrete without being listed.

    Attributes:
        graph: the :class:`CausalGraph`.
        mechanisms: ``nn.ModuleDict`` of f_i, keyed by :func:`module_key`.
        root_priors: buffers ``(mu_k, s_k)`` of the non-action roots; ``root_priors.get(name)``.
        provenance: JSON-compatible record of how the model was made (seed, config,
            versions); :func:`models.io.load` restores it.

    Raises:
        ValueError: a graph that is not a :class:`CausalGraph`, mechanisms that are not a
            mapping of :class:`Mechanism`, a mechanism for a root or of the wrong dims, an
            unknown kind or activation, bad hidden widths, seed or ensemble size, or a bad
            ``discrete`` entry (unknown name, an action, dim > 1, K < 2, or a K that
            disagrees with the site's mechanism).
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
        members: int = 1,
        discrete: Mapping[str, int] | None = None,
    ) -> None:
        super().__init__()
        if not isinstance(graph, CausalGraph):
            raise ValueError(f"graph must be a CausalGraph, got {type(graph).__name__}")
        kind = check_choice("kind", kind, KINDS)
        members = check_int("members", members, minimum=1)
        hidden = check_hidden(hidden)
        activation = check_choice("activation", activation, sorted(ACTIVATIONS))
        given = dict(check_mapping("mechanisms", mechanisms, allow_none=True))
        for name in given:
            graph.check_name(name, what="mechanism target")
            if graph.is_root(name):
                raise ValueError(f"{name!r} is a root; roots have no mechanism")
        categories = _categories(graph, discrete, given)
        generator = as_generator(seed)
        self.graph = graph
        mods: dict[str, Mechanism] = {}
        for name in graph.non_roots:
            in_dim = sum(_width(graph, categories, p) for p in graph.parents(name))
            out_dim = graph[name].dim
            mech = given.get(name)
            if mech is None and name in categories:
                mech = _default_discrete(kind, in_dim, categories[name], hidden, activation, generator)
            elif mech is None:
                mech = _default_mechanism(kind, in_dim, out_dim, hidden, activation, members, generator)
            if not isinstance(mech, Mechanism):
                raise ValueError(f"mechanism for {name!r} must be a Mechanism, got {type(mech).__name__}")
            if isinstance(mech, GatedMechanism):  # the switch must be a Bernoulli parent
                widths = {p: _width(graph, categories, p) for p in graph.parents(name)}
                bind_gated(name, mech, graph.parents(name), widths, categories)
            if (mech.in_dim, mech.out_dim) != (in_dim, out_dim):
                raise ValueError(
                    f"mechanism for {name!r} maps {mech.in_dim} -> {mech.out_dim}, expected "
                    f"{in_dim} (parents {list(graph.parents(name))}, categorical parents one-hot) -> {out_dim}"
                )
            mods[module_key(name)] = mech
        self.mechanisms = nn.ModuleDict(mods)
        self.root_priors = _RootPriors(graph, categories)
        # Plain references for the program. PyroModule.__getattr__ would lift every
        # parameter of a plain submodule into the Pyro param store on each access, which
        # is slow and would let SVI train the world model during state inference.
        self.__dict__["_mech_by_name"] = {n: mods[module_key(n)] for n in graph.non_roots}
        self.__dict__["_priors"] = self.root_priors
        self.__dict__["_categories"] = categories
        # per site: (parent, K) with K > 2 for the parents read one-hot, else 0
        self.__dict__["_encoding"] = {
            n: tuple((p, categories.get(p, 0) if categories.get(p, 0) > 2 else 0) for p in graph.parents(n))
            for n in graph.non_roots
        }
        self.__dict__["_defaults"] = {
            "kind": kind,
            "hidden": hidden,
            "activation": activation,
            "members": members,
        }
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
        """Total width of the encoded parents concat(pa_i) (categorical parents one-hot)."""
        return sum(self.parent_width(p) for p in self.graph.parents(name))

    def parent_width(self, name: str) -> int:
        """Columns that ``name`` takes in its children's inputs.

        K for a categorical site with K > 2 categories (one-hot), else its dim.
        """
        return _width(self.graph, self._categories, name)

    @property
    def discrete(self) -> dict[str, int]:
        """Name -> number of categories K of every discrete site (roots included)."""
        return dict(self._categories)

    def categories(self, name: str) -> int | None:
        """K of a discrete site, None for a continuous one."""
        self.graph.check_name(name)
        return self._categories.get(name)

    def check_codes(self, values: Mapping[str, Tensor], what: str = "values") -> None:
        """Refuse values of discrete sites that are not codes ``0 .. K-1`` (e.g. 0.5 for a Bernoulli).

        Raises:
            ValueError: naming the site, the first bad value and its index.
        """
        for name, v in values.items():
            k = self._categories.get(name)
            if k is not None and isinstance(v, Tensor):
                check_codes(f"{what}[{name!r}]", v, k)

    def probs(self, name: str, values: Mapping[str, Any], grad: bool = False) -> Tensor:
        """``(..., K)`` category probabilities of the discrete non-root ``name`` given its parents' values.

        ``grad`` keeps the autograd graph; by default the result is a plain tensor.

        Raises:
            ValueError: ``name`` is not a discrete non-root, or a parent value is missing.
        """
        mech = self.mechanism(name)
        if not isinstance(mech, DiscreteMechanism):
            raise ValueError(
                f"{name!r} is continuous; probs is for discrete sites ({sorted(self._categories)})"
            )
        values = check_mapping("values", values)
        missing = [p for p in self.graph.parents(name) if p not in values]
        if missing:
            raise ValueError(f"probs of {name!r} needs values of its parents; missing {missing}")
        vals = {p: as_float_tensor(values[p], f"values[{p!r}]", self.dtype) for p in self.graph.parents(name)}
        with torch.set_grad_enabled(grad and torch.is_grad_enabled()):
            return mech.distribution(self._parents(name, vals)).probs

    def mechanism(self, name: str) -> Mechanism:
        """f_i of a non-root variable."""
        self.graph.check_name(name)
        mech = self._mech_by_name.get(name)
        if mech is None:
            raise ValueError(f"{name!r} is a root and has no mechanism")
        return mech

    def sigma(self, name: str) -> Tensor:
        """sigma_i of a homoscedastic site, shape ``(dim,)``, in the variable's units.

        Raises:
            ValueError: the site is heteroscedastic or an ensemble of K > 1 (its scale
                depends on the parents: use :meth:`predict_scale`).
        """
        return self.mechanism(name).sigma

    def _parents(self, name: str, values: Mapping[str, Tensor]) -> Tensor:
        """concat(pa_i), ``(..., in_dim)``, leading dims broadcast; categorical parents one-hot."""
        encoding = self._encoding[name]
        if len(encoding) == 1 and not encoding[0][1]:
            return values[encoding[0][0]]
        pas = [_one_hot(values[p], k) if k else values[p] for p, k in encoding]
        if len(pas) == 1:
            return pas[0]
        leading = {p.shape[:-1] for p in pas}
        if len(leading) == 1:  # the common case in rollouts: nothing to broadcast
            return torch.cat(pas, -1)
        batch = torch.broadcast_shapes(*leading)
        return torch.cat([p.expand(*batch, p.shape[-1]) for p in pas], -1)

    def _loc(self, name: str, values: Mapping[str, Tensor]) -> Tensor:
        return self._mech_by_name[name](self._parents(name, values))

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
            and self._categories.get(r) == other._categories.get(r)
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
            if r in self._categories:
                self.set_root_probs(r, other.root_priors.logits(r).exp())
                continue
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
            if name in self._categories:
                logits = self._priors.logits(name)
                return CategoricalCode(logits.expand(n, logits.shape[0]))
            loc, scale = self._priors.get(name)
            return dist.Normal(loc, scale).expand([n, var.dim]).to_event(1)
        mech = self._mech_by_name[name]
        if name in self._categories:
            return mech.distribution(self._parents(name, values))
        loc, scale = mech.loc_scale(self._parents(name, values))
        return dist.Normal(loc, scale).to_event(1)

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
        if self._categories:
            self.check_codes(data, "data")
        values: dict[str, Tensor] = {}
        with pyro.plate("units", n, dim=-1):
            for name in self.graph.topological_order():
                values[name] = pyro.sample(name, self.site_distribution(name, values, n), obs=data.get(name))
        return values

    # ------------------------------------------------------------------ editing
    def with_graph(self, graph: CausalGraph, *, seed: Seed = None) -> WorldModel:
        """A new model on an edited ``graph`` that warm-starts from this one.

        For every non-root X_i of ``graph``:

        - same parents as here: a copy of f_i (weights, normalisers, sigma_i) - "kept";
        - other parents, and f_i is an MLP, linear, heteroscedastic or ensemble mechanism:
          a copy whose input layer(s) keep the weight columns of the parents that remain and
          have zero columns for the new ones, so f_i is unchanged when parents are only
          added - "rewired" (:func:`models.warmstart.rewire_mechanism`);
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
        kept_discrete = {k: v for k, v in self._categories.items() if k in graph}
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
            if any(
                self.parent_width(p) != graph[p].dim
                for p in (*self.graph.parents(name), *new_parents)
                if p in self.graph
            ):
                outcome[name] = "new"  # one-hot parents: columns are not the graph's dims
                continue
            rewired = rewire_mechanism(
                old, self.graph, self.graph.parents(name), graph, new_parents, generator
            )
            if rewired is None:
                outcome[name] = "new"
            else:
                mechs[name] = rewired
                outcome[name] = "rewired"
        model = WorldModel(graph, mechs, seed=generator, discrete=kept_discrete, **self._defaults)
        model.copy_root_priors_from(self)
        model.provenance = {**copy.deepcopy(self.provenance), "warm_start": outcome}
        return model

    def extra_repr(self) -> str:
        """The graph's repr, shown inside ``repr(model)``."""
        return repr(self.graph)
