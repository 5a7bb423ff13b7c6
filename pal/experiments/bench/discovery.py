"""Benchmark ``discovery``: wall time of structure learning and of contextualised action inference.

1. :func:`inference.discover` on standardised data of the synthetic SCMs of
   :mod:`pal.experiments.structure.scm` (d in ``scm.dims``, ``n`` rows), against
   causal-learn's GRaSP and PC on the same data when causal-learn is importable (None
   otherwise). Figures: median seconds per call over ``repeats`` interleaved calls, and
   ``ratio_grasp`` = ours / GRaSP (> 1: ours is slower); SHD is reported beside them.
2. Action inference (Alg. 4.2) for one joint of a ``context.joints``-joint world model
   (:func:`models.joint_chain_graph`, state variant): on the whole graph, and on the active
   subgraph of the query (:func:`inference.context.active_subgraph`). Figures: seconds of
   each, ``ratio`` = subgraph / whole (< 1: the subgraph is faster), extraction seconds,
   and the largest action difference (the subgraph must give the whole graph's actions).
3. Weak data (:mod:`pal.experiments.structure.robust`): edges found on shuffled columns (the
   permutation baseline) and SHD on measurement-like simulated data against the empty graph,
   PC and GRaSP.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from inference import infer_action
from inference.context import active_subgraph, subgraph_model
from inference.discovery import discover, shd
from models import CausalGraph, WorldModel, joint_chain_graph
from pal.baselines import discovery_peers as peers
from pal.checks import check_int
from pal.experiments.structure.robust import RobustConfig, measurement_shd, permutation_edges
from pal.experiments.structure.scm import SCMConfig, standardised
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import measure_interleaved, ratio, torch_threads

__all__ = ["Config", "ContextConfig", "run"]

log = logging.getLogger(__name__)

#: Largest |action on the subgraph - action on the whole graph| counted as the same action.
SAME_ACTION = 1e-5


@dataclass(frozen=True)
class ContextConfig:
    """Action inference for the angle of one joint of a many-joint world model.

    Attributes:
        joints: joints of the model (4 variables each, 2 x 32 MLP mechanisms).
        targets: target angles inferred in one batch.
        num_steps: Adam iterations of Alg. 4.2.
    """

    joints: int = 50
    targets: int = 64
    num_steps: int = 100

    def __post_init__(self) -> None:
        check_int("joints", self.joints)
        check_int("targets", self.targets)
        check_int("num_steps", self.num_steps)


@dataclass(frozen=True)
class Config:
    """Benchmark sizes.

    Attributes:
        seed: seeds the SCMs, their data, the learners and the world model's weights.
        scm: sizes of the synthetic SCMs.
        context: the contextualisation query.
        robust: the permutation baseline and the measurement-like data.
        repeats: timed calls per figure (median).
        threads: torch intra-op threads during the timings (None: leave as is).
    """

    seed: int = 0
    scm: SCMConfig = SCMConfig(dims=(10, 20))
    context: ContextConfig = ContextConfig()
    robust: RobustConfig = RobustConfig()
    repeats: int = 3
    threads: int | None = 1

    def __post_init__(self) -> None:
        check_int("repeats", self.repeats)
        if self.threads is not None:
            check_int("threads", self.threads)


def _calls(
    graph: CausalGraph, std: dict[str, np.ndarray], seed: int, use_peers: bool
) -> dict[str, Callable[[], Any]]:
    """The timed calls on one SCM's standardised data: pal, and the peers when they run."""
    calls: dict[str, Callable[[], Any]] = {"pal": lambda: discover(graph, std, seed=seed)}
    if use_peers:
        calls |= {m: lambda m=m: peers.compare(m, std, graph, seed=seed) for m in peers.PEERS}
    return calls


