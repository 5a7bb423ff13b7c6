"""Scores of the ``pusher`` experiment: per checkpoint and controller, and the targets with their preconditions.

For each checkpoint c and controller k, over the evaluation episodes of all seeds (goals g):

    mean ± sd of d_final(k, c, g)      median, 25th / 75th percentile
    success  = share of d_final <= success                    moved = share of episodes with object moved > MOVED
    reach    = median over episodes of min_t |tip(t) - object(t)|   predicted = mean planning-time prediction of d_final

``seed_sd`` is the sd over seeds of the per-seed means (the learning curve's band). Random
torques and the simulator-model planner (the planner's ceiling: the learners' planner settings
and cost with the true simulator as its model, :mod:`pal.baselines.simulator_mpc`) do not learn:
their goals run once and stand at every checkpoint.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from pal.agent.aggregate import Counts
from pal.experiments.closed_loop.pusher_plots import curve_figure, paths_figure, prediction_figure
from pal.experiments.closed_loop.pusher_runs import MOVED, Episode
from pal.lab.report import Precondition, Report, Table, Target

__all__ = ["CONTROLLERS", "FULL_STEPS", "block", "summarise", "targets"]

CONTROLLERS = ("pal", "baseline", "simulator", "random")
#: The controllers that do not learn: their episodes run once per seed.
FIXED = ("simulator", "random")
#: Median final distance the agent should reach at :data:`FULL_STEPS` steps, m; its share within 5 cm there.
TARGET_DISTANCE = 0.1
TARGET_SUCCESS = 0.4
#: The agent's planning time per step on one core at horizon :data:`TARGET_HORIZON`, s.
TARGET_STEP_SECONDS = 0.5
TARGET_HORIZON = 25
#: The step count, seeds and goals at which the distance targets are stated.
FULL_STEPS, FULL_SEEDS, FULL_GOALS = 6000, 3, 20
#: Share of the agent's episodes that must move the object for its ratio to the baseline to count.
PAL_MOVED_SHARE = 0.9


def _stat(values: list[float | None]) -> dict[str, float | None]:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return {"mean": None, "sd": None, "median": None, "p25": None, "p75": None}
    return {
        "mean": float(v.mean()),
        "sd": float(v.std()),
        "median": float(np.median(v)),
        "p25": float(np.percentile(v, 25)),
        "p75": float(np.percentile(v, 75)),
    }


def block(per_seed: list[list[Episode]], success: float) -> dict[str, Any]:
    """The scores of one controller at one checkpoint from its episodes per seed (module docstring)."""
    eps = [e for seed in per_seed for e in seed]
    seed_means = [float(np.mean([e.final_planar for e in s])) for s in per_seed if s]
    return {
        "final_planar": _stat([e.final_planar for e in eps]),
        "final_distance": _stat([e.final_distance for e in eps]),
        "start_planar": _stat([e.start_planar for e in eps]),
        "seed_means": seed_means,
        "seed_sd": float(np.std(seed_means)) if seed_means else None,
        "success": float(np.mean([e.final_planar <= success for e in eps])),
        "moved_share": float(np.mean([e.moved > MOVED for e in eps])),
        "max_moved": max((e.moved for e in eps), default=0.0),
        "min_tip_object": _stat([e.min_tip_object for e in eps]),
        "predicted_final": _stat([e.predicted_final for e in eps]),
        "step_cpu_seconds": _median([e.cpu for e in eps]),
        "episodes": len(eps),
    }


def _metres(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f} m"


def _blocks(config: Any, per_seed: dict[int, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The scores per checkpoint (str) and controller (:func:`block`)."""
    out: dict[str, dict[str, Any]] = {}
    for point in config.aggregation.checkpoints:
        row = {
            c: block([r[c]["at"][point]["episodes"] for r in per_seed.values()], config.success)
            for c in ("pal", "baseline")
        }
        for c in FIXED:
            row[c] = block([r[c] for r in per_seed.values()], config.success)
        for c in ("pal", "baseline"):
            row[c]["env_steps"] = [r[c]["at"][point]["counts"]["env_steps"] for r in per_seed.values()]
            row[c]["ranking"] = _ranking([r[c]["at"][point].get("ranking") for r in per_seed.values()])
        out[str(point)] = row
    return out


