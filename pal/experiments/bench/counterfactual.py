"""``pal bench counterfactual``: exact counterfactuals against ChiRho and DoWhy-GCM.

Figures, each for :func:`inference.counterfactual` and for each peer library on the same
SCMs in the same run (:mod:`pal.baselines.counterfactual_peers`):

* ``chain_unit_ms``: one unit of the chain X -> Y -> Z, ``Y = 2X + U_y``,
  ``Z = -1.5Y + U_z``, ``U ~ N(0, 1)``, factual (1, 2.5, -3), ``do(X = 0)``.
* ``mlp50_unit_ms``: one unit of a random 50-node SCM with default MLP mechanisms,
  ``do`` on the root with the most descendants.
* ``units_per_s``: a batch of 10 000 chain units in one call.
* ``scenarios_ms``: K = 1, 2, 8, 32 scenarios (different ``do`` values) on the MLP SCM
  with 1 000 units, one call each; our K calls are timed interleaved, so a change in
  machine load hits every K alike. ``scenario_growth[lib]`` holds a library's time for K
  scenarios over its time for one (wall and CPU), and its CPU ms per added scenario;
  ``scenario_growth["pal_over_chirho_cpu"][K]`` is our CPU growth over ChiRho's for each K
  (:mod:`pal.experiments.bench.counterfactual_render`). ``compute_growth_bound[K]`` is the
  growth of pal's mechanism evaluations alone (abduction once, the descendants per scenario).

``ratios[peer]`` is ours / peer for the times and peer / ours for ``units_per_s``, so a
ratio below 1 always means that pal is faster. Every figure is a median after a warm-up
call (:mod:`pal.lab.timing`). Peer answers are checked against ours; a mismatch is
logged as a warning.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor
from tqdm.auto import tqdm

from inference.counterfactual import counterfactual
from models.mechanisms import LinearMechanism
from models.presets import chain_graph, random_graph
from models.world import WorldModel
from pal.baselines.counterfactual_peers import available, make_peer
from pal.checks import check_float, check_int
from pal.experiments.bench.counterfactual_render import (
    compute_bound,
    growth,
    scenario_figure,
    scenario_summary,
    table,
)
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Target
from pal.lab.timing import Timing, measure, measure_interleaved, ratio, torch_threads

__all__ = [
    "CHAIN_WEIGHTS",
    "Config",
    "PeerFigures",
    "chain_model",
    "intervention_node",
    "mlp_model",
    "ratios",
    "run",
]

log = logging.getLogger(__name__)

#: Y = 2 X + U_y, Z = -1.5 Y + U_z
CHAIN_WEIGHTS = {"y": 2.0, "z": -1.5}
#: the single chain unit and its intervention do(X = 0)
CHAIN_UNIT = {"x": 1.0, "y": 2.5, "z": -3.0}
CHAIN_DO = 0.0
#: agreement tolerance between libraries (float32 mechanisms)
TOLERANCE = 1e-4

FIGURES = ("chain_unit_ms", "mlp50_unit_ms", "units_per_s", "scenarios_ms")


@dataclass(frozen=True)
class Config:
    """Sizes and repetitions.

    Attributes:
        seed: seeds the MLP graph, its weights and the factual samples.
        mlp_nodes: nodes of the random MLP SCM (50 for the ``mlp50`` figure).
        chain_units: batch size of ``units_per_s``.
        scenario_units: units of each ``scenarios_ms`` call.
        scenarios: the numbers of scenarios K.
        repeats: timed repeats of the single-unit figures (median reported).
        batch_repeats: timed repeats of the batch and scenario figures.
        peers: peer libraries to compare with (skipped when not importable).
        peer_repeats: timed repeats for the peers (they are much slower).
        peer_budget_s: above this estimated time for one call, a peer is measured on
            fewer units and scaled linearly (noted in its ``notes``).
        threads: torch threads during the run (None: leave as is).
    """

    seed: int = 0
    mlp_nodes: int = 50
    chain_units: int = 10_000
    scenario_units: int = 1_000
    scenarios: tuple[int, ...] = (1, 2, 8, 32)
    repeats: int = 50
    batch_repeats: int = 5
    peers: tuple[str, ...] = ("chirho", "dowhy")
    peer_repeats: int = 3
    peer_budget_s: float = 60.0
    threads: int | None = 1

    def __post_init__(self) -> None:
        check_int("mlp_nodes", self.mlp_nodes, minimum=2)
        check_int("chain_units", self.chain_units)
        check_int("scenario_units", self.scenario_units)
        if not self.scenarios:
            raise ValueError("scenarios is empty; give the numbers of scenarios K, e.g. (1, 8)")
        for k in self.scenarios:
            check_int("scenarios", k)
        for name in ("repeats", "batch_repeats", "peer_repeats"):
            check_int(name, getattr(self, name))
        check_float("peer_budget_s", self.peer_budget_s, 0.0, open_low=True)
        for name in self.peers:
            available(name)  # raises on unknown names


@dataclass(frozen=True)
class PeerFigures:
    """The four figures for one library; ``notes`` say how they were obtained."""

    chain_unit_ms: float
    mlp50_unit_ms: float
    units_per_s: float
    scenarios_ms: dict[str, float]
    notes: tuple[str, ...] = ()
    scenarios_cpu_ms: dict[str, float] = dataclasses.field(default_factory=dict)


def ratios(ours: PeerFigures, peer: PeerFigures) -> dict[str, Any]:
    """Speed ratio per figure: ours / peer (peer / ours for ``units_per_s``); < 1: pal is faster."""
    return {
        "chain_unit_ms": ratio(ours.chain_unit_ms, peer.chain_unit_ms),
        "mlp50_unit_ms": ratio(ours.mlp50_unit_ms, peer.mlp50_unit_ms),
        "units_per_s": ratio(peer.units_per_s, ours.units_per_s),
        "scenarios_ms": {k: ratio(v, peer.scenarios_ms.get(k)) for k, v in ours.scenarios_ms.items()},
    }


# ---------------------------------------------------------------------------- models
def chain_model() -> WorldModel:
    """The linear chain X -> Y -> Z with ``CHAIN_WEIGHTS`` and unit noise."""
    mechs = {k: LinearMechanism.from_coefficients([[w]]) for k, w in CHAIN_WEIGHTS.items()}
    return WorldModel(chain_graph(), mechs)


def mlp_model(nodes: int, seed: int) -> WorldModel:
    """``random_graph(nodes, seed)`` with default MLP mechanisms, weights seeded by ``seed``."""
    return WorldModel(random_graph(nodes, seed=seed), seed=seed)


def intervention_node(model: WorldModel) -> str:
    """The root with the most descendants (the first such in name order)."""
    graph = model.graph
    best = max(graph.roots, key=lambda r: len(graph.descendants(r)))
    if not graph.descendants(best):
        raise ValueError("the graph has no root with descendants; a do() there would change nothing")
    return best


def _values(k: int) -> list[float]:
    """K distinct intervention values."""
    return [0.5 * (i + 1) for i in range(k)]


def _max_diff(a: dict[str, Tensor], b: dict[str, Tensor]) -> float:
    return max(float((a[k].reshape(-1) - b[k].reshape(-1)).abs().max()) for k in a)


# ---------------------------------------------------------------------------- run
def _ours(config: Config, chain: WorldModel, mlp: WorldModel, data: dict[str, Any]) -> dict[str, Timing]:
    node = data["node"]
    out = {
        "chain_unit": measure(
            lambda: counterfactual(chain, data["chain_unit"], {"x": CHAIN_DO}), config.repeats
        ),
        "mlp_unit": measure(lambda: counterfactual(mlp, data["mlp_unit"], {node: 1.0}), config.repeats),
        "batch": measure(
            lambda: counterfactual(chain, data["chain_batch"], {"x": CHAIN_DO}), config.batch_repeats
        ),
    }

    def call(k: int) -> Callable[[], Any]:
        scenarios = [{node: v} for v in _values(k)]
        return lambda: counterfactual(mlp, data["scenario"], scenarios)

    calls = {f"k{k}": call(k) for k in config.scenarios}
    out.update(measure_interleaved(calls, config.batch_repeats))
    return out


def _peer_call(
    peer: Any,
    config: Config,
    which: str,
    data: Any,
    size: int,
    node: str,
    values: list[float],
    what: str,
    notes: list[str],
) -> tuple[float, Any, int, float]:
    """Median seconds of one peer call on ``size`` units, scaled from a subset when over budget.

    A call on ``min(size, 100)`` units is the warm-up and the probe: when it extrapolates
    linearly to more than ``peer_budget_s`` for the full size, the timed calls use fewer
    units and the time is scaled linearly (and noted).

    Returns the seconds for the full size, the last output, the units it covers and the CPU
    seconds for the full size.
    """
    probe_n = min(size, 100)
    probe = measure(lambda: peer.run(which, peer.subset(data, probe_n), node, values), repeats=1)
    estimate = probe.median * size / probe_n
    n = size
    if estimate > config.peer_budget_s:
        n = max(probe_n, int(size * config.peer_budget_s / estimate))
    timing = measure(
        lambda: peer.run(which, peer.subset(data, n), node, values), config.peer_repeats, warmup=0
    )
    if n < size:
        notes.append(
            f"{what}: one call on {size} units was estimated at {estimate:.0f} s; measured on {n} units "
            "and scaled linearly"
        )
    return timing.median * size / n, timing.result, n, timing.cpu_median * size / n


def _peer(
    name: str, config: Config, chain: WorldModel, mlp: WorldModel, data: dict[str, Any], ours: dict[str, Any]
) -> tuple[PeerFigures, float]:
    peer = make_peer(name, chain, CHAIN_WEIGHTS, mlp)
    node = data["node"]
    native = {k: peer.native(data[k]) for k in ("chain_unit", "mlp_unit", "chain_batch", "scenario")}
    notes: list[str] = []
    unit = measure(lambda: peer.run("chain", native["chain_unit"], "x", [CHAIN_DO]), config.peer_repeats)
    mlp_unit = measure(lambda: peer.run("mlp", native["mlp_unit"], node, [1.0]), config.peer_repeats)
    batch_s, batch_out, batch_n, _ = _peer_call(
        peer,
        config,
        "chain",
        native["chain_batch"],
        config.chain_units,
        "x",
        [CHAIN_DO],
        "units_per_s",
        notes,
    )
    scenarios: dict[str, float] = {}
    scenarios_cpu: dict[str, float] = {}
    diffs = []
    for k in config.scenarios:
        sec, out, n, cpu = _peer_call(
            peer,
            config,
            "mlp",
            native["scenario"],
            config.scenario_units,
            node,
            _values(k),
            f"{k} scenarios",
            notes,
        )
        scenarios[str(k)] = 1e3 * sec
        scenarios_cpu[str(k)] = 1e3 * cpu
        theirs = peer.to_tensors(out, node, k, n)
        diffs.append(_max_diff(theirs, {v: t[:, :n] for v, t in ours[f"k{k}"].items()}))
    chain_cf = peer.to_tensors(batch_out, "x", 1, batch_n)
    chain_diff = _max_diff(chain_cf, {v: t[:, :batch_n] for v, t in ours["chain_batch"].items()})
    unit_cf = peer.to_tensors(unit.result, "x", 1, 1)
    chain_diff = max(chain_diff, _max_diff(unit_cf, ours["chain_unit"]))
    mlp_diff = max(diffs)
    for what, diff in (("chain", chain_diff), (f"{config.mlp_nodes}-node MLP", mlp_diff)):
        if not diff <= TOLERANCE:
            log.warning(
                "%s disagrees with pal on the %s counterfactual: max |diff| = %.3g > %g",
                name,
                what,
                diff,
                TOLERANCE,
            )
    notes.append(f"counterfactuals agree with pal: max |diff| {chain_diff:.2g} (chain), {mlp_diff:.2g} (MLP)")
    if name == "chirho":
        notes.append("K scenarios: one call, do() with a tuple of K values (K + 1 worlds)")
    else:
        notes.append("K scenarios: K counterfactual_samples calls, one per intervention")
    figs = PeerFigures(
        unit.ms, mlp_unit.ms, config.chain_units / batch_s, scenarios, tuple(notes), scenarios_cpu
    )
    return figs, max(chain_diff, mlp_diff)


def _growth_targets(config: Config, libs: dict[str, PeerFigures | None]) -> list[Target]:
    """CPU time of K = 8 scenarios (else the largest K) over one, alone and against ChiRho's.

    CPU time of the calling thread (one torch thread): wall time also counts the other
    processes of a loaded machine.
    """
    first = str(config.scenarios[0])
    k = "8" if 8 in config.scenarios[1:] else str(config.scenarios[-1])
    ours = growth(libs["pal"].scenarios_cpu_ms, first)[k] if libs["pal"] is not None else None
    chirho = libs.get("chirho")
    theirs = None if chirho is None else growth(chirho.scenarios_cpu_ms, first)[k]
    return [
        Target(
            f"scenarios_{k}_vs_{first}",
            ours,
            1.5,
            "<=",
            f"CPU time of {k} scenarios / CPU time of {first}",
            Precondition.nonzero(ours, f"the time of {first} scenarios"),
        ),
        Target(
            f"scenarios_{k}_vs_{first}_vs_chirho",
            ratio(ours, theirs),
            1.0,
            "<",
            f"our CPU-time growth from {first} to {k} scenarios / ChiRho's in the same run",
            Precondition.nonzero(theirs, "ChiRho's growth (not measured without the bench extra)"),
        ),
    ]


def _targets(
    config: Config,
    pal: PeerFigures,
    libs: dict[str, PeerFigures | None],
    rel: dict[str, Any],
) -> list[Target]:
    """Our unit time, batch rate and scenario growth; our time per unit against each peer's."""
    return [
        Target("chain_unit_ms", pal.chain_unit_ms, 2.0, "<=", "one chain unit, ms"),
        Target(
            "units_per_s",
            pal.units_per_s,
            3e5,
            ">=",
            f"chain units per second in a batch of {config.chain_units}",
        ),
        *_growth_targets(config, libs),
        *(
            Target(
                f"{figure}_vs_{name}",
                None if rel[name] is None else rel[name][figure],
                0.5,
                "<=",
                f"our time per unit / {name}'s ({label}; not measured without the bench extra)",
                Precondition.nonzero(
                    None if libs[name] is None else getattr(libs[name], figure), f"{name}'s time per unit"
                ),
            )
            for name in ("chirho", "dowhy")
            for figure, label in (("chain_unit_ms", "3-node chain"), ("mlp50_unit_ms", "MLP SCM"))
        ),
    ]


