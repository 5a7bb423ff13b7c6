"""Synthetic additive-noise SCMs with known graphs for the structure-learning evaluation.

Each non-root variable follows

    X_i = s_i * tanh-MLP_i((x_pa - m_pa) / s_pa) + c_i + sigma_i * eps_i,    eps_i ~ N(0, 1),

with one hidden layer of ``hidden`` tanh units whose weights are drawn with magnitudes in
[0.5, 2] (so the mechanism is far from linear), inputs standardised on a pilot sample, the
output scaled to unit variance and sigma_i ~ U(noise). Roots are N(0, 1). The graph is
:func:`models.random_graph` (Erdos-Renyi in a random order).

Interventions ``do(X_j = v)`` draw v uniformly on the pilot mean +- 2 sd of X_j.
:class:`SCMConfig` holds the sizes that the experiment ``discovery`` and the benchmark
``discovery`` share, and draws the SCM of every (d, seed).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from models import CausalGraph, MLPMechanism, WorldModel, random_graph
from pal.checks import check_float, check_int

__all__ = ["SCMConfig", "SyntheticSCM", "random_scm", "standardised"]


@dataclass
class SyntheticSCM:
    """A ground-truth world model, its graph and the pilot moments used for interventions."""

    model: WorldModel
    graph: CausalGraph
    loc: dict[str, float]
    scale: dict[str, float]

    def sample(self, n: int, seed: int) -> dict[str, np.ndarray]:
        """Draw ``n`` observational rows: name -> ``(n, 1)`` float64."""
        gen = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            return {k: v.double().numpy() for k, v in self.model.sample(n, gen).items()}

    def intervene(
        self, targets: Sequence[str], seed: int
    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """One row per entry of ``targets`` with ``do(target = v)``; returns data and the ``intervened`` masks."""
        gen = torch.Generator().manual_seed(seed)
        n = len(targets)
        if n == 0:
            raise ValueError("targets is empty; give at least one intervention target")
        with torch.no_grad():
            base = self.model.sample(n, gen)
        out = {k: np.zeros((n, 1)) for k in self.graph.names}
        masks = {k: np.zeros(n, dtype=bool) for k in self.graph.names}
        for j in sorted(set(targets)):
            self.graph.check_name(j, what="intervention target")
            rows = np.array([r for r, t in enumerate(targets) if t == j])
            u = torch.rand(len(rows), 1, generator=gen, dtype=torch.float64)
            value = self.loc[j] + self.scale[j] * (4 * u - 2)
            given = {r: base[r][rows] for r in self.graph.roots}
            given[j] = value.float()
            noise = {k: torch.randn(len(rows), 1, generator=gen) for k in self.graph.non_roots}
            with torch.no_grad():
                pred = self.model.predict(given, noise=noise)
            for k in self.graph.names:
                out[k][rows] = pred[k].double().numpy()
            masks[j][rows] = True
        return out, masks


@dataclass(frozen=True)
class SCMConfig:
    """Synthetic SCMs, one per size d and seed.

    Attributes:
        dims: numbers of variables d.
        n: observational rows of each SCM.
        expected_parents: mean in-degree of the random DAG.
    """

    dims: tuple[int, ...] = (10, 20, 50)
    n: int = 1000
    expected_parents: float = 2.0

    def __post_init__(self) -> None:
        if not self.dims:
            raise ValueError("dims is empty; give at least one number of variables, e.g. [10]")
        object.__setattr__(self, "dims", tuple(check_int("dims", d, minimum=2) for d in self.dims))
        check_int("n", self.n, minimum=10)
        check_float("expected_parents", self.expected_parents, 0.0, open_low=True)

    def draw(self, d: int, seed: int) -> tuple[SyntheticSCM, dict[str, np.ndarray]]:
        """The SCM of size ``d`` for ``seed`` and its ``n`` observational rows: name -> ``(n, 1)`` float64.

        The graph and mechanisms are drawn from ``1000 d + seed``, the rows from ``seed``.
        """
        scm = random_scm(d, self.expected_parents, seed=1000 * d + seed)
        return scm, scm.sample(self.n, seed=seed)


def standardised(data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every column to zero mean and unit sd over all its rows.

    No method may then read the causal order off the variances of simulated data.
    """
    return {k: (v - v.mean(0)) / v.std(0) for k, v in data.items()}


def random_scm(
    d: int,
    expected_parents: float = 2.0,
    *,
    hidden: int = 16,
    noise: tuple[float, float] = (0.3, 0.6),
    seed: int = 0,
) -> SyntheticSCM:
    """A random nonlinear additive-noise SCM over ``x0 .. x{d-1}`` (see the module docstring)."""
    check_int("d", d)
    check_int("hidden", hidden)
    graph = random_graph(d, expected_parents, seed=seed)
    gen = torch.Generator().manual_seed(seed + 1)
    mechs = {}
    for name in graph.non_roots:
        k = len(graph.parents(name))
        mech = MLPMechanism(k, 1, hidden=(hidden,), activation="tanh", seed=seed)  # weights set below
        with torch.no_grad():
            for layer in (mech.net[0], mech.net[2]):
                mag = 0.5 + 1.5 * torch.rand(layer.weight.shape, generator=gen)
                sign = torch.where(torch.rand(layer.weight.shape, generator=gen) < 0.5, -1.0, 1.0)
                layer.weight.copy_(mag * sign / (layer.weight.shape[1] ** 0.5))
                layer.bias.copy_(2 * torch.rand(layer.bias.shape, generator=gen) - 1)
        sigma = noise[0] + (noise[1] - noise[0]) * float(torch.rand(1, generator=gen))
        mech.set_sigma(sigma)
        mechs[name] = mech
    model = WorldModel(graph, mechs)
    pilot: dict[str, torch.Tensor] = {}
    with torch.no_grad():
        for name in graph.topological_order():
            if graph.is_root(name):
                pilot[name] = torch.randn(4000, 1, generator=gen)
                continue
            mech = model.mechanism(name)
            pa = torch.cat([pilot[p] for p in graph.parents(name)], -1)
            mech.set_normalization(pa.mean(0), pa.std(0), torch.zeros(1), torch.ones(1))
            core = mech(pa)
            mech.set_normalization(pa.mean(0), pa.std(0), -core.mean(0) / core.std(0), 1 / core.std(0))
            pilot[name] = mech(pa) + mech.sigma * torch.randn(4000, 1, generator=gen)
    return SyntheticSCM(
        model,
        graph,
        {k: float(v.mean()) for k, v in pilot.items()},
        {k: float(v.std()) for k, v in pilot.items()},
    )
