"""``pal experiment discovery``: structure learning on synthetic SCMs, or on a babbling body.

Without ``--body``: for every d in ``dims`` and seed, a random nonlinear additive-noise SCM
(:mod:`pal.experiments.discovery_scm`) gives ``n`` observational rows. Every method sees
the data standardised (each column to zero mean and unit sd), so no method can exploit
the variance ordering of simulated data. Regimes:

- ``observational``: the n rows;
- ``interventional``: plus ``interventions`` agent-chosen interventions, each
  ``do(X_j = v)`` on one variable for ``rows_per_intervention`` rows with v uniform on
  mean +- 2 sd; the targets come from :func:`inference.design.choose_interventions` on the
  observational result;
- ``interventional_random``: the same budget with uniformly random targets.

Methods: ``pal`` (:func:`inference.discover`), ``pal_gated`` (with group-lasso-gated MLP
sparsification, for d <= ``gated_max_d``), and causal-learn's GRaSP (BIC) and PC (Fisher-z)
when causal-learn is importable (``null`` otherwise). The peers do not model interventions:
they get the pooled rows. SHD counts missing, extra and reversed edges; for the peers'
CPDAGs an undirected edge also counts 1.

With ``--body finger`` or ``--body arm``: see :mod:`pal.experiments.discovery_body`.
"""

from __future__ import annotations

import logging
import statistics
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from tqdm import tqdm

from inference.design import choose_interventions, orientation_margins
from inference.discovery import discover, shd
from pal.experiments import discovery_peers as peers
from pal.experiments.discovery_scm import random_scm
from pal.experiments.timing import markdown_table

__all__ = ["Config", "DiscoveryExperiment", "run"]

log = logging.getLogger(__name__)

REGIMES = ("observational", "interventional", "interventional_random")


@dataclass(frozen=True)
class Config:
    """Synthetic sizes, or a body (then the body fields apply, see discovery_body)."""

    dims: tuple[int, ...] = (10, 20, 50)
    n: int = 1000
    seeds: tuple[int, ...] = (0,)
    expected_parents: float = 2.0
    interventions: int = 50
    rows_per_intervention: int = 10
    regimes: tuple[str, ...] = REGIMES
    peers: bool = True
    gated_max_d: int = 20
    # body mode (``--body``, ``--mjcf``, ``--joint``, ``--actuator``)
    body: str | None = None
    mjcf: str | None = None
    joint: tuple[str, ...] | None = None
    actuator: tuple[str, ...] | None = None
    transitions: int = 20000
    epochs: int = 60
    batch_size: int = 512
    b1_seeds: tuple[int, ...] = (0, 1, 2)
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def quick(cls) -> Config:
        return cls(
            dims=(10,), n=400, interventions=20, gated_max_d=0, transitions=3000, epochs=15, b1_seeds=(0,)
        )


@dataclass(frozen=True)
class DiscoveryExperiment:
    """Per (d, seed, regime, method): SHD, edge counts and seconds."""

    config: dict[str, Any]
    rows: list[dict[str, Any]]

    def summary(self) -> dict[str, dict[str, dict[str, float | None]]]:
        """``shd[d][method][regime]`` averaged over seeds (None where a method did not run)."""
        out: dict[str, dict[str, dict[str, float | None]]] = {}
        for r in self.rows:
            out.setdefault(str(r["d"]), {}).setdefault(r["method"], {}).setdefault(r["regime"], [])  # type: ignore[arg-type]
            out[str(r["d"])][r["method"]][r["regime"]].append(r["shd"])  # type: ignore[union-attr]
        return {
            d: {
                m: {
                    g: (None if any(v is None for v in vals) else statistics.mean(vals))
                    for g, vals in regs.items()
                }  # type: ignore[union-attr]
                for m, regs in ms.items()
            }
            for d, ms in out.items()
        }

    def seconds(self) -> dict[str, dict[str, dict[str, float | None]]]:
        out: dict[str, dict[str, dict[str, list[float | None]]]] = {}
        for r in self.rows:
            out.setdefault(str(r["d"]), {}).setdefault(r["method"], {}).setdefault(r["regime"], []).append(
                r["seconds"]
            )
        return {
            d: {
                m: {
                    g: (None if any(v is None for v in vals) else statistics.mean(vals))
                    for g, vals in regs.items()
                }
                for m, regs in ms.items()
            }
            for d, ms in out.items()
        }

    def to_dict(self) -> dict[str, Any]:
        return {
            "shd": self.summary(),
            "seconds": self.seconds(),
            "rows": self.rows,
            "config": self.config,
            "causal_learn": peers.available(),
        }

    def to_markdown(self) -> str:
        shd_ = self.summary()
        secs = self.seconds()
        lines = [
            "# Structure learning on synthetic nonlinear additive-noise SCMs",
            "",
            f"n = {self.config['n']} observational rows, standardised; interventional regimes add "
            f"{self.config['interventions']} interventions x {self.config['rows_per_intervention']} rows. "
            f"Seeds {self.config['seeds']}. SHD (lower is better); peers' undirected edges count 1.",
            "",
        ]
        rows = []
        for d, ms in shd_.items():
            for m, regs in ms.items():
                for g in self.config["regimes"]:
                    if g in regs:
                        rows.append([d, m, g, regs[g], secs[d][m][g]])
        lines.append(markdown_table(["d", "method", "regime", "SHD", "seconds"], rows))
        return "\n".join(lines) + "\n"

    def figures(self) -> dict[str, Any]:
        import matplotlib.pyplot as plt

        shd_ = self.summary()
        fig, axes = plt.subplots(
            1, len(self.config["regimes"]), figsize=(4 * len(self.config["regimes"]), 3), squeeze=False
        )
        for ax, regime in zip(axes[0], self.config["regimes"], strict=True):
            methods = sorted({m for ms in shd_.values() for m in ms})
            dims = list(shd_)
            for k, m in enumerate(methods):
                vals = [shd_[d].get(m, {}).get(regime) for d in dims]
                xs = [i + 0.8 * k / len(methods) for i in range(len(dims))]
                ax.bar(xs, [v if v is not None else 0 for v in vals], width=0.8 / len(methods), label=m)
            ax.set_xticks([i + 0.4 - 0.4 / len(methods) for i in range(len(dims))], [f"d={d}" for d in dims])
            ax.set_title(regime, fontsize=9)
            ax.set_ylabel("SHD")
        axes[0][0].legend(fontsize=7)
        fig.tight_layout()
        return {"shd": fig}


