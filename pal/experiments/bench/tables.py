"""``pal bench tables``: :func:`inference.fit` on its default schedule on small tables with known effects.

Three tables, each an X -> T -> Y model with every confounder a parent of the treatment T
(a Bernoulli site: the propensity) and of the outcome Y:

* ``semi``: :func:`pal.datasets.semi_synthetic.ihdp_like`, a table of IHDP's shape with known
  unit effects, ``rows`` x 26 (24 covariates, T, Y; Hill's response surface B, the effect on
  the treated 4). MLP mechanisms. PEHE = sqrt(mean_i (tau_hat_i - tau_i)^2), with
  tau_hat_i = m_1(x_i) - m_0(x_i) the model's effect of do(T) on unit i.
* ``lalonde``: NSW trainees + CPS controls (16 177 rows), linear mechanisms on the
  Dehejia-Wahba covariates; the doubly robust ATT against the experimental 1794 USD.
* ``nhefs``: NHEFS (1566 rows), linear mechanisms, categorical confounders; the doubly
  robust ATE against the book's 3.4 kg.

Each is fitted with ``schedule=None`` (:meth:`inference.FitSchedule.auto`) and, for
comparison, with the former minibatch default (``minibatch_schedule``). DoWhy-GCM
(``gcm.fit`` of an invertible SCM with its auto-assigned mechanisms on the same graph) is timed
on the semi-synthetic table when dowhy is importable (None otherwise).
"""

from __future__ import annotations

import importlib.util
import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
import torch

from inference import FitSchedule, fit
from inference.effects import treatment_effect
from models import CausalGraph, WorldModel
from pal.checks import check_int
from pal.datasets import NHEFS_EFFECT, NSW_EFFECT, lalonde, nhefs
from pal.datasets.semi_synthetic import ihdp_like
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import ratio, torch_threads

__all__ = ["Config", "minibatch_schedule", "run", "semi_synthetic"]

log = logging.getLogger(__name__)

LALONDE_CONFOUNDERS = (
    "age",
    "educ",
    "black",
    "hisp",
    "marr",
    "nodegree",
    "re74",
    "re75",
    "u74",
    "u75",
    "age^2",
    "educ^2",
)
NHEFS_CONFOUNDERS = (
    "sex",
    "race",
    "age",
    "education",
    "smokeintensity",
    "smokeyrs",
    "exercise",
    "active",
    "wt71",
)
NHEFS_CATEGORIES = {"qsmk": 2, "sex": 2, "race": 2, "education": 5, "exercise": 3, "active": 3}


@dataclass(frozen=True)
class Config:
    """Sizes.

    Attributes:
        seed: seeds the semi-synthetic table, the models and the fits.
        rows: rows of the semi-synthetic table.
        replications: semi-synthetic tables (seeds ``seed, seed + 1, ...``), PEHE averaged.
        controls: CPS controls of the LaLonde table (None: all 15 992), drawn with ``seed``.
        nhefs_rows: NHEFS rows (None: all 1566).
        dowhy: time DoWhy-GCM's fit when it is importable.
        threads: torch threads during the run (None: leave as is).
    """

    seed: int = 0
    rows: int = 747
    replications: int = 5
    controls: int | None = None
    nhefs_rows: int | None = None
    threads: int | None = 1
    dowhy: bool = True

    def __post_init__(self) -> None:
        check_int("rows", self.rows, minimum=50)
        check_int("replications", self.replications, minimum=1)
        for key in ("controls", "nhefs_rows"):
            if getattr(self, key) is not None:
                check_int(key, getattr(self, key), minimum=200)
        if not isinstance(self.dowhy, bool):
            raise TypeError(f"dowhy must be True or False, got {self.dowhy!r}")