def _ranking(per_seed: list[dict[str, Any] | None]) -> dict[str, float | int | None]:
    """The mean over seeds of each ranking score (:func:`pusher_ranking.score`), None where no seed has one."""
    found = [r for r in per_seed if r]
    out: dict[str, float | int | None] = {"probes": sum(int(r["probes"]) for r in found)}
    for key in ("rho", "rho_obj", "regret"):
        v = [r[key] for r in found if r[key] is not None]
        out[key] = float(np.mean(v)) if v else None
    return out


def _training(per_seed: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """Per learner: each training episode's final distance, smallest tip-object distance and object motion, per seed."""
    out = {}
    for c in ("pal", "baseline"):
        runs = [r[c] for r in per_seed.values()]
        out[c] = {
            "steps": runs[0]["steps"],
            "counts": [r["counts"] for r in runs],
            "final_planar": [[e.final_planar for e in r["training"]] for r in runs],
            "min_tip_object": [[e.min_tip_object for e in r["training"]] for r in runs],
            "moved": [[e.moved for e in r["training"]] for r in runs],
            "step_cpu_seconds": _median([e.cpu for r in runs for e in r["training"]]),
        }
    return out


def _median(values: list[float | None]) -> float | None:
    """The median of the values that are not None, or None."""
    found = [v for v in values if v is not None]
    return float(np.median(found)) if found else None


def targets(config: Any, at: dict[str, dict[str, Any]], step_cpu: float | None) -> list[Target]:
    """The issue's targets; each ratio counts only if both controllers moved the object (module docstring)."""
    last = str(config.aggregation.checkpoints[-1])
    full = Precondition(
        int(last) >= FULL_STEPS and config.runs >= FULL_SEEDS and config.eval_goals >= FULL_GOALS,
        f"the run reaches {FULL_STEPS} environment steps with >= {FULL_SEEDS} seeds x {FULL_GOALS} goals "
        f"(this run: {last} steps, {config.runs} x {config.eval_goals})",
    )
    pal = at[last]["pal"]
    out = [
        Target(
            "pal_median_final",
            pal["final_planar"]["median"],
            TARGET_DISTANCE,
            "<=",
            f"median final object-goal distance (x-y) of the agent at {last} steps, m",
            full,
        ),
        Target(
            "pal_within_5cm",
            pal["success"],
            TARGET_SUCCESS,
            ">=",
            f"share of the agent's goals within {config.success} m at {last} steps",
            full,
        ),
    ]
    for point, row in at.items():
        p, b = row["pal"], row["baseline"]
        sample = config.runs >= FULL_SEEDS and config.eval_goals >= FULL_GOALS
        moved = Precondition(
            p["moved_share"] >= PAL_MOVED_SHARE and b["moved_share"] > 0 and sample,
            f"the object moved > {MOVED * 1000:g} mm in >= {PAL_MOVED_SHARE:.0%} of pal's episodes "
            f"(was {p['moved_share']:.0%}) and in at least one of the baseline's (was {b['moved_share']:.0%}), "
            f"over >= {FULL_SEEDS} seeds x {FULL_GOALS} goals (this run: {config.runs} x {config.eval_goals})",
        )
        pm, bm = p["final_planar"]["median"], b["final_planar"]["median"]
        out.append(
            Target(
                f"pal_over_baseline_at_{point}",
                None if pm is None or not bm else pm / bm,
                1.0,
                "<=",
                f"the agent's median final distance / the PETS-style baseline's at {point} steps",
                moved,
            )
        )
    horizon = config.plan.action.horizon
    out.append(
        Target(
            "pal_step_cpu_seconds",
            step_cpu,
            TARGET_STEP_SECONDS,
            "<=",
            "the agent's planning time per MPC step, process CPU s on one torch thread (median over its MPC "
            "training episodes, each the mean of its steps)",
            Precondition(
                horizon >= TARGET_HORIZON and config.threads == 1 and config.plan.replan_every == 1,
                f"horizon >= {TARGET_HORIZON} on one thread, a plan at every step (this run: horizon {horizon}, "
                f"{config.threads} threads, a plan every {config.plan.replan_every} steps)",
            ),
        )
    )
    return out


def _tables(config: Any, at: dict[str, dict[str, Any]], training: dict[str, Any]) -> list[Table]:
    rows = []
    for point, row in at.items():
        for c in CONTROLLERS:
            b, f = row[c], row[c]["final_planar"]
            rows.append(
                [
                    int(point),
                    c,
                    f["mean"],
                    f["sd"],
                    f["median"],
                    b["success"],
                    b["moved_share"],
                    b["predicted_final"]["mean"],
                    b["min_tip_object"]["median"],
                    b["step_cpu_seconds"],
                ]
            )
    fields = [f.name for f in dataclasses.fields(Counts)]  # by name: a part read back has its keys sorted
    counts = [
        [c, i, *(r[f] for f in fields)]
        for c in ("pal", "baseline")
        for i, r in enumerate(training[c]["counts"])
    ]
    ranking = [
        [int(point), c, *(row[c]["ranking"][k] for k in ("rho", "rho_obj", "regret", "probes"))]
        for point, row in at.items()
        for c in ("pal", "baseline")
    ]
    return [
        Table(
            "Learning curve: final object-goal distance (x-y) over seeds x goals at each checkpoint",
            [
                "env steps",
                "controller",
                "mean [m]",
                "sd [m]",
                "median [m]",
                f"share within {config.success} m",
                f"share moved > {MOVED * 1000:g} mm",
                "predicted final, mean [m]",
                "min tip-object, median [m]",
                "planning CPU s / step",
            ],
            rows,
            caption="The baseline is a PETS-style ensemble with CEM written for this comparison, not the authors' code. "
            "simulator: the same planner and cost with the true simulator as its model (the planner's ceiling). "
            "It and random torques do not learn: the same episodes stand at every checkpoint.",
        ),
        Table(
            "How each learner's model ranks candidate plans at states of the ceiling's episodes (mean over seeds)",
            [
                "env steps",
                "learner",
                "Spearman, summed cost",
                "Spearman, final object-goal",
                "regret",
                "probes",
            ],
            ranking,
            caption="Spearman correlation of the model's predicted and the true summed step cost (and final "
            "object-goal distance) over candidates around the ceiling's plan; regret 0: the model's pick is the "
            "best candidate, 1: a median one (pal.experiments.closed_loop.pusher_ranking). n/a: no probes, or a "
            "model that predicts the same final object position for every candidate.",
        ),
        Table(
            "What aggregation spent, per learner and seed",
            ["learner", "seed index", *(f.replace("_", " ") for f in fields)],
            counts,
        ),
    ]


def _first_goals(run: dict[str, Any], point: int, n: int = 3) -> dict[str, list[Episode]]:
    """The first ``n`` evaluation episodes of one seed per controller at checkpoint ``point``."""
    return {c: (run[c] if c in FIXED else run[c]["at"][point]["episodes"])[:n] for c in CONTROLLERS}


def summarise(config: Any, per_seed: dict[int, dict[str, Any]]) -> Report:
    """The report of the ``pusher`` experiment from its per-seed results (:func:`pusher_protocol.one_seed`)."""
    at = _blocks(config, per_seed)
    training = _training(per_seed)
    points = list(config.aggregation.checkpoints)
    first = next(iter(per_seed.values()))
    agg = config.aggregation
    metrics = {
        "seeds": list(config.seeds),
        "checkpoints": points,
        "budget": agg.budget,
        "at": at,
        "training": training,
    }
    last = str(points[-1])
    return Report(
        title="Pusher-v5 learning curves: the agent, a PETS-style baseline and random torques at equal environment steps",
        metrics=metrics,
        tables=_tables(config, at, training),
        targets=targets(config, at, training["pal"]["step_cpu_seconds"]),
        notes=[
            f"Seeds {', '.join(map(str, config.seeds))}; per seed {agg.rounds} episodes of {agg.episode_steps} steps "
            f"({agg.random_rounds} random, then MPC), each followed by a warm refit; {config.eval_goals} evaluation "
            f"goals per checkpoint ({', '.join(map(str, points))} steps).",
            "Both planners use the same sampling settings (population, elites, iterations, horizon, momentum, "
            "initial spread, warm start) and the same step cost.",
            f"The same planner on the true simulator (no model error) ends at a median "
            f"{_metres(at[last]['simulator']['final_planar']['median'])}: what a perfect model reaches with "
            "these planner settings, cost and episode length.",
        ],
        figures={
            "learning_curve": curve_figure(points, at),
            "paths": paths_figure(
                _first_goals(first, int(last)),
                f"seed {next(iter(per_seed))}: the first evaluation goals after {last} environment steps",
            ),
            "predicted_vs_realized": prediction_figure(
                {
                    c: [e for r in per_seed.values() for e in r[c]["at"][int(last)]["episodes"]]
                    for c in ("pal", "baseline")
                }
            ),
        },
    )
