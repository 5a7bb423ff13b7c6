"""``pal experiment a2``: visual concept formation (thesis §5.1.3, Table 5.4, Fig. 5.4).

One visual record per run: the gallery-mean 54-d descriptor (Eq. 4.20) of the moved object's
main record (:mod:`pal.experiments.perception.runs`). Records are placed in a visual conceptual
space after the fitted robust normalisation (:func:`visual_scaler`: per-dimension median/IQR,
the two histograms scaled as a whole, families weighted equally); prototypes are per-object
means.

- Table 5.4 in the thesis's format: each record's distance to the box, boat and ball
  prototypes (all records forming the prototypes, as in the thesis), beside the thesis's rows.
  Distances are in normalised units, so only their order is comparable with the thesis's.
- ``nearest_own_prototype``: the fraction of records nearest to their own object's prototype
  (target: all of them; in the thesis the box depth-translation record was nearer the ball).
- ``loo_accuracy``: leave-one-run-out accuracy, each record held out and the normaliser and
  prototypes rebuilt from the others (target ≥ 90 %).
- The same two figures without normalisation (``*_raw``, the proof of concept's protocol), to
  show what the normalisation changes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pal.experiments.perception.concept_eval import Scaler, leave_one_out, loo_accuracy, prototype_distances
from pal.experiments.perception.evaluation import RunResult
from pal.experiments.perception.plots import pca_figure
from pal.experiments.perception.runs import QUICK_RUNS, TINY_RUNS, Config, RunSet, collect
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target
from pal.perception import VISUAL_FAMILIES, VISUAL_HISTOGRAMS, RobustNormaliser

__all__ = ["THESIS_TABLE_5_4", "Config", "report", "run", "visual_scaler"]

#: Table 5.4: (object, motion, usable motion, snapshots, d_box, d_boat, d_ball).
THESIS_TABLE_5_4 = (
    ("box", "translation", True, 2, 8.778, 20.000, 18.240),
    ("box", "depth translation", True, 2, 8.778, 8.831, 4.937),
    ("boat", "translation", False, 6, 11.670, 3.979, 5.239),
    ("boat", "rotation", False, 7, 14.810, 3.979, 8.920),
    ("ball", "roll", False, 8, 10.074, 6.138, 0.000),
)
TARGET_NEAREST_OWN, TARGET_LOO = 1.0, 0.9


def visual_scaler() -> RobustNormaliser:
    """The visual space's normaliser (fitted on the records that form the prototypes)."""
    return RobustNormaliser(VISUAL_FAMILIES, shared=VISUAL_HISTOGRAMS)


def _nearest(distances: dict[str, float]) -> str:
    return min(sorted(distances), key=distances.__getitem__)


def categorise(
    X: np.ndarray, labels: Sequence[str], scaler: Callable[[], Scaler] | None
) -> tuple[dict[str, Any], list[dict[str, float]], list[str | None]]:
    """Nearest-prototype scores of the (n, d) records ``X`` under one scaler (None: raw distances).

    Returns:
        (``{nearest_own_prototype, nearest_own_count: [k, n], loo_accuracy, prototype_support}``,
        per record ``{label: distance}``, per record the leave-one-out prediction).
    """
    dists, support = prototype_distances(X, labels, scaler, "visual")
    loo = leave_one_out(X, labels, scaler, "visual")
    own = sum(_nearest(d) == lab for d, lab in zip(dists, labels, strict=True))
    scores = {
        "nearest_own_prototype": own / len(labels),
        "nearest_own_count": [own, len(labels)],
        "loo_accuracy": loo_accuracy(loo, labels),
        "prototype_support": support,
    }
    return scores, dists, loo


def metrics(records: Sequence[RunResult]) -> dict[str, Any]:
    """Scores with and without normalisation, and every record's distances and predictions.

    Raises:
        ValueError: fewer than 2 records have a visual descriptor.
    """
    records = [r for r in records if r.visual is not None]
    if len(records) < 2:
        raise ValueError(f"A2 needs at least 2 visual records, got {len(records)}; record more runs")
    X = np.stack([r.visual for r in records])  # type: ignore[misc]
    labels = [r.object for r in records]
    scores, dists, loo = categorise(X, labels, visual_scaler)
    raw, dists_raw, loo_raw = categorise(X, labels, None)
    rows = [
        {
            "name": r.name,
            "object": r.object,
            "motion": r.kind,
            "run": r.run,
            "snapshots": r.snapshots,
            "usable_motion": r.usable,
            "distances": d,
            "nearest": _nearest(d),
            "loo_predicted": p,
            "distances_raw": dr,
            "nearest_raw": _nearest(dr),
            "loo_predicted_raw": pr,
        }
        for r, d, p, dr, pr in zip(records, dists, loo, dists_raw, loo_raw, strict=True)
    ]
    return {**scores, "raw": {k: v for k, v in raw.items() if k != "prototype_support"}, "records": rows}