def minibatch_schedule(n: int) -> FitSchedule:
    """The former default: ~10 000 minibatch Adam steps, lr 0.01 (``n`` >= 20 rows)."""
    validation = 0.2 if n < 10_000 else 0.1
    n_train = n - round(validation * n)
    batch = int(min(2048, max(32, n_train // 8)))
    epochs = int(min(500, max(10, math.ceil(10_000 / math.ceil(n_train / batch)))))
    return FitSchedule(epochs, batch, 0.01, validation, max(5, epochs // 10))


def semi_synthetic(rows: int, seed: int) -> tuple[pd.DataFrame, np.ndarray]:
    """The semi-synthetic table (module docstring) and its true unit effects ``(rows,)``."""
    table = ihdp_like(rows, seed)
    return pd.DataFrame(table.columns), table.effect


def _graph(confounders: tuple[str, ...] | list[str], t: str, y: str) -> CausalGraph:
    return CausalGraph.from_edges([(c, t) for c in confounders] + [(c, y) for c in confounders] + [(t, y)])


def _timed(fn: Any) -> tuple[Any, float, float]:
    """``(result, wall seconds, CPU seconds)`` of ``fn()``."""
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def _semi(config: Config, schedule: FitSchedule | None) -> dict[str, Any]:
    """Means over the replications (fit seconds: the median)."""
    reps = [_semi_one(config.rows, config.seed + r, schedule) for r in range(config.replications)]
    out = {k: float(np.mean([r[k] for r in reps])) for k in reps[0]}
    for key in ("fit_seconds", "fit_cpu_seconds"):
        out[key] = float(np.median([r[key] for r in reps]))
    out["pehe_each"] = [r["pehe"] for r in reps]
    return out


def _semi_one(rows: int, seed: int, schedule: FitSchedule | None) -> dict[str, Any]:
    frame, tau = semi_synthetic(rows, seed)
    conf = [c for c in frame.columns if c not in ("t", "y")]
    model = WorldModel(_graph(conf, "t", "y"), seed=seed, discrete={"t": 2})
    result, wall, cpu = _timed(lambda: fit(model, frame, schedule=schedule, seed=seed))
    given = {c: torch.tensor(frame[c].to_numpy(), dtype=model.dtype)[:, None] for c in conf}
    with torch.no_grad():
        arm = {
            a: model.predict({**given, "t": torch.full((len(frame), 1), float(a), dtype=model.dtype)})
            for a in (0, 1)
        }
    tau_hat = (arm[1]["y"] - arm[0]["y"])[:, 0].double().numpy()
    return {
        "fit_seconds": wall,
        "fit_cpu_seconds": cpu,
        "epochs": result.epochs,
        "pehe": float(np.sqrt(np.mean((tau_hat - tau) ** 2))),
        "ate": float(tau_hat.mean()),
        "true_ate": float(tau.mean()),
    }


def _effect(
    model: WorldModel, frame: pd.DataFrame, t: str, y: str, target: str, fitted: Any
) -> dict[str, Any]:
    result, wall, cpu = fitted
    r = treatment_effect(model, frame, t, y, target=target)
    return {
        "fit_seconds": wall,
        "fit_cpu_seconds": cpu,
        "epochs": result.epochs,
        "estimate": r.estimate,
        "low": r.low,
        "high": r.high,
        "clipped": r.clipped,
        "clip": r.clip,
        "n": r.n,
    }


def lalonde_table(controls: int | None, seed: int) -> pd.DataFrame:
    """NSW trainees and (a seeded sample of) the CPS controls with the Dehejia-Wahba terms."""
    df = pd.DataFrame(lalonde("cps"))
    if controls is not None:
        df = pd.concat([df[df.treat == 1], df[df.treat == 0].sample(controls, random_state=seed)])
    df = df.reset_index(drop=True)
    df["u74"], df["u75"] = (df.re74 == 0).astype(float), (df.re75 == 0).astype(float)
    df["age^2"], df["educ^2"] = df.age**2, df.educ**2
    return df


def _lalonde(config: Config, schedule: FitSchedule | None) -> dict[str, Any]:
    df = lalonde_table(config.controls, config.seed)
    model = WorldModel(
        _graph(LALONDE_CONFOUNDERS, "treat", "re78"), seed=config.seed, kind="linear", discrete={"treat": 2}
    )
    fitted = _timed(lambda: fit(model, df, schedule=schedule, seed=config.seed))
    return _effect(model, df, "treat", "re78", "att", fitted)


def _nhefs(config: Config, schedule: FitSchedule | None) -> dict[str, Any]:
    raw = pd.DataFrame(nhefs())
    table = raw.drop(columns="seqn").assign(education=raw.education - 1)
    if config.nhefs_rows is not None:
        table = table.sample(config.nhefs_rows, random_state=config.seed).reset_index(drop=True)
    model = WorldModel(
        _graph(NHEFS_CONFOUNDERS, "qsmk", "wt82_71"),
        seed=config.seed,
        kind="linear",
        discrete=NHEFS_CATEGORIES,
    )
    fitted = _timed(lambda: fit(model, table, schedule=schedule, seed=config.seed))
    return _effect(model, table, "qsmk", "wt82_71", "ate", fitted)


def _dowhy_seconds(config: Config) -> dict[str, float] | None:
    """DoWhy-GCM's auto assignment and fit on the semi-synthetic table (None: not installed).

    A first call on the same table is timed apart (``first_call_seconds``: imports, caches,
    compilation); ``seconds`` and ``cpu_seconds`` are the wall and process CPU time of a second
    call, which is what a user fitting a second table pays. DoWhy's model selection may run in
    worker processes, whose CPU time ``cpu_seconds`` does not count: compare wall times.
    """
    if importlib.util.find_spec("dowhy") is None:
        return None
    import networkx as nx
    from dowhy import gcm

    frame, _ = semi_synthetic(config.rows, config.seed)
    graph = _graph([c for c in frame.columns if c not in ("t", "y")], "t", "y")
    gcm.config.disable_progress_bars()

    def once() -> None:
        scm = gcm.InvertibleStructuralCausalModel(nx.DiGraph(graph.edges))
        gcm.auto.assign_causal_mechanisms(scm, frame)
        gcm.fit(scm, frame)

    _, first, _ = _timed(once)
    _, wall, cpu = _timed(once)
    return {"seconds": wall, "cpu_seconds": cpu, "first_call_seconds": first}


SCHEDULES = ("default", "minibatch")


def _measure(config: Config) -> dict[str, dict[str, dict[str, Any]]]:
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for table, fn in (("semi", _semi), ("lalonde", _lalonde), ("nhefs", _nhefs)):
        n = {"semi": config.rows}.get(table)
        out[table] = {}
        for label in SCHEDULES:
            if label == "minibatch" and n is None:  # the row count is known after loading
                n = (
                    len(lalonde_table(config.controls, config.seed))
                    if table == "lalonde"
                    else (config.nhefs_rows or 1566)
                )
            schedule = None if label == "default" else minibatch_schedule(n)
            out[table][label] = fn(config, schedule)
            log.info("%s, %s schedule: %s", table, label, out[table][label])
    return out


#: Targets: fit time at most this multiple of DoWhy-GCM's; LaLonde ATT within this many USD of
#: the experiment; NHEFS ATE within this many kg of the book's.
DOWHY_RATIO, LALONDE_TOLERANCE, NHEFS_TOLERANCE = 2.0, 400.0, 0.5


def _targets(m: dict[str, Any], dowhy: dict[str, float] | None) -> list[Target]:
    semi, la, nh = m["semi"]["default"], m["lalonde"]["default"], m["nhefs"]["default"]
    return [
        Target(
            "semi.fit_ratio_dowhy",
            ratio(semi["fit_seconds"], None if dowhy is None else dowhy["seconds"]),
            DOWHY_RATIO,
            "<=",
            "wall seconds of fit (default schedule) / of DoWhy-GCM's auto assignment and fit on the "
            "semi-synthetic table (its second call)",
            Precondition.nonzero(None if dowhy is None else dowhy["seconds"], "DoWhy-GCM's seconds"),
        ),
        Target(
            "semi.pehe_vs_minibatch",
            semi["pehe"],
            m["semi"]["minibatch"]["pehe"],
            "<=",
            "mean PEHE of the default schedule over the replications, at most the former minibatch default's",
        ),
        Target(
            "lalonde.att_error",
            abs(la["estimate"] - NSW_EFFECT),
            LALONDE_TOLERANCE,
            "<=",
            "|doubly robust ATT - 1794| USD, default schedule",
        ),
        Target(
            "lalonde.covers",
            float(la["low"] <= NSW_EFFECT <= la["high"]),
            1.0,
            ">=",
            "the 90 % interval of the ATT covers 1794 (1 yes, 0 no)",
        ),
        Target(
            "nhefs.ate_error",
            abs(nh["estimate"] - NHEFS_EFFECT),
            NHEFS_TOLERANCE,
            "<=",
            "|doubly robust ATE - 3.4| kg",
        ),
    ]


def _tables(m: dict[str, Any], dowhy: dict[str, float] | None) -> list[Table]:
    semi = [
        (label, r["fit_seconds"], r["fit_cpu_seconds"], r["epochs"], r["pehe"], r["ate"], r["true_ate"])
        for label, r in m["semi"].items()
    ]
    effects = [
        (
            f"{table} ({label})",
            r["fit_seconds"],
            r["fit_cpu_seconds"],
            r["epochs"],
            r["estimate"],
            r["low"],
            r["high"],
            r["clipped"],
            r["clip"],
        )
        for table in ("lalonde", "nhefs")
        for label, r in m[table].items()
    ]
    return [
        Table(
            "Semi-synthetic tables: fit time (median) and unit effects (mean over replications)",
            ("schedule", "fit s", "fit CPU s", "epochs", "PEHE", "ATE", "true ATE"),
            semi,
            "DoWhy-GCM auto assignment and fit: "
            + (
                "n/a (not installed or not asked for)."
                if dowhy is None
                else f"{dowhy['seconds']:.2f} s wall, {dowhy['cpu_seconds']:.2f} s CPU in this process (second call; "
                f"the first took {dowhy['first_call_seconds']:.2f} s)."
            ),
        ),
        Table(
            "Real tables: doubly robust effect (LaLonde ATT, USD; NHEFS ATE, kg), 90 % interval",
            (
                "table (schedule)",
                "fit s",
                "fit CPU s",
                "epochs",
                "estimate",
                "low",
                "high",
                "units clipped",
                "clip bound",
            ),
            effects,
            "Reference: LaLonde 1794 USD (the NSW experiment), NHEFS 3.4 kg.",
        ),
    ]


@register(
    "tables",
    kind="bench",
    config=Config,
    quick=Config(rows=300, replications=2, controls=2000, nhefs_rows=600),
    tiny=Config(rows=60, replications=1, controls=200, nhefs_rows=200, dowhy=False),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Fit's default schedule on a semi-synthetic table, LaLonde and NHEFS, against the former default and DoWhy-GCM."""
    with torch_threads(config.threads):
        metrics = _measure(config)
        dowhy = _dowhy_seconds(config) if config.dowhy else None
    notes = [
        f"{config.threads} torch thread(s); the semi-synthetic table has {config.rows} rows x 26 columns."
    ]
    if dowhy is None:
        notes.append("dowhy is not installed or not asked for, so the DoWhy-GCM fit time is n/a.")
    return Report(
        title="Fit defaults on small tables",
        metrics={
            **metrics,
            "dowhy_fit_seconds": None if dowhy is None else dowhy["seconds"],
            "dowhy_fit": dowhy,
        },
        tables=_tables(metrics, dowhy),
        targets=_targets(metrics, dowhy),
        notes=notes,
    )
