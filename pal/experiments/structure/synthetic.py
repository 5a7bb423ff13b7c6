"""Experiment ``discovery``: structure learning on synthetic nonlinear SCMs, against GRaSP and PC.

For every d in ``scm.dims`` and seed, a random nonlinear additive-noise SCM
(:mod:`pal.experiments.structure.scm`) gives ``n`` observational rows. Every method sees
the data standardised (each column to zero mean and unit sd), so no method can exploit
the variance ordering of simulated data. Regimes:

- ``observational``: the n rows;
- ``interventional``: plus ``interventions.count`` agent-chosen interventions, each
  ``do(X_j = v)`` on one variable for ``interventions.rows`` rows with v uniform on
  mean +- 2 sd; the targets come from :func:`inference.design.choose_interventions` on the
  observational result;
- ``interventional_random``: the same budget with uniformly random targets.

Methods: ``pal`` (:func:`inference.discover`), ``pal_gated`` (with group-lasso-gated MLP
sparsification, for d <= ``gated.max_d``), and causal-learn's GRaSP (BIC) and PC (Fisher-z)
when causal-learn is importable (``None`` otherwise). The peers do not model
interventions: they get the pooled rows. SHD counts missing, extra and reversed edges;
for the peers' CPDAGs an undirected edge also counts 1.

Metrics: ``shd`` and ``seconds`` as ``{d: {method: {regime: mean over seeds}}}`` (None where
a method did not run), ``rows`` (one per d, seed, regime and method: shd, edges,
true_edges, seconds; the peers also shd_undirected_free and undirected), ``seeds`` and
``causal_learn``. Targets: on every seed, pal's SHD is at most GRaSP's (observational, and
with the agent's interventions).
"""

from __future__ import annotations

import logging
import statistics
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from inference.design import choose_interventions, orientation_margins
from inference.discovery import DiscoveryOptions, DiscoveryResult, discover, shd
from pal.baselines import discovery_peers as peers
from pal.checks import check_choice, check_int
from pal.experiments.structure.scm import SCMConfig, SyntheticSCM, standardised
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["METHODS", "REGIMES", "Config", "InterventionConfig", "run"]

log = logging.getLogger(__name__)

REGIMES = ("observational", "interventional", "interventional_random")
METHODS = ("pal", "pal_gated", *peers.PEERS)
#: Regimes whose SHD is held against GRaSP's, seed by seed.
JUDGED = ("observational", "interventional")

Row = dict[str, Any]


@dataclass(frozen=True)
class InterventionConfig:
    """The budget of the interventional regimes.

    Attributes:
        count: interventions ``do(X_j = v)``, each on one variable.
        rows: rows recorded per intervention.
    """

    count: int = 50
    rows: int = 10

    def __post_init__(self) -> None:
        check_int("count", self.count)
        check_int("rows", self.rows)


@dataclass(frozen=True)
class GatedConfig:
    """The ``pal_gated`` method: group-lasso-gated MLP sparsification (:mod:`inference.gated`).

    Attributes:
        max_d: run it for d up to this size (0: never).
        num_steps: Adam steps of the gated MLPs per penalty.
    """

    max_d: int = 20
    num_steps: int = 300

    def __post_init__(self) -> None:
        check_int("num_steps", self.num_steps)
        check_int("max_d", self.max_d, minimum=0)


@dataclass(frozen=True)
class Config:
    """Synthetic structure learning.

    Attributes:
        seed: the first seed; the run uses ``seed, ..., seed + repeats - 1`` (each seeds its
            SCM, data, interventions and the learners).
        repeats: seeds per size.
        scm: sizes of the synthetic SCMs.
        interventions: budget of the interventional regimes.
        regimes: some of :data:`REGIMES`.
        peers: run GRaSP and PC when causal-learn is installed.
        gated: when and how ``pal_gated`` runs.
    """

    seed: int = 0
    repeats: int = 4
    scm: SCMConfig = SCMConfig()
    interventions: InterventionConfig = InterventionConfig()
    regimes: tuple[str, ...] = REGIMES
    peers: bool = True
    gated: GatedConfig = GatedConfig()

    def __post_init__(self) -> None:
        check_int("repeats", self.repeats)
        regimes = tuple(check_choice("regime", g, REGIMES) for g in self.regimes)
        if not regimes or len(set(regimes)) != len(regimes):
            raise ValueError(f"regimes {list(regimes)} invalid; expected distinct names from {list(REGIMES)}")
        object.__setattr__(self, "regimes", regimes)

    @property
    def seeds(self) -> list[int]:
        """The seeds of the run."""
        return [self.seed + k for k in range(self.repeats)]


