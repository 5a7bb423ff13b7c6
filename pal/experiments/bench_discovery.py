"""``pal bench discovery``: wall time of structure learning and of contextualised action inference.

1. :func:`inference.discover` on standardised data of the synthetic SCMs of
   :mod:`pal.experiments.discovery_scm` (d in ``dims``, ``n`` rows), against causal-learn's
   GRaSP and PC on the same data when causal-learn is importable (``null`` otherwise).
   Figures: seconds per call and ``ratio_grasp`` = ours / GRaSP (> 1: ours is slower); SHD
   is reported beside them.
2. Action inference (Alg. 4.2) for one joint of a ``joints``-joint world model
   (:func:`models.joint_chain_graph`, state variant): on the whole graph, and on the active
   subgraph of the query (:func:`inference.context.active_subgraph`). Figures: seconds of
   each, ``ratio`` = subgraph / whole (< 1: the subgraph is faster), extraction seconds,
   and the largest action difference.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from inference import infer_action
from inference.context import active_subgraph, subgraph_model
from inference.discovery import discover, shd
from models import WorldModel, joint_chain_graph
from pal.experiments import discovery_peers as peers
from pal.experiments.discovery_scm import random_scm
from pal.experiments.timing import markdown_table, measure_interleaved, ratio, torch_threads

__all__ = ["Config", "Result", "run"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Config:
    dims: tuple[int, ...] = (10, 20)
    n: int = 1000
    seed: int = 0
    joints: int = 50
    targets: int = 64
    steps: int = 100
    repeats: int = 3
    threads: int | None = 1

    @classmethod
    def quick(cls) -> Config:
        return cls(dims=(8,), n=300, joints=10, targets=8, steps=20, repeats=1)


@dataclass(frozen=True)
class Result:
    discovery: dict[str, dict[str, Any]]
    context: dict[str, Any]
    config: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {"discovery": self.discovery, "context": self.context, "causal_learn": peers.available()}

    def to_markdown(self) -> str:
        rows = []
        for d, r in self.discovery.items():
            rows.append(
                [
                    d,
                    r["seconds"],
                    r["shd"],
                    r["grasp_seconds"],
                    r["grasp_shd"],
                    r["pc_seconds"],
                    r["pc_shd"],
                    r["ratio_grasp"],
                ]
            )
        c = self.context
        return (
            "## Structure-learning and contextualisation benchmark\n\n"
            + markdown_table(
                ["d", "discover s", "SHD", "GRaSP s", "GRaSP SHD", "PC s", "PC SHD", "ours / GRaSP"], rows
            )
            + "\n\n"
            + f"Action inference for one joint of a {c['joints']}-joint model ({c['variables']} variables), "
            f"{c['targets']} targets x {c['steps']} steps: whole graph {c['whole_seconds']:.3g} s, active subgraph "
            f"({c['subgraph_variables']} variables) {c['subgraph_seconds']:.3g} s, ratio **{c['ratio']:.3g}**; "
            f"extraction {c['extract_seconds']:.3g} s; max |action difference| {c['max_action_diff']:.2g}.\n"
        )

    def figures(self) -> dict[str, Any]:
        return {}


def _discovery(config: Config) -> dict[str, dict[str, Any]]:
    out = {}
    if peers.available():  # warm up: imports and first-call costs stay out of the timings
        warm = np.random.default_rng(0).normal(size=(50, 3))
        for method in peers.PEERS:
            peers.run_peer(method, warm, ["a", "b", "c"], seed=0)
    for d in config.dims:
        scm = random_scm(d, seed=1000 * d + config.seed)
        data = scm.sample(config.n, seed=config.seed)
        std = {k: (v - v.mean(0)) / v.std(0) for k, v in data.items()}
        start = time.perf_counter()
        res = discover(scm.graph, std, seed=config.seed)
        row: dict[str, Any] = {"seconds": time.perf_counter() - start, "shd": shd(res.graph, scm.graph)}
        names = scm.graph.names
        x = np.concatenate([std[k] for k in names], 1)
        for method in peers.PEERS:
            if peers.available():
                g = peers.run_peer(method, x, names, seed=config.seed)
                row[f"{method}_seconds"] = g.seconds
                row[f"{method}_shd"] = peers.cpdag_shd(g.directed, g.undirected, scm.graph.edges)
            else:
                row[f"{method}_seconds"] = row[f"{method}_shd"] = None
        row["ratio_grasp"] = ratio(row["seconds"], row["grasp_seconds"])
        out[str(d)] = row
    return out


def _context(config: Config) -> dict[str, Any]:
    joints = [f"j{i}" for i in range(config.joints)]
    with torch.random.fork_rng():
        torch.manual_seed(config.seed)
        model = WorldModel(
            joint_chain_graph(joints, dict.fromkeys(joints, (-1.0, 1.0)), "state"), hidden=(32, 32)
        )
    gen = torch.Generator().manual_seed(config.seed)
    samples = model.sample(256, gen)
    target_joint = joints[len(joints) // 2]
    act, tgt = f"act.{target_joint}", f"q.{target_joint}"
    start = time.perf_counter()
    sub = active_subgraph(model, samples, [tgt])
    small = subgraph_model(model, sub)
    extract = time.perf_counter() - start
    k = config.targets
    state = {n: samples[n][:k] for n in model.graph.roots if n != act}
    small_state = {n: v for n, v in state.items() if n in small.graph}
    target = {tgt: samples[tgt][k : 2 * k]}
    timings = measure_interleaved(
        {
            "whole": lambda: infer_action(model, state, target, actions=[act], steps=config.steps),
            "subgraph": lambda: infer_action(small, small_state, target, actions=[act], steps=config.steps),
        },
        repeats=config.repeats,
    )
    diff = float((timings["whole"].result.actions[act] - timings["subgraph"].result.actions[act]).abs().max())
    return {
        "joints": config.joints,
        "variables": len(model.graph),
        "subgraph_variables": len(small.graph),
        "targets": k,
        "steps": config.steps,
        "whole_seconds": timings["whole"].median,
        "subgraph_seconds": timings["subgraph"].median,
        "ratio": ratio(timings["subgraph"].median, timings["whole"].median),
        "extract_seconds": extract,
        "max_action_diff": diff,
    }


def run(config: Config, progress_bar: bool = False) -> Result:
    with torch_threads(config.threads):
        disc = _discovery(config)
        ctx = _context(config)
    return Result(disc, ctx, asdict(config))