@register(
    "counterfactual",
    kind="bench",
    config=Config,
    quick=Config(
        mlp_nodes=10,
        chain_units=500,
        scenario_units=50,
        repeats=3,
        batch_repeats=2,
        peer_repeats=1,
        peer_budget_s=5.0,
    ),
    tiny=Config(
        mlp_nodes=4,
        chain_units=50,
        scenario_units=10,
        scenarios=(1, 2),
        repeats=1,
        batch_repeats=1,
        peers=(),
        peer_repeats=1,
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Exact counterfactuals: time per unit, units/s and K-scenario scaling against ChiRho and DoWhy-GCM."""
    with torch_threads(config.threads):
        chain, mlp = chain_model(), mlp_model(config.mlp_nodes, config.seed)
        node = intervention_node(mlp)
        gen = torch.Generator().manual_seed(config.seed)
        data = {
            "node": node,
            "chain_unit": {k: torch.tensor([[v]]) for k, v in CHAIN_UNIT.items()},
            "chain_batch": chain.sample(config.chain_units, gen),
            "mlp_unit": mlp.sample(1, gen),
            "scenario": mlp.sample(config.scenario_units, gen),
        }
        peers = [p for p in config.peers if available(p)]
        bar = tqdm(total=1 + len(peers), desc="bench counterfactual", disable=not progress_bar, leave=False)
        log.info("timing pal (do on %s of the %d-node MLP SCM)", node, config.mlp_nodes)
        timings = _ours(config, chain, mlp, data)
        # our answers for the agreement checks: key -> name -> (K, N, 1) (S = 1 dropped)
        keys = {
            "chain_unit": "chain_unit",
            "chain_batch": "batch",
            **{f"k{k}": f"k{k}" for k in config.scenarios},
        }
        ours = {
            key: {v: t[0] for v, t in timings[t_key].result.samples.items()} for key, t_key in keys.items()
        }
        bar.update()
        pal = PeerFigures(
            timings["chain_unit"].ms,
            timings["mlp_unit"].ms,
            config.chain_units / timings["batch"].median,
            {str(k): timings[f"k{k}"].ms for k in config.scenarios},
            scenarios_cpu_ms={str(k): 1e3 * timings[f"k{k}"].cpu_median for k in config.scenarios},
        )
        libs: dict[str, PeerFigures | None] = {"pal": pal, "chirho": None, "dowhy": None}
        agreement: dict[str, float] = {}
        for name in peers:
            log.info("timing %s", name)
            libs[name], agreement[name] = _peer(name, config, chain, mlp, data, ours)
            bar.update()
        bar.close()
    rel = {n: None if f is None else ratios(pal, f) for n, f in libs.items() if n != "pal"}
    first = str(config.scenarios[0])
    replayed = len(mlp.graph.descendants(node))
    bound = compute_bound(len(mlp.graph.non_roots), replayed, config.scenarios)
    sizes = {k: getattr(config, k) for k in ("mlp_nodes", "chain_units", "scenario_units")}
    notes = [
        f"do() on {node} in the MLP SCM; medians after a warm-up call; torch threads: {config.threads}.",
        f"pal evaluates {len(mlp.graph.non_roots)} mechanisms once (abduction) and the {replayed} descendants "
        f"of {node} once per scenario: those evaluations alone grow by "
        + ", ".join(f"{v:.2f}x for K = {k}" for k, v in bound.items() if k != first)
        + "; a measured growth below that comes from fixed costs.",
    ]
    for name in ("chirho", "dowhy"):
        fig = libs[name]
        notes += (
            [f"{name}: not installed or not asked for, skipped."]
            if fig is None
            else [f"{name}: {n}." for n in fig.notes]
        )
    return Report(
        title="Counterfactual benchmark",
        metrics={
            **{n: None if f is None else dataclasses.asdict(f) for n, f in libs.items()},
            "ratios": rel,
            "agreement": agreement,
            "scenario_growth": scenario_summary(libs, first),
            "compute_growth_bound": bound,
            "intervened": node,
        },
        tables=[table(sizes, config.scenarios, libs, rel)],
        targets=_targets(config, pal, libs, rel),
        notes=notes,
        figures={"scenarios": scenario_figure(sizes, libs)},
    )