QUICK = Config(
    repeats=1, scm=SCMConfig(dims=(10,), n=400), interventions=InterventionConfig(20), gated=GatedConfig(0)
)
TINY = Config(
    repeats=1,
    scm=SCMConfig(dims=(5,), n=150),
    interventions=InterventionConfig(4, 5),
    gated=GatedConfig(5, 20),
)


def _timed_discover(
    config: Config,
    scm: SyntheticSCM,
    data: dict[str, np.ndarray],
    masks: dict[str, np.ndarray] | None,
    seed: int,
    method: str = "pal",
) -> tuple[DiscoveryResult, float]:
    """:func:`inference.discover` (``method`` pal or pal_gated) on the standardised ``data``, and its wall time in s."""
    start = time.perf_counter()
    std = standardised(data)
    if method == "pal_gated":
        options = DiscoveryOptions(sparsify="gated", gated={"steps": config.gated.num_steps})
        res = discover(scm.graph, std, intervened=masks, options=options, seed=seed)
    else:
        res = discover(scm.graph, std, intervened=masks, seed=seed)
    return res, time.perf_counter() - start


def _regime_data(
    config: Config,
    scm: SyntheticSCM,
    obs: dict[str, np.ndarray],
    regime: str,
    first: DiscoveryResult,
    seed: int,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray] | None]:
    """Rows of ``regime`` and the ``intervened`` masks (None for observational rows)."""
    if regime == "observational":
        return obs, None
    names = scm.graph.names
    budget = config.interventions.count
    if regime == "interventional":
        chosen = choose_interventions(first, orientation_margins(first, standardised(obs)), budget)
    else:
        rng = np.random.default_rng([seed, len(names), 7])
        chosen = [str(t) for t in rng.choice(names, budget)]
    log.info("d=%d seed=%d %s: %d distinct targets", len(names), seed, regime, len(set(chosen)))
    idata, imask = scm.intervene(
        [t for t in chosen for _ in range(config.interventions.rows)], seed=seed + 17
    )
    n = config.scm.n
    data = {k: np.concatenate([obs[k], idata[k]]) for k in names}
    return data, {k: np.concatenate([np.zeros(n, bool), imask[k]]) for k in names}


def _one_scm(config: Config, d: int, seed: int, use_peers: bool) -> list[Row]:
    """One row per regime and method for the SCM of size ``d`` and ``seed``."""
    scm, obs = config.scm.draw(d, seed)
    truth = scm.graph
    # pal on the observational rows: its own row, and the input of the agent's design
    first, first_seconds = _timed_discover(config, scm, obs, None, seed)
    methods = ["pal"] + (["pal_gated"] if d <= config.gated.max_d else []) + list(peers.PEERS)
    rows = []
    for regime in config.regimes:
        data, masks = _regime_data(config, scm, obs, regime, first, seed)
        for method in methods:
            row: Row = {
                "d": d,
                "seed": seed,
                "regime": regime,
                "method": method,
                "true_edges": len(truth.edges),
            }
            if method in peers.PEERS:
                empty = {"shd": None, "edges": None, "seconds": None}
                row |= peers.compare(method, standardised(data), truth, seed=seed) if use_peers else empty
            else:
                if method == "pal" and regime == "observational":
                    res, seconds = first, first_seconds
                else:
                    res, seconds = _timed_discover(config, scm, data, masks, seed, method)
                row |= {"shd": shd(res.graph, truth), "edges": len(res.graph.edges), "seconds": seconds}
            rows.append(row)
    return rows


def _means(rows: list[Row], key: str) -> dict[str, dict[str, dict[str, float | None]]]:
    """``{d: {method: {regime: mean of key over seeds}}}``; None where any seed has None."""
    groups: dict[str, dict[str, dict[str, list[Any]]]] = {}
    for r in rows:
        groups.setdefault(str(r["d"]), {}).setdefault(r["method"], {}).setdefault(r["regime"], []).append(
            r[key]
        )
    return {
        d: {
            m: {g: None if None in v else float(statistics.mean(v)) for g, v in regs.items()}
            for m, regs in ms.items()
        }
        for d, ms in groups.items()
    }


def _pairs(rows: list[Row]) -> dict[tuple[int, int, str], dict[str, Any]]:
    """(d, seed, regime) -> method -> SHD."""
    out: dict[tuple[int, int, str], dict[str, Any]] = {}
    for r in rows:
        out.setdefault((r["d"], r["seed"], r["regime"]), {})[r["method"]] = r["shd"]
    return out


