"""Structure learning on a real table with a reference graph: pal against PC, GRaSP and the empty graph.

The table is a CSV file with a header row and one numeric column per variable; the reference
graph is a CSV file of ``(cause, effect)`` rows under a header, for example the flow-cytometry
measurements of Sachs et al. (2005) and their 18-edge consensus graph. Names are made into
variable names by lower-casing them and replacing every character outside ``[a-z0-9_]`` with
``_``, in both files alike. ``subsamples`` seeded subsets of ``rows`` rows are standardised and
scored against the reference: SHD of pal's DAG and of its CPDAG, of PC and GRaSP (causal-learn,
when importable) and of the empty graph, with the wall and CPU seconds of each method. SHD counts
pair states (:func:`pal.baselines.discovery_peers.cpdag_shd`: an undirected edge counts 1), so a
reference graph with a cycle can be scored too.

Without a table (``path`` empty) the entry runs the same protocol on simulated measurement-like
data of the same size (:func:`pal.experiments.structure.measurement.measurement_data`), and its
targets are not evaluated.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from inference.discovery import discover
from models import CausalGraph
from pal.baselines import discovery_peers as peers
from pal.checks import check_int
from pal.experiments.structure.measurement import measurement_data
from pal.experiments.structure.scm import standardised
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target

__all__ = ["Config", "load", "run", "variable_name"]


@dataclass(frozen=True)
class Config:
    """The table, the reference graph and the sizes.

    Attributes:
        seed: seeds the subsamples and the methods.
        path: CSV file of the table (empty: simulated stand-in, targets not evaluated).
        truth: CSV file of the reference graph's ``(cause, effect)`` rows (given with ``path``;
            checked when the entry runs, so that ``--set`` may give them one at a time).
        rows: rows per subsample (at most the table's).
        subsamples: seeded subsamples scored.
        peers: run PC and GRaSP when causal-learn is importable.
    """

    seed: int = 0
    path: str = ""
    truth: str = ""
    rows: int = 1000
    subsamples: int = 5
    peers: bool = True

    def __post_init__(self) -> None:
        check_int("rows", self.rows, minimum=20)
        check_int("subsamples", self.subsamples, minimum=1)


def variable_name(label: str) -> str:
    """``label`` lower-cased with every character outside ``[a-z0-9_]`` replaced by ``_``."""
    return re.sub(r"[^a-z0-9_]", "_", str(label).lower())


def load(path: str, truth: str) -> tuple[dict[str, np.ndarray], list[tuple[str, str]]]:
    """The table as name -> ``(N,)`` float64 and the reference edges, names made variable names.

    Raises:
        ValueError: a missing file, a non-numeric or non-finite column, two labels with one
            name, a reference file without two columns, or a reference name not in the table.
    """
    for what, file in (("path", path), ("truth", truth)):
        if not Path(file).is_file():
            raise ValueError(f"{what} {file!r} is not a file")
    frame = pd.read_csv(path)
    names = [variable_name(c) for c in frame.columns]
    if len(set(names)) != len(names):
        raise ValueError(f"the columns {list(frame.columns)} give repeated names {names}")
    table = {}
    for label, name in zip(frame.columns, names, strict=True):
        values = pd.to_numeric(frame[label], errors="coerce").to_numpy(float)
        if not np.isfinite(values).all():
            raise ValueError(f"column {label!r} of {path!r} has non-numeric or non-finite values")
        table[name] = values
    ref = pd.read_csv(truth)
    if ref.shape[1] != 2:
        raise ValueError(f"truth {truth!r} has {ref.shape[1]} columns, expected 2 (cause, effect)")
    edges = [(variable_name(a), variable_name(b)) for a, b in ref.itertuples(index=False)]
    unknown = sorted({v for e in edges for v in e} - set(table))
    if unknown:
        raise ValueError(f"truth names {unknown} are not columns of {path!r}; columns: {names}")
    return table, edges


def _timed(fn: Any) -> tuple[Any, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def _score(
    data: dict[str, np.ndarray], edges: list[tuple[str, str]], seed: int, use_peers: bool
) -> dict[str, Any]:
    """One subsample: SHD, edges and seconds of pal, PC, GRaSP and the empty graph."""
    names = list(data)
    graph = CausalGraph.from_edges([], nodes=names)
    result, wall, cpu = _timed(lambda: discover(graph, data, seed=seed))
    row: dict[str, Any] = {
        "seed": seed,
        "pal": peers.cpdag_shd(result.graph.edges, [], edges),
        "pal_cpdag": peers.cpdag_shd(result.cpdag.directed, result.cpdag.undirected, edges),
        "pal_edges": len(result.graph.edges),
        "pal_seconds": wall,
        "pal_cpu_seconds": cpu,
        "empty": peers.cpdag_shd([], [], edges),
    }
    x = np.concatenate([data[k] for k in names], 1)
    for method in peers.PEERS:
        if not use_peers:
            row.update(
                {
                    method: None,
                    f"{method}_edges": None,
                    f"{method}_seconds": None,
                    f"{method}_cpu_seconds": None,
                }
            )
            continue
        g, wall, cpu = _timed(lambda m=method: peers.run_peer(m, x, names, seed=seed))
        row[method] = peers.cpdag_shd(g.directed, g.undirected, edges)
        row[f"{method}_edges"] = len(g.directed) + len(g.undirected)
        row[f"{method}_seconds"], row[f"{method}_cpu_seconds"] = wall, cpu
    return row


def _mean(rows: list[dict[str, Any]], key: str) -> float | None:
    values = [r[key] for r in rows]
    return None if any(v is None for v in values) else float(np.mean(values))


@register(
    "discovery_table",
    config=Config,
    quick=Config(rows=500, subsamples=2),
    tiny=Config(rows=100, subsamples=1, peers=False),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """SHD and time of discover on a real table against PC, GRaSP and the empty graph."""
    if bool(config.path) != bool(config.truth):
        raise ValueError(
            f"give both path and truth or neither, got path={config.path!r}, truth={config.truth!r}"
        )
    real = bool(config.path)
    if real:
        table, edges = load(config.path, config.truth)
    else:
        truth, sim = measurement_data(11, config.rows, config.seed)
        table, edges = {k: v[:, 0] for k, v in sim.items()}, list(truth.edges)
    n = len(next(iter(table.values())))
    if config.rows > n:
        raise ValueError(f"rows={config.rows} is more than the table's {n} rows")
    use_peers = config.peers and peers.available()
    if use_peers:
        peers.warm_up()
    rows = []
    for s in range(config.seed, config.seed + config.subsamples):
        idx = np.random.default_rng(s).choice(n, config.rows, replace=False)
        rows.append(_score(standardised({k: v[idx, None] for k, v in table.items()}), edges, s, use_peers))
    keys = [k for k in rows[0] if k != "seed"]
    mean = {k: _mean(rows, k) for k in keys}
    source = config.path if real else "simulated measurement-like data (no table given)"
    why = "a real table was given (path and truth)"
    targets = [
        Target(
            f"shd_minus_{other}",
            None if mean[other] is None else mean["pal"] - mean[other],
            0.0,
            "<",
            f"mean SHD of pal's DAG minus {label}'s (below 0: pal is closer to the reference)",
            Precondition(
                real and mean[other] is not None, why + ("" if other == "empty" else f" and {label} ran")
            ),
        )
        for other, label in (("pc", "PC"), ("empty", "the empty graph"))
    ]
    return Report(
        title=f"Structure learning on a real table ({len(table)} variables, {len(edges)} reference edges)",
        metrics={"mean": mean, "rows": rows, "source": source, "reference_edges": len(edges)},
        tables=[
            Table(
                f"SHD against the reference graph, mean of {config.subsamples} subsamples of {config.rows} rows",
                ("method", "SHD", "edges", "wall s", "CPU s"),
                [
                    (
                        "pal (DAG)",
                        mean["pal"],
                        mean["pal_edges"],
                        mean["pal_seconds"],
                        mean["pal_cpu_seconds"],
                    ),
                    ("pal (CPDAG)", mean["pal_cpdag"], mean["pal_edges"], None, None),
                    *(
                        (m, mean[m], mean[f"{m}_edges"], mean[f"{m}_seconds"], mean[f"{m}_cpu_seconds"])
                        for m in peers.PEERS
                    ),
                    ("empty graph", mean["empty"], 0, None, None),
                ],
                caption=f"Data: {source}. SHD counts pair states; an undirected edge counts 1.",
            )
        ],
        targets=targets,
        notes=[] if use_peers else ["PC and GRaSP not run (causal-learn not importable or not asked for)."],
    )