def _discovery(config: Config, use_peers: bool) -> dict[str, dict[str, Any]]:
    """Per d: seconds and SHD of pal, GRaSP and PC, and the ratio to GRaSP."""
    out = {}
    for d in config.scm.dims:
        scm, data = config.scm.draw(d, config.seed)
        calls = _calls(scm.graph, standardised(data), config.seed, use_peers)
        timings = measure_interleaved(calls, repeats=config.repeats, warmup=0)
        row: dict[str, Any] = {
            "seconds": timings["pal"].median,
            "shd": shd(timings["pal"].result.graph, scm.graph),
        }
        for method in peers.PEERS:
            t = timings.get(method)
            row[f"{method}_seconds"] = None if t is None else t.median
            row[f"{method}_shd"] = None if t is None else t.result["shd"]
        row["ratio_grasp"] = ratio(row["seconds"], row["grasp_seconds"])
        log.info("d=%d: discover %.2f s (GRaSP %s s)", d, row["seconds"], row["grasp_seconds"])
        out[str(d)] = row
    return out


def _context(config: ContextConfig, seed: int, repeats: int) -> dict[str, Any]:
    """Seconds of Alg. 4.2 on the whole graph and on the query's active subgraph."""
    joints = [f"j{i}" for i in range(config.joints)]
    graph = joint_chain_graph(joints, dict.fromkeys(joints, (-1.0, 1.0)), "state")
    model = WorldModel(graph, hidden=(32, 32), seed=seed)
    samples = model.sample(256, torch.Generator().manual_seed(seed))
    target_joint = joints[len(joints) // 2]
    act, tgt = f"act.{target_joint}", f"q.{target_joint}"
    start = time.perf_counter()
    small = subgraph_model(model, active_subgraph(model, samples, [tgt]))
    extract = time.perf_counter() - start
    k = config.targets
    state = {n: samples[n][:k] for n in model.graph.roots if n != act}
    small_state = {n: v for n, v in state.items() if n in small.graph}
    target = {tgt: samples[tgt][k : 2 * k]}
    timings = measure_interleaved(
        {
            "whole": lambda: infer_action(model, state, target, actions=[act], num_steps=config.num_steps),
            "subgraph": lambda: infer_action(
                small, small_state, target, actions=[act], num_steps=config.num_steps
            ),
        },
        repeats=repeats,
    )
    diff = (timings["whole"].result.actions[act] - timings["subgraph"].result.actions[act]).abs().max()
    return {
        "joints": config.joints,
        "variables": len(model.graph),
        "subgraph_variables": len(small.graph),
        "targets": k,
        "steps": config.num_steps,
        "whole_seconds": timings["whole"].median,
        "subgraph_seconds": timings["subgraph"].median,
        "ratio": ratio(timings["subgraph"].median, timings["whole"].median),
        "extract_seconds": extract,
        "max_action_diff": float(diff),
    }


def _tables(disc: dict[str, dict[str, Any]], ctx: dict[str, Any]) -> list[Table]:
    rows = [
        (
            int(d),
            r["seconds"],
            r["shd"],
            r["grasp_seconds"],
            r["grasp_shd"],
            r["pc_seconds"],
            r["pc_shd"],
            r["ratio_grasp"],
        )
        for d, r in disc.items()
    ]
    keys = (
        "variables",
        "subgraph_variables",
        "whole_seconds",
        "subgraph_seconds",
        "ratio",
        "extract_seconds",
    )
    return [
        Table(
            "Structure learning: seconds per call and SHD",
            ("d", "discover s", "SHD", "GRaSP s", "GRaSP SHD", "PC s", "PC SHD", "ours / GRaSP"),
            rows,
            "Median over interleaved calls; n/a where causal-learn is not installed.",
        ),
        Table(
            f"Action inference for one joint of a {ctx['joints']}-joint model, "
            f"{ctx['targets']} targets x {ctx['steps']} Adam steps",
            (
                "variables",
                "active subgraph variables",
                "whole graph s",
                "subgraph s",
                "subgraph / whole",
                "extraction s",
                "max |action difference|",
            ),
            [(*(ctx[k] for k in keys), ctx["max_action_diff"])],
        ),
    ]


#: Structure-learning time target: at most this multiple of GRaSP's seconds, at d = TARGET_D.
GRASP_RATIO = 5.0
TARGET_D = "20"


def _discovery_targets(disc: dict[str, dict[str, Any]]) -> list[Target]:
    """At the largest d (d = 20 in the full run): time <= 5x GRaSP's and SHD <= GRaSP's (None without peers)."""
    d = TARGET_D if TARGET_D in disc else max(disc, key=int)
    row = disc[d]
    out = [
        Target(
            f"discovery.ratio_grasp_d{d}",
            row["ratio_grasp"],
            GRASP_RATIO,
            "<=",
            f"seconds of discover / seconds of GRaSP at d = {d}",
            Precondition.nonzero(row["grasp_seconds"], "GRaSP's seconds"),
        )
    ]
    if row["grasp_shd"] is not None:
        out.append(
            Target(
                f"discovery.shd_d{d}",
                row["shd"],
                row["grasp_shd"],
                "<=",
                f"SHD of discover at d = {d}, at most GRaSP's (its CPDAG, an undirected edge counting 1)",
            )
        )
    return out


#: The permutation baseline: at most this many edges on shuffled columns, on average.
SHUFFLED_EDGES = 1.0


def _robust_table(config: RobustConfig, perm: dict[str, Any], meas: dict[str, Any]) -> Table:
    m = meas["mean"]
    return Table(
        f"Weak data: shuffled columns (d = {config.shuffled_d}, n = {config.shuffled_n}, "
        f"{config.shuffled_seeds} seeds) and measurement-like data (d = {config.d}, n = {config.n}, "
        f"{config.seeds} seeds)",
        ("edges on shuffled columns", "SHD (DAG)", "SHD (CPDAG)", "edges", "empty graph", "PC", "GRaSP"),
        [(perm["mean_edges"], m["pal"], m["pal_cpdag"], m["pal_edges"], m["empty"], m["pc"], m["grasp"])],
        "Means over seeds; PC and GRaSP (CPDAGs, an undirected edge counting 1) n/a without causal-learn.",
    )


def _robust_targets(perm: dict[str, Any], meas: dict[str, Any]) -> list[Target]:
    m = meas["mean"]
    out = [
        Target(
            "weak.shuffled_edges",
            perm["mean_edges"],
            SHUFFLED_EDGES,
            "<=",
            "mean edges that discover finds on independently shuffled columns",
        ),
        Target(
            "weak.shd_vs_empty", m["pal"], m["empty"], "<", "mean SHD of discover, below the empty graph's"
        ),
    ]
    if m["pc"] is not None:
        out.append(Target("weak.shd_vs_pc", m["pal"], m["pc"], "<", "mean SHD of discover, below PC's"))
    return out


@register(
    "discovery",
    kind="bench",
    config=Config,
    quick=Config(
        scm=SCMConfig(dims=(8,), n=300),
        context=ContextConfig(10, 8, 20),
        robust=RobustConfig(6, 300, 3, 6, 300, 2),
        repeats=1,
    ),
    tiny=Config(
        scm=SCMConfig(dims=(5,), n=120),
        context=ContextConfig(3, 4, 5),
        robust=RobustConfig(4, 100, 1, 4, 100, 1),
        repeats=1,
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Seconds of structure learning against GRaSP and PC, and of action inference on the active subgraph."""
    use_peers = peers.available()
    with torch_threads(config.threads):
        if use_peers:
            peers.warm_up()
        disc = _discovery(config, use_peers)
        ctx = _context(config.context, config.seed, config.repeats)
        perm = permutation_edges(config.robust, config.seed)
        meas = measurement_shd(config.robust, config.seed, use_peers)
    notes = [f"Synthetic SCMs with n = {config.scm.n} standardised rows; {config.threads} torch thread(s)."]
    if not use_peers:
        notes.append("causal-learn is not installed, so the GRaSP and PC columns are n/a.")
    return Report(
        title="Structure-learning and contextualisation benchmark",
        metrics={
            "discovery": disc,
            "context": ctx,
            "permutation": perm,
            "measurement": meas,
            "causal_learn": use_peers,
        },
        tables=[*_tables(disc, ctx), _robust_table(config.robust, perm, meas)],
        targets=[
            *_discovery_targets(disc),
            *_robust_targets(perm, meas),
            Target(
                "context.max_action_diff",
                ctx["max_action_diff"],
                SAME_ACTION,
                "<=",
                "largest |action inferred on the active subgraph - on the whole graph| (ctrl units)",
            ),
            Target(
                "context.ratio",
                ctx["ratio"],
                1.0,
                "<",
                "seconds of action inference on the active subgraph / on the whole graph",
                Precondition.nonzero(ctx["whole_seconds"], "the seconds on the whole graph"),
            ),
        ],
        notes=notes,
    )
