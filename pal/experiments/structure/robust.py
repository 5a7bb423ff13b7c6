"""Structure learning where the data are weak: a permutation baseline and measurement-like data.

* Permutation baseline: the columns of :func:`pal.experiments.structure.measurement.measurement_data`
  (d variables, n rows) are shuffled independently, so no dependence is left and every edge
  found is false; the figure is the mean number of edges over ``seeds``.
* Measurement-like data (heavy tails, heteroscedastic noise, skewed and saturated readings,
  measurement error): SHD of :func:`inference.discover`'s DAG against the true DAG, beside
  the empty graph's (its number of true edges) and causal-learn's PC and GRaSP (their CPDAGs,
  an undirected edge counting 1) when installed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from inference.discovery import discover, shd
from pal.baselines import discovery_peers as peers
from pal.checks import check_int
from pal.experiments.structure.measurement import measurement_data, shuffled
from pal.experiments.structure.scm import standardised

__all__ = ["RobustConfig", "measurement_shd", "permutation_edges"]


@dataclass(frozen=True)
class RobustConfig:
    """Sizes of the two checks.

    Attributes:
        shuffled_d, shuffled_n, shuffled_seeds: the permutation baseline.
        d, n, seeds: the measurement-like data.
    """

    shuffled_d: int = 10
    shuffled_n: int = 1000
    shuffled_seeds: int = 10
    d: int = 11
    n: int = 1000
    seeds: int = 5

    def __post_init__(self) -> None:
        for key in ("shuffled_d", "d"):
            check_int(key, getattr(self, key), minimum=2)
        for key in ("shuffled_n", "n"):
            check_int(key, getattr(self, key), minimum=20)
        for key in ("shuffled_seeds", "seeds"):
            check_int(key, getattr(self, key), minimum=1)


def permutation_edges(config: RobustConfig, seed: int) -> dict[str, Any]:
    """Edges that discover finds on shuffled columns, per seed, their mean, and the CPU seconds."""
    edges, cpu = [], time.process_time()
    for s in range(seed, seed + config.shuffled_seeds):
        graph, data = measurement_data(config.shuffled_d, config.shuffled_n, s)
        edges.append(len(discover(graph, standardised(shuffled(data, s)), seed=s).graph.edges))
    return {"edges": edges, "mean_edges": float(np.mean(edges)), "cpu_seconds": time.process_time() - cpu}


def measurement_shd(config: RobustConfig, seed: int, use_peers: bool) -> dict[str, Any]:
    """Per seed SHD of discover (DAG and CPDAG), the empty graph, PC and GRaSP; their means."""
    rows = []
    for s in range(seed, seed + config.seeds):
        graph, data = measurement_data(config.d, config.n, s)
        std = standardised(data)
        cpu = time.process_time()
        result = discover(graph, std, seed=s)
        row = {
            "seed": s,
            "pal": shd(result.graph, graph),
            "pal_cpdag": shd(result.cpdag, graph),
            "pal_cpu_seconds": time.process_time() - cpu,
            "pal_edges": len(result.graph.edges),
            "empty": len(graph.edges),
        }
        for method in peers.PEERS:
            row[method] = peers.compare(method, std, graph, seed=s)["shd"] if use_peers else None
        rows.append(row)
    means = {
        k: (None if rows[0][k] is None else float(np.mean([r[k] for r in rows])))
        for k in ("pal", "pal_cpdag", "empty", "pal_edges", "pal_cpu_seconds", *peers.PEERS)
    }
    return {"rows": rows, "mean": means}