def _matrix(data: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray:
    x = np.concatenate([data[n] for n in names], 1)
    return (x - x.mean(0)) / x.std(0)


def _standardised(data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: (v - v.mean(0)) / v.std(0) for k, v in data.items()}


def run_synthetic(config: Config, progress_bar: bool = False) -> DiscoveryExperiment:
    for g in config.regimes:
        if g not in REGIMES:
            raise ValueError(f"regime {g!r} unknown; expected some of {REGIMES}")
    rows: list[dict[str, Any]] = []
    jobs = [(d, s) for d in config.dims for s in config.seeds]
    use_peers = config.peers and peers.available()
    if use_peers:  # warm up: imports and first-call costs stay out of the timings
        warm = np.random.default_rng(0).normal(size=(50, 3))
        for method in peers.PEERS:
            peers.run_peer(method, warm, ["a", "b", "c"], seed=0)
    for d, seed in tqdm(jobs, desc="discovery", disable=not progress_bar):
        scm = random_scm(d, config.expected_parents, seed=1000 * d + seed)
        truth = scm.graph
        names = truth.names
        obs = scm.sample(config.n, seed=seed)
        datasets: dict[str, tuple[dict[str, np.ndarray], dict[str, np.ndarray] | None]] = {}
        if "observational" in config.regimes:
            datasets["observational"] = (obs, None)
        first = None  # the observational result, reused by the design and the observational row
        first_seconds = 0.0
        need_int = [g for g in config.regimes if g != "observational"]
        budget = config.interventions
        for regime in need_int:
            if regime == "interventional":
                start = time.perf_counter()
                if first is None:
                    first = discover(truth, _standardised(obs), seed=seed)
                    first_seconds = time.perf_counter() - start
                margins = orientation_margins(first, _standardised(obs))
                chosen = choose_interventions(first, margins, budget)
                design_seconds = time.perf_counter() - start
            else:
                rng = np.random.default_rng([seed, d, 7])
                chosen = [str(t) for t in rng.choice(names, budget)]
                design_seconds = 0.0
            targets = [t for t in chosen for _ in range(config.rows_per_intervention)]
            idata, imask = scm.intervene(targets, seed=seed + 17)
            full = {k: np.concatenate([obs[k], idata[k]]) for k in names}
            masks = {k: np.concatenate([np.zeros(config.n, bool), imask[k]]) for k in names}
            datasets[regime] = (full, masks)
            log.info(
                "d=%d seed=%d %s: %d targets, design %.1f s",
                d,
                seed,
                regime,
                len(set(chosen)),
                design_seconds,
            )
        for regime, (data, masks) in datasets.items():
            std = _standardised(data)
            methods = ["pal"] + (["pal_gated"] if d <= config.gated_max_d else [])
            for method in methods:
                start = time.perf_counter()
                if method == "pal" and regime == "observational" and first is not None:
                    res, elapsed = first, first_seconds  # the same call as the design's
                else:
                    res = discover(
                        truth,
                        std,
                        intervened=masks,
                        seed=seed,
                        sparsify="gated" if method == "pal_gated" else "none",
                    )
                    elapsed = time.perf_counter() - start
                rows.append(
                    {
                        "d": d,
                        "seed": seed,
                        "regime": regime,
                        "method": method,
                        "shd": shd(res.graph, truth),
                        "edges": len(res.graph.edges),
                        "true_edges": len(truth.edges),
                        "seconds": elapsed,
                    }
                )
            for method in peers.PEERS:
                row = {
                    "d": d,
                    "seed": seed,
                    "regime": regime,
                    "method": method,
                    "true_edges": len(truth.edges),
                }
                if use_peers:
                    g = peers.run_peer(method, _matrix(data, names), names, seed=seed)
                    row |= {
                        "shd": peers.cpdag_shd(g.directed, g.undirected, truth.edges),
                        "shd_undirected_free": peers.cpdag_shd(
                            g.directed, g.undirected, truth.edges, undirected_cost=0.0
                        ),
                        "edges": len(g.directed) + len(g.undirected),
                        "undirected": len(g.undirected),
                        "seconds": g.seconds,
                    }
                else:
                    row |= {"shd": None, "edges": None, "seconds": None}
                rows.append(row)
    cfg = {
        k: v
        for k, v in asdict(config).items()
        if k not in ("body", "mjcf", "joint", "actuator", "transitions", "epochs", "batch_size", "b1_seeds")
    }
    return DiscoveryExperiment(cfg, rows)


def run(config: Config, progress_bar: bool = False) -> Any:
    """Synthetic evaluation, or the body study when ``config.body`` or ``config.mjcf`` is set."""
    if config.body is not None or config.mjcf is not None:
        from pal.experiments.discovery_body import run_body

        return run_body(config, progress_bar=progress_bar)
    return run_synthetic(config, progress_bar=progress_bar)


def quick_config(**changes: Any) -> Config:
    """``Config.quick()`` with changes (for tests and notebooks)."""
    return replace(Config.quick(), **changes)