def _of(count: Sequence[int]) -> str:
    return "{} of {}".format(*count)


def tables(m: dict[str, Any]) -> list[Table]:
    """Our records in the format of Table 5.4, the thesis's table, and the summary against the thesis."""
    labs = sorted(m["prototype_support"])
    raw = m["raw"]
    return [
        Table(
            "Visual records and prototype distances (thesis Table 5.4 format, normalised units)",
            [
                "Object",
                "Associated motion",
                "run",
                "Usable motion",
                "Snapshots",
                *[f"d_{x}" for x in labs],
                "nearest",
                "leave-one-out",
            ],
            [
                [
                    r["object"],
                    r["motion"],
                    r["run"],
                    r["usable_motion"],
                    r["snapshots"],
                    *[r["distances"][x] for x in labs],
                    r["nearest"],
                    r["loo_predicted"],
                ]
                for r in m["records"]
            ],
            "Prototype supports: "
            + ", ".join(f"{k} {v}" for k, v in sorted(m["prototype_support"].items()))
            + ".",
        ),
        Table(
            "Thesis Table 5.4 (raw distances)",
            ["Object", "Associated motion", "Usable motion", "Snapshots", "d_box", "d_boat", "d_ball"],
            THESIS_TABLE_5_4,
            "Prototype supports in the thesis: box 2, boat 2, ball 1.",
        ),
        Table(
            "A2 against the thesis",
            ["quantity", "goal", "thesis", "pal", "pal without normalisation"],
            [
                [
                    "records nearest their own prototype",
                    "all",
                    "4 of 5 (box depth translation nearer the ball)",
                    _of(m["nearest_own_count"]),
                    _of(raw["nearest_own_count"]),
                ],
                [
                    "leave-one-run-out accuracy",
                    f">= {TARGET_LOO:g}",
                    "not reported",
                    m["loo_accuracy"],
                    raw["loo_accuracy"],
                ],
            ],
        ),
    ]


def targets(m: dict[str, Any]) -> list[Target]:
    """Every record nearest its own prototype; leave-one-run-out accuracy >= 90 %."""
    return [
        Target(
            "nearest_own_prototype",
            m["nearest_own_prototype"],
            TARGET_NEAREST_OWN,
            ">=",
            "fraction of visual records nearest to their own object's prototype (normalised space)",
        ),
        Target(
            "loo_accuracy",
            m["loo_accuracy"],
            TARGET_LOO,
            ">=",
            "fraction of held-out records categorised as their own object, normaliser and prototypes rebuilt",
        ),
    ]


def report(records: Sequence[RunResult], run_set: RunSet, seed: int) -> Report:
    """The A2 report of already scored runs (see :func:`metrics`)."""
    m = metrics(records)
    visual = [r for r in records if r.visual is not None]
    X = visual_scaler().fit_transform(np.stack([r.visual for r in visual]))  # type: ignore[misc]
    names = [r.name for r in visual]
    fig = pca_figure(X, [r.object for r in visual], [True] * len(visual), names, "visual space R^54 -> R^2")
    return Report(
        title="A2: visual concept formation (thesis Table 5.4)",
        metrics=m,
        tables=tables(m),
        targets=targets(m),
        figures={"visual_pca": fig},
        notes=[
            run_set.note(seed),
            f"{len(visual)} visual records in R^54 (gallery means), robustly normalised; prototypes are per-object "
            "means, and distances are in normalised units, so only their order compares with the thesis's.",
        ],
    )


@register("a2", config=Config, quick=Config(runs=QUICK_RUNS), tiny=Config(runs=TINY_RUNS))
def run(config: Config, progress_bar: bool = False) -> Report:
    """A2: nearest-prototype categories of the objects' visual records (Table 5.4)."""
    return report(collect(config.runs, config.seed, progress_bar), config.runs, config.seed)
