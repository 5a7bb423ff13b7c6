"""The table and figure of ``pal bench counterfactual`` (:mod:`pal.experiments.bench.counterfactual`).

Each library's figures are an object with the attributes ``chain_unit_ms``,
``mlp50_unit_ms``, ``units_per_s``, ``scenarios_ms`` and ``scenarios_cpu_ms`` (K -> wall and
CPU ms per call), or None when the
library was not measured. The growth of a library is its time for K scenarios over its time
for the first K of the run: 1 would be free scenarios, K a full replay per scenario.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from pal.lab.report import Table
from pal.lab.timing import ratio

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["compute_bound", "growth", "marginal", "scenario_figure", "scenario_summary", "table"]


def growth(scenarios_ms: Mapping[str, float], first: str) -> dict[str, float | None]:
    """K -> time of K scenarios / time of ``first`` scenarios."""
    return {k: ratio(v, scenarios_ms.get(first)) for k, v in scenarios_ms.items()}


def marginal(scenarios_ms: Mapping[str, float], first: str) -> dict[str, float | None]:
    """K -> ms per scenario added to ``first``: ``(t_K - t_first) / (K - first)`` (K > first)."""
    t0 = scenarios_ms.get(first)
    return {
        k: None if t0 is None else (v - t0) / (int(k) - int(first))
        for k, v in scenarios_ms.items()
        if int(k) > int(first)
    }


def compute_bound(abducted: int, replayed: int, scenarios: Sequence[int]) -> dict[str, float]:
    """K -> the growth of the mechanism evaluations alone, ``(A + K R) / (A + first R)``.

    ``A`` mechanisms are evaluated once (abduction of every non-root site) and ``R`` (the
    descendants of the intervened site) once per scenario. A call whose time were all in
    those evaluations would grow by this ratio; fixed costs (checks, Python per site) make a
    measured growth smaller, so a growth below it comes from fixed cost, not from sharing.
    """
    first = scenarios[0]
    return {str(k): (abducted + k * replayed) / (abducted + first * replayed) for k in scenarios}


def scenario_summary(libs: Mapping[str, Any], first: str) -> dict[str, Any]:
    """Per library: wall and CPU growth, CPU ms per added scenario; pal's CPU growth over ChiRho's per K."""
    out: dict[str, Any] = {}
    for name, f in libs.items():
        out[name] = (
            None
            if f is None
            else {
                "wall": growth(f.scenarios_ms, first),
                "cpu": growth(f.scenarios_cpu_ms, first),
                "cpu_ms_per_added_scenario": marginal(f.scenarios_cpu_ms, first),
            }
        )
    pal, chirho = out.get("pal"), out.get("chirho")
    out["pal_over_chirho_cpu"] = (
        None
        if pal is None or chirho is None
        else {k: ratio(v, chirho["cpu"].get(k)) for k, v in pal["cpu"].items() if k != first}
    )
    return out


def table(
    sizes: Mapping[str, Any], scenarios: Sequence[int], libs: Mapping[str, Any], rel: Mapping[str, Any]
) -> Table:
    """The figures of every library, their ratios pal/peer, and the growth with K.

    Args:
        sizes: ``mlp_nodes``, ``chain_units`` and ``scenario_units`` of the run.
        scenarios: the numbers of scenarios K.
        libs: library -> figures (None: not measured).
        rel: peer -> the ratios of :func:`pal.experiments.bench.counterfactual.ratios` (or None).
    """
    peers = [n for n in libs if n != "pal"]
    first = str(scenarios[0])

    def row(label: str, get: Callable[[Any], Any], rget: Callable[[dict[str, Any]], Any]) -> list[Any]:
        values = [None if fig is None else get(fig) for fig in libs.values()]
        return [label, *values, *(None if rel[n] is None else rget(rel[n]) for n in peers)]

    rows = [
        row("chain, 1 unit (ms)", lambda f: f.chain_unit_ms, lambda r: r["chain_unit_ms"]),
        row(
            f"MLP {sizes['mlp_nodes']} nodes, 1 unit (ms)",
            lambda f: f.mlp50_unit_ms,
            lambda r: r["mlp50_unit_ms"],
        ),
        row(
            f"chain, {sizes['chain_units']} units (units/s)",
            lambda f: f.units_per_s,
            lambda r: r["units_per_s"],
        ),
    ]
    for k in (str(k) for k in scenarios):
        rows.append(
            row(
                f"MLP, {sizes['scenario_units']} units, {k} scenarios (ms)",
                lambda f, k=k: f.scenarios_ms.get(k),
                lambda r, k=k: r["scenarios_ms"][k],
            )
        )
    for clock, attr in (("wall", "scenarios_ms"), ("CPU", "scenarios_cpu_ms")):
        for k in (str(k) for k in scenarios[1:]):
            values = [None if f is None else growth(getattr(f, attr), first).get(k) for f in libs.values()]
            rows.append(
                [
                    f"{k} scenarios / {first} (growth, {clock} time)",
                    *values,
                    *(ratio(values[0], v) for v in values[1:]),
                ]
            )
    for k in (str(k) for k in scenarios[1:]):
        values = [None if f is None else marginal(f.scenarios_cpu_ms, first).get(k) for f in libs.values()]
        rows.append(
            [
                f"CPU ms per scenario added, {first} -> {k}",
                *values,
                *(ratio(values[0], v) for v in values[1:]),
            ]
        )
    return Table(
        "Counterfactual queries: pal against its peers on the same SCMs",
        ["figure", *libs, *(f"pal/{n}" for n in peers)],
        rows,
        caption="Ratios pal/peer are ours/peer for times and peer/ours for units/s: < 1 means pal is faster. "
        "Growth is a library's time for K scenarios over its time for one.",
    )


def scenario_figure(sizes: Mapping[str, Any], libs: Mapping[str, Any]) -> Figure:
    """Time against the number of scenarios K, one line per library."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for name, figs in libs.items():
        if figs is not None:
            ax.plot(
                [int(k) for k in figs.scenarios_ms], list(figs.scenarios_ms.values()), marker="o", label=name
            )
    ax.set(
        xlabel="scenarios K",
        xscale="log",
        ylabel="ms per call",
        yscale="log",
        title=f"{sizes['scenario_units']} units, {sizes['mlp_nodes']}-node MLP SCM",
    )
    ax.legend()
    fig.tight_layout()
    return fig