def _tables(config: Config, rows: list[Row]) -> list[Table]:
    shd_, edges, seconds = _means(rows, "shd"), _means(rows, "edges"), _means(rows, "seconds")
    true = _means(rows, "true_edges")
    summary = [
        (int(d), m, g, shd_[d][m][g], edges[d][m][g], true[d][m][g], seconds[d][m][g])
        for d, ms in shd_.items()
        for m, regs in ms.items()
        for g in regs
    ]
    per_seed = []
    for (d, seed, regime), by in _pairs(rows).items():
        pal, grasp = by["pal"], by.get("grasp")
        per_seed.append((d, seed, regime, pal, grasp, by.get("pc"), None if grasp is None else pal - grasp))
    return [
        Table(
            f"SHD per size, method and regime (mean over seeds {config.seeds})",
            ("d", "method", "regime", "SHD", "learnt edges", "true edges", "seconds"),
            summary,
            "SHD counts missing, extra and reversed edges; a peer's undirected edge counts 1.",
        ),
        Table(
            "pal against the peers, seed by seed",
            ("d", "seed", "regime", "pal SHD", "GRaSP SHD", "PC SHD", "pal - GRaSP"),
            per_seed,
        ),
    ]


def _targets(config: Config, rows: list[Row]) -> list[Target]:
    """Per d and judged regime: the largest pal - GRaSP SHD over the seeds, <= 0."""
    pairs = _pairs(rows)
    targets = []
    for d in config.scm.dims:
        for regime in (g for g in JUDGED if g in config.regimes):
            diffs = [
                by["pal"] - by["grasp"]
                for (dd, _, g), by in pairs.items()
                if (dd, g) == (d, regime) and by.get("grasp") is not None
            ]
            what = (
                "observational rows" if regime == "observational" else "with the agent-chosen interventions"
            )
            targets.append(
                Target(
                    f"shd_minus_grasp.{regime}.d{d}",
                    max(diffs) if len(diffs) == config.repeats else None,
                    0.0,
                    "<=",
                    f"largest SHD of pal minus GRaSP's over seeds {config.seeds}, d = {d}, {what} "
                    "(edges; GRaSP gets the pooled rows)",
                )
            )
    return targets


@register("discovery", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Structure learning on synthetic nonlinear SCMs: SHD per d, method and regime, against GRaSP and PC."""
    use_peers = config.peers and peers.available()
    if use_peers:
        peers.warm_up()
    rows: list[Row] = []
    jobs = [(d, s) for d in config.scm.dims for s in config.seeds]
    for d, seed in tqdm(jobs, desc="discovery", disable=not progress_bar):
        rows += _one_scm(config, d, seed, use_peers)
    shd_ = _means(rows, "shd")
    budget = config.interventions
    notes = [
        f"Random nonlinear additive-noise SCMs (tanh-MLP mechanisms, {config.scm.expected_parents} expected "
        f"parents per variable), n = {config.scm.n} observational rows, every column standardised.",
        f"The interventional regimes add {budget.count} interventions x {budget.rows} rows, chosen by the agent "
        "from the observational result or uniformly at random; GRaSP and PC get the pooled rows.",
    ]
    if not use_peers:
        notes.append("causal-learn is not installed or peers are off, so GRaSP and PC did not run (n/a).")
    return Report(
        title="Structure learning on synthetic nonlinear SCMs",
        metrics={
            "shd": shd_,
            "seconds": _means(rows, "seconds"),
            "rows": rows,
            "seeds": config.seeds,
            "causal_learn": peers.available(),
        },
        tables=_tables(config, rows),
        targets=_targets(config, rows),
        notes=notes,
        figures={"shd": _figure(shd_, config.regimes)},
    )


def _figure(shd_: dict[str, dict[str, dict[str, float | None]]], regimes: tuple[str, ...]) -> Figure:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(regimes), figsize=(4 * len(regimes), 3), squeeze=False)
    dims = list(shd_)
    methods = [m for m in METHODS if any(m in ms for ms in shd_.values())]
    width = 0.8 / len(methods)
    for ax, regime in zip(axes[0], regimes, strict=True):
        for k, m in enumerate(methods):
            vals = [shd_[d].get(m, {}).get(regime) for d in dims]
            xs = [i + width * k for i in range(len(dims))]
            ax.bar(xs, [0.0 if v is None else v for v in vals], width=width, label=m)
        ax.set_xticks([i + 0.4 - width / 2 for i in range(len(dims))], [f"d={d}" for d in dims])
        ax.set(title=regime, ylabel="SHD [edges]")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    return fig
