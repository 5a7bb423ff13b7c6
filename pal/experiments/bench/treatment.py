"""``pal bench treatment``: a binary treatment on a table of IHDP's shape with known unit effects.

The table (:func:`pal.datasets.semi_synthetic.ihdp_like`: 747 units, 24 covariates, a
confounded Bernoulli treatment ``t``, outcome ``y``) is fitted by a world model with the graph
covariates -> t, covariates -> y, t -> y. Figures:

* ``counterfactual_s``: :func:`inference.counterfactual` of every unit under do(t = 0) and
  do(t = 1) with the default ``num_samples`` (1000), median wall time (and CPU time) of
  ``repeats`` calls. The treatment is set in both scenarios, so its Gumbel noise does not
  matter: the answer is exact (``exact``) and takes one pass (``draws`` = 1).
* ``max_diff``: the largest difference between those unit effects ``y'(1) - y'(0)`` and the
  same counterfactual through the general handler path (the whole program replayed under
  Pyro's plates, with a measurement-scale handler active), and the CATE ``m_1 - m_0`` of
  :func:`inference.unit_effects` (the outcome is additive, so the abducted noise cancels).
* ``pehe``: sqrt(mean (tau_hat - tau)^2) of :func:`inference.treatment_effect`'s unit effects
  from a ``members``-member ensemble, against the true unit effects; ``pehe_constant`` is that
  of the best constant effect, ``sd(tau)``. ``coverage``: share of the true unit effects inside
  their 90 % intervals (bootstrap members; no target, reported as measured).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from inference import FitSchedule, MeasurementScale, counterfactual, fit, treatment_effect, unit_effects
from models.graph import CausalGraph
from models.tables import as_table
from models.world import WorldModel
from pal.checks import check_int
from pal.datasets.semi_synthetic import EffectTable, ihdp_like
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import torch_threads

__all__ = ["Config", "run"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Config:
    """Sizes and settings.

    Attributes:
        seed: seeds the table, the weights and the fits.
        units: rows of the table (747 as in IHDP).
        members: ensemble members of the model whose intervals are measured.
        schedule: the fit schedule of both models.
        num_samples: ``num_samples`` of the counterfactual call (its default).
        repeats: timed counterfactual calls (median reported) after one warm-up.
        threads: torch threads during the run (None: leave as is).
    """

    seed: int = 0
    units: int = 747
    members: int = 3
    schedule: FitSchedule = FitSchedule(epochs=150, batch_size=256, validation=0.2, patience=20)
    num_samples: int = 1000
    repeats: int = 5
    threads: int | None = 1

    def __post_init__(self) -> None:
        check_int("units", self.units, minimum=10)
        check_int("members", self.members, minimum=2)
        check_int("num_samples", self.num_samples)
        check_int("repeats", self.repeats)
        if not isinstance(self.schedule, FitSchedule):
            raise ValueError(f"schedule must be a FitSchedule, got {type(self.schedule).__name__}")


def _model(table: EffectTable, members: int, seed: int) -> WorldModel:
    edges = [(c, "t") for c in table.covariates] + [(c, "y") for c in table.covariates] + [("t", "y")]
    return WorldModel(CausalGraph.from_edges(edges), seed=seed, discrete={"t": 2}, members=members)


def _timed(fn: Callable[[], Any], repeats: int) -> tuple[float, float, Any]:
    """Median wall and CPU (this thread) seconds of ``repeats`` calls after a warm-up, and the last result."""
    out = fn()
    wall, cpu = [], []
    for _ in range(repeats):
        w, c = time.perf_counter(), time.thread_time()
        out = fn()
        wall.append(time.perf_counter() - w)
        cpu.append(time.thread_time() - c)
    return float(np.median(wall)), float(np.median(cpu)), out


def _fit(model: WorldModel, rows: Any, config: Config) -> float:
    start = time.perf_counter()
    fit(model, rows, schedule=config.schedule, seed=config.seed)
    return time.perf_counter() - start


@register(
    "treatment",
    kind="bench",
    config=Config,
    quick=Config(
        units=300, schedule=FitSchedule(epochs=40, batch_size=128, validation=0.2, patience=10), repeats=2
    ),
    tiny=Config(
        units=60,
        members=2,
        schedule=FitSchedule(epochs=2, batch_size=64, validation=0.0),
        num_samples=10,
        repeats=1,
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Binary-treatment counterfactuals (time, exactness) and unit-level effects (PEHE, coverage)."""
    with torch_threads(config.threads):
        table = ihdp_like(config.units, config.seed)
        rows = as_table(table.columns)
        single, ensemble = _model(table, 1, config.seed), _model(table, config.members, config.seed)
        fit_s = {"single": _fit(single, rows, config), "ensemble": _fit(ensemble, rows, config)}
        scenarios = [{"t": 0.0}, {"t": 1.0}]
        wall, cpu, cf = _timed(
            lambda: counterfactual(single, rows, scenarios, num_samples=config.num_samples, seed=config.seed),
            config.repeats,
        )
        effect = (cf.samples["y"][:, 1] - cf.samples["y"][:, 0])[..., 0].double()  # (S, N)
        with MeasurementScale({"y": single.mechanism("y").sigma.detach()}):
            general = counterfactual(
                single, rows, scenarios, num_samples=config.num_samples, seed=config.seed
            )
        general_effect = (general.samples["y"][:, 1] - general.samples["y"][:, 0])[..., 0].double()
        cate = torch.as_tensor(unit_effects(single, rows, "t", "y").effect)
        max_diff = max(float((effect - general_effect).abs().max()), float((effect - cate).abs().max()))
        result = treatment_effect(ensemble, rows, "t", "y", target="att")
    units = result.units
    pehe, constant = table.pehe(units.effect), float(table.effect.std())
    coverage = units.covers(table.effect)
    metrics = {
        "counterfactual_s": wall,
        "counterfactual_cpu_s": cpu,
        "exact": cf.exact,
        "draws": int(cf.samples["y"].shape[0]),
        "max_diff": max_diff,
        "pehe": pehe,
        "pehe_constant": constant,
        "coverage": coverage,
        "att": result.to_dict() | {"units": None},
        "fit_s": fit_s,
    }
    rows_out = [
        ["counterfactual, 2 scenarios (s, wall)", wall],
        ["counterfactual, 2 scenarios (s, CPU)", cpu],
        ["exact / draws", f"{cf.exact} / {metrics['draws']}"],
        ["max |diff| of unit effects against the handler path and m_1 - m_0", max_diff],
        [f"PEHE, {config.members}-member ensemble", pehe],
        ["PEHE of the best constant effect, sd(tau)", constant],
        ["coverage of the true unit effects by the 90 % intervals", coverage],
        ["ATT [90 % interval] (true 4)", f"{result.estimate:.3g} [{result.low:.3g}, {result.high:.3g}]"],
    ]
    identical = Precondition(
        bool(cf.exact) and max_diff <= 1e-4, "the answer is exact and the effects identical"
    )
    return Report(
        title="Binary treatment: counterfactuals and unit-level effects",
        metrics=metrics,
        tables=[Table(f"{config.units} units, 24 covariates, t binary", ["figure", "value"], rows_out)],
        targets=[
            Target("counterfactual_s", wall, 1.0, "<=", "2 scenarios of every unit, wall s", identical),
            Target("exact", float(cf.exact), 1.0, ">=", "the counterfactual says it is exact (1) or not (0)"),
            Target("max_diff", max_diff, 1e-4, "<=", "unit effects identical across the three computations"),
            Target("pehe_vs_constant", pehe / constant, 1.0, "<", "PEHE / that of the best constant effect"),
        ],
        notes=[
            f"fit (epochs {config.schedule.epochs}, batch {config.schedule.batch_size}, patience "
            f"{config.schedule.patience}): {fit_s['single']:.1f} s (1 member), {fit_s['ensemble']:.1f} s "
            f"({config.members} members); torch threads: {config.threads}; counterfactual num_samples="
            f"{config.num_samples}.",
        ],
    )
