"""Peer libraries for ``pal bench counterfactual``: ChiRho and DoWhy-GCM on pal's SCMs.

Both peers compute the same exact counterfactual as :func:`inference.counterfactual` for
a fully observed additive-Gaussian SCM

    X_i = f_i(pa_i) + sigma_i * U_i,   U_i ~ N(0, 1)

(abduction ``u_i = (x_i - f_i(pa_i)) / sigma_i``, then ``do``, then prediction with the
same ``u``), using our torch ``f_i`` and ``sigma_i`` so that all three compute the same
numbers. The libraries are imported lazily, inside :func:`make_peer`; neither is a
dependency of pal (``pip install pal[bench]``).

Each peer splits the work into ``native`` (convert the factual tensors to the library's
data type, untimed), ``run`` (the timed counterfactual call) and ``to_tensors`` (convert
the answer back for the agreement check, untimed).

* ChiRho 0.3: one call per question. The program is run under
  ``MultiWorldCounterfactual``, ``chirho.interventional.handlers.do`` and
  ``chirho.observational.handlers.condition``. K scenarios are one ``do`` with a tuple of
  K values, i.e. K + 1 worlds (factual + K) in one batched run of the program.
* DoWhy-GCM: an ``InvertibleStructuralCausalModel`` whose ``AdditiveNoiseModel``
  prediction models wrap our torch ``f_i`` (``fit`` is a no-op) and whose noise is
  ``Normal(0, sigma_i)``; ``gcm.counterfactual_samples(scm, interventions,
  observed_data=...)`` per scenario, so K scenarios are K calls.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from models.variables import Role
from models.world import WorldModel

__all__ = ["PEERS", "ChirhoPeer", "DowhyPeer", "available", "make_peer"]

#: peer name -> importable module that provides it
PEERS: dict[str, str] = {"chirho": "chirho", "dowhy": "dowhy"}


def available(name: str) -> bool:
    """True when the peer library ``name`` can be imported (without importing it)."""
    if name not in PEERS:
        raise ValueError(f"unknown peer {name!r}; expected one of {sorted(PEERS)}")
    return importlib.util.find_spec(PEERS[name]) is not None


def _check_scalar(model: WorldModel) -> None:
    graph = model.graph
    wide = [v for v in graph.names if graph[v].dim != 1]
    actions = [v for v in graph.names if graph[v].role is Role.ACTION]
    if wide or actions:
        raise ValueError(
            f"peer programs support scalar non-action variables only; got dims > 1 at {wide}, actions {actions}"
        )


def _parent_matrix(values: Sequence[Tensor]) -> Tensor:
    """Stack scalar parent values ``(..., N)`` into ``(..., N, k)`` after broadcasting."""
    return torch.stack(torch.broadcast_tensors(*values), -1)


class ChirhoPeer:
    """ChiRho programs for the chain and for any scalar :class:`models.WorldModel`.

    Every non-root site is ChiRho's exact counterfactual form of ``X = loc + scale * U``:
    a ``TransformedDistribution(Normal(0, 1), [AffineTransform(loc, scale)])``. When such
    a site is observed downstream of an intervention, ChiRho inverts the transform in the
    factual world (``u = (x - loc) / scale``, the ``*_noise_likelihood`` site) and pushes
    the same ``u`` through the counterfactual ``loc`` (the ``*_cf_obs`` site). An
    explicit ``u = pyro.sample("u", Normal(0, 1)); x = pyro.deterministic("x", ...)`` site
    pair would instead need posterior inference over ``u`` to condition on ``x``.

    Args:
        chain_weights: ``{"y": w_y, "z": w_z}`` of the chain ``Y = w_y X + U_y``,
            ``Z = w_z Y + U_z``, ``X, U ~ N(0, 1)``.
        mlp: the world model whose mechanisms the ``"mlp"`` program reuses.
    """

    name = "chirho"

    def __init__(self, chain_weights: Mapping[str, float], mlp: WorldModel) -> None:
        import pyro
        import pyro.distributions as dist
        from chirho.counterfactual.handlers import MultiWorldCounterfactual
        from chirho.indexed.ops import IndexSet, gather
        from chirho.interventional.handlers import do
        from chirho.observational.handlers import condition

        _check_scalar(mlp)
        self._pyro, self._dist = pyro, dist
        self._mwc, self._do, self._condition = MultiWorldCounterfactual, do, condition
        self._index_set, self._gather = IndexSet, gather
        self.chain_weights = dict(chain_weights)
        self.mlp = mlp
        self.programs: dict[str, Callable[[int], dict[str, Tensor]]] = {
            "chain": self.chain,
            "mlp": self.world,
        }

    def _site(self, name: str, loc: Tensor, scale: Tensor | float) -> Tensor:
        dist = self._dist
        base = dist.Normal(torch.zeros_like(loc), 1.0)
        return self._pyro.sample(
            name, dist.TransformedDistribution(base, [dist.transforms.AffineTransform(loc, scale)])
        )

    def chain(self, n: int) -> dict[str, Tensor]:
        """The chain X -> Y -> Z as a ChiRho-style Pyro program over n units."""
        with self._pyro.plate("units", n, dim=-1):
            x = self._pyro.sample("x", self._dist.Normal(0.0, 1.0))
            y = self._site("y", self.chain_weights["y"] * x, 1.0)
            z = self._site("z", self.chain_weights["z"] * y, 1.0)
        return {"x": x, "y": y, "z": z}

    def world(self, n: int) -> dict[str, Tensor]:
        """The scalar world model with our f_i and sigma_i, as a ChiRho-style program."""
        model, pyro = self.mlp, self._pyro
        values: dict[str, Tensor] = {}
        with pyro.plate("units", n, dim=-1):
            for name in model.graph.topological_order():
                if model.graph.is_root(name):
                    loc, scale = model.root_priors.get(name)
                    values[name] = pyro.sample(name, self._dist.Normal(loc[0], scale[0]))
                else:
                    pa = _parent_matrix([values[p] for p in model.graph.parents(name)])
                    values[name] = self._site(name, model.mechanism(name)(pa)[..., 0], model.sigma(name)[0])
        return values

    def native(self, factual: Mapping[str, Tensor]) -> dict[str, Tensor]:
        """``(N, 1)`` factual values -> ``(N,)`` observations."""
        return {k: v[:, 0] for k, v in factual.items()}

    def subset(self, data: dict[str, Tensor], n: int) -> dict[str, Tensor]:
        """The first ``n`` units of native observations: name -> ``(n,)``."""
        return {k: v[:n] for k, v in data.items()}

    def run(
        self, which: str, data: Mapping[str, Tensor], node: str, values: Sequence[float]
    ) -> dict[str, Tensor]:
        """All worlds (factual + one per value of ``do(node)``) in one batched program run.

        Returns:
            name -> ``(K, N)``: the counterfactual worlds 1..K, gathered inside the
            ``MultiWorldCounterfactual`` context (which knows the world index).
        """
        n = next(iter(data.values())).shape[0]
        acts = tuple(torch.tensor(float(v)) for v in values)
        with torch.no_grad(), self._mwc(), self._do(actions={node: acts}), self._condition(data=data):
            out = self.programs[which](n)
            worlds = [self._index_set(**{node: {i}}) for i in range(1, len(acts) + 1)]
            return {
                name: torch.stack([self._gather(v, w, event_dim=0).reshape(-1).expand(n) for w in worlds])
                for name, v in out.items()
            }

    def to_tensors(self, out: Mapping[str, Tensor], node: str, k: int, n: int) -> dict[str, Tensor]:
        """The batched worlds as name -> ``(K, N, 1)``."""
        return {name: v[..., None] for name, v in out.items()}


class DowhyPeer:
    """DoWhy-GCM invertible SCMs that reuse our mechanisms.

    Args:
        chain: the chain world model.
        mlp: the MLP world model.
    """

    name = "dowhy"

    def __init__(self, chain: WorldModel, mlp: WorldModel) -> None:
        import pandas as pd
        from dowhy import gcm

        self._pd, self._gcm = pd, gcm
        self.scms = {"chain": self._scm(chain), "mlp": self._scm(mlp)}

    def _scm(self, model: WorldModel) -> Any:
        import networkx as nx
        from dowhy.gcm.ml.prediction_model import PredictionModel
        from scipy import stats

        gcm = self._gcm
        _check_scalar(model)

        class TorchPrediction(PredictionModel):
            """f_i as a DoWhy prediction model; dowhy passes the parents in sorted order."""

            def __init__(self, mechanism: torch.nn.Module, perm: list[int]) -> None:
                self.mechanism, self.perm = mechanism, perm

            def fit(self, X: np.ndarray, Y: np.ndarray) -> None:
                return None  # the mechanism is given, not learned

            def predict(self, X: np.ndarray) -> np.ndarray:
                x = torch.as_tensor(
                    np.asarray(X).reshape(len(X), -1)[:, self.perm], dtype=torch.get_default_dtype()
                )
                with torch.no_grad():
                    return self.mechanism(x).numpy().astype(np.float64)

            def clone(self) -> TorchPrediction:
                return TorchPrediction(self.mechanism, self.perm)

        graph = model.graph
        g = nx.DiGraph()
        g.add_nodes_from(graph.names)
        g.add_edges_from(graph.edges)
        scm = gcm.InvertibleStructuralCausalModel(g)
        for name in graph.names:
            if graph.is_root(name):
                loc, scale = model.root_priors.get(name)
                scm.set_causal_mechanism(
                    name, gcm.ScipyDistribution(stats.norm, loc=float(loc[0]), scale=float(scale[0]))
                )
                continue
            order = sorted(graph.parents(name))
            perm = [order.index(p) for p in graph.parents(name)]
            sigma = float(model.sigma(name).detach()[0])
            noise = gcm.ScipyDistribution(stats.norm, loc=0.0, scale=sigma)
            scm.set_causal_mechanism(
                name, gcm.AdditiveNoiseModel(TorchPrediction(model.mechanism(name), perm), noise)
            )
        # fit() only records each node's parents here: the prediction models and the
        # fixed-parameter noise models ignore the data.
        with torch.no_grad():
            sample = model.sample(8, torch.Generator().manual_seed(0))
        shown = gcm.config.show_progress_bars
        gcm.config.disable_progress_bars()
        try:
            gcm.fit(scm, self.native(sample))
        finally:
            gcm.config.show_progress_bars = shown
        return scm

    def native(self, factual: Mapping[str, Tensor]) -> Any:
        """``(N, 1)`` factual values -> a float64 DataFrame with one column per variable."""
        return self._pd.DataFrame(
            {k: v[:, 0].detach().numpy().astype(np.float64) for k, v in factual.items()}
        )

    def subset(self, data: Any, n: int) -> Any:
        """The first ``n`` rows of a native DataFrame."""
        return data.iloc[:n]

    def run(self, which: str, data: Any, node: str, values: Sequence[float]) -> list[Any]:
        """One ``counterfactual_samples`` call per value of ``do(node)``."""
        scm = self.scms[which]
        return [
            self._gcm.counterfactual_samples(scm, {node: lambda _x, v=float(v): v}, observed_data=data)
            for v in values
        ]

    def to_tensors(self, out: Sequence[Any], node: str, k: int, n: int) -> dict[str, Tensor]:
        """Counterfactual DataFrames -> name -> ``(K, N, 1)``."""
        dtype = torch.get_default_dtype()
        return {
            name: torch.stack([torch.tensor(df[name].to_numpy(), dtype=dtype) for df in out])[..., None]
            for name in out[0].columns
        }


def make_peer(
    name: str, chain: WorldModel, chain_weights: Mapping[str, float], mlp: WorldModel
) -> ChirhoPeer | DowhyPeer:
    """Build peer ``name`` (imports the library). Raises ImportError when it is missing."""
    if name == "chirho":
        return ChirhoPeer(chain_weights, mlp)
    if name == "dowhy":
        return DowhyPeer(chain, mlp)
    raise ValueError(f"unknown peer {name!r}; expected one of {sorted(PEERS)}")
