"""Experiment C4: curiosity-driven exploration of the object variables against random babbling.

For each of ``runs`` seeds (``seed``, ``seed + 1``, ...), two agents start from the same
``setup.babble_steps`` steps of random babbling (same seed, so the same actions and the same
world), then spend ``budget`` more steps:

- ``curiosity``: the gated world model (heteroscedastic ensembles, the objects' sites in the push
  frame of :mod:`pal.agent.graph_frame`; ``--set setup.agent.model.object_frame=world`` for the
  world frame) is fitted on the warm-up, then every step the agent searches the action sequence
  (horizon ``setup.agent.curiosity.horizon``) of highest contact gate, ``P(contact | a)`` times the
  on branches' disagreement, times the novelty of the predicted object position, minus a
  joint-limit penalty (:mod:`pal.agent.explore`), executes its first action, and refits every
  ``setup.agent.curiosity.refit_every`` steps; below ``setup.agent.curiosity.min_score`` it babbles
  (``setup.agent.curiosity.method`` selects the older CAI-gated disagreement or the grid targets of
  Eq. 4.34-4.38 instead);
- ``random``: random babbling goes on.

Objects are put back at the same seeded places every ``setup.agent.reset_every`` steps in both runs.
Coverage is the share of cells of the agent's grid over the table region that an object entered
during the budget *by being moved* (true position after a step in which it moved more than
``min_motion`` m; positions where objects were put back do not count), averaged over the objects.
The contact rate is the share of the budget's steps in which the arm touched an object.

Metrics: ``coverage_at_budget`` and ``contact_rate`` ``{curiosity, random}`` (mean over seeds),
``per_seed`` values, ``coverage_gain`` and ``contact_gain`` (curiosity minus random, targets > 0),
the one-sided paired t-test and Wilcoxon signed-rank test over seeds of each gain
(``paired_test``), ``curiosity_over_random``, the coverage and contact ``curves``, the curious
agent's ``curious_decisions``, the share of executed actions at a joint limit (within 1 % of an
action's range of a bound, ``at_limit``) of both conditions, and ``gate_auc``: the ROC AUC
against realized touch of the contact gate of each executed curious-mode action, of its contact
probability alone and of CAI at the belief (the diagnostic beside it), over (step, object) pairs
of all seeds. Every budget step is held out: the model that scored it was fitted on earlier
steps only.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import stats

from pal.agent import AgentConfig
from pal.agent.config import CURIOSITY_SAMPLING, MODEL_SCHEDULE, CuriosityConfig, ModelConfig
from pal.agent.curiosity import grid_occupancy
from pal.agent.explore import at_limit
from pal.agent.history import History
from pal.checks import check_float, check_int
from pal.experiments.closed_loop.setup import TINY_AGENT, TINY_SETUP, SetupConfig, babbled_agent
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["Config", "coverage_curve", "run"]

log = logging.getLogger(__name__)

#: The two explorers: curiosity targets (Eq. 4.38) and random babbling.
_CONDITIONS = ("curiosity", "random")
#: The targets are evaluated only with at least this many seeds, each of this many budget steps.
MIN_SEEDS = 5
MIN_BUDGET = 200
#: The gate's AUC target is evaluated only with at least this many touch and no-touch pairs each.
MIN_CLASS = 10


@dataclass(frozen=True)
class Config:
    """C4 protocol (module docstring).

    Attributes:
        seed: seed of the first run (the k-th run uses ``seed + k``).
        runs: repetitions of both conditions.
        setup: the warm-up babbling, the fits and the agent (its ``curiosity.refit_every`` is the
            curious agent's online refit period, steps).
        budget: steps after the warm-up.
        checkpoint_every: coverage is read every this many steps of the budget.
        min_motion: an object counts as moved when it moves more than this in one step, m.
    """

    seed: int = 0
    runs: int = 5
    setup: SetupConfig = SetupConfig(
        babble_steps=400, agent=AgentConfig(model=ModelConfig(object_frame="push"))
    )
    budget: int = 200
    checkpoint_every: int = 20
    min_motion: float = 0.005

    def __post_init__(self) -> None:
        for name in ("runs", "budget", "checkpoint_every"):
            check_int(name, getattr(self, name))
        check_int("seed", self.seed, minimum=0)
        check_float("min_motion", self.min_motion, 0.0)

    @property
    def seeds(self) -> tuple[int, ...]:
        """The seeds of the runs."""
        return tuple(range(self.seed, self.seed + self.runs))


QUICK = Config(
    runs=1,
    setup=SetupConfig(
        babble_steps=120,
        agent=AgentConfig(
            model=ModelConfig(schedule=replace(MODEL_SCHEDULE, epochs=30), object_frame="push"),
            curiosity=CuriosityConfig(refit_every=1000),
        ),
    ),
    budget=6,
    checkpoint_every=3,
)
TINY = Config(
    runs=2,
    setup=replace(
        TINY_SETUP,
        babble_steps=8,
        agent=replace(
            TINY_AGENT,
            model=replace(TINY_AGENT.model, object_frame="push"),
            curiosity=CuriosityConfig(
                horizon=2,
                sampling=replace(CURIOSITY_SAMPLING, population=8, elites=2, iterations=1),
                influence_samples=4,
                refit_every=2,
            ),
        ),
    ),
    budget=2,
    checkpoint_every=1,
)


def contact_curve(history: History, start: int, checkpoints: np.ndarray) -> np.ndarray:
    """Share of the rows [start, start + s) in which the arm touched any object, for each s in ``checkpoints``."""
    touched = (history.array("touch")[start:] > 0).any(1)
    return np.array([float(touched[: int(s)].mean()) for s in checkpoints])


def paired_test(a: list[float], b: list[float]) -> float | None:
    """One-sided paired t-test p-value that ``a`` exceeds ``b`` (None with fewer than 2 pairs or no spread)."""
    d = np.asarray(a) - np.asarray(b)
    if d.size < 2 or np.allclose(d, d[0]):
        return None
    return float(stats.ttest_rel(a, b, alternative="greater").pvalue)


def wilcoxon_test(a: list[float], b: list[float]) -> float | None:
    """One-sided Wilcoxon signed-rank p-value that ``a`` exceeds ``b`` (None with fewer than 2 non-zero differences).

    Exact for small samples: with 5 pairs the smallest p-value is 1/32 ~ 0.031 (all 5 positive).
    """
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    if np.count_nonzero(d) < 2:
        return None
    return float(stats.wilcoxon(d, alternative="greater").pvalue)


def roc_auc(score: np.ndarray, label: np.ndarray) -> float | None:
    """ROC AUC of ``score`` against the 0/1 ``label`` (Mann-Whitney, ties count 1/2); None without both classes."""
    score, label = np.asarray(score, dtype=float), np.asarray(label, dtype=bool)
    n1, n0 = int(label.sum()), int((~label).sum())
    if n1 == 0 or n0 == 0:
        return None
    ranks = stats.rankdata(score)
    return float((ranks[label].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def gate_rows(decisions: list[Any], touch: np.ndarray, objects: tuple[str, ...]) -> dict[str, list[float]]:
    """The (step, object) pairs of the decisions that carry diagnostics: gate, p_on, influence and touch.

    Args:
        decisions: the budget's decisions, one per history row.
        touch: ``(budget, O)`` the touch sensed over each step.
        objects: the history's objects (the columns of ``touch``).
    """
    out: dict[str, list[float]] = {"gate": [], "p_on": [], "influence": [], "touch": []}
    for d, row in zip(decisions, touch, strict=True):
        for o, value in d.diagnostics.get("gate", {}).items():
            out["gate"].append(value)
            out["p_on"].append(d.diagnostics["p_on"][o])
            out["influence"].append(d.diagnostics["influence"][o])
            out["touch"].append(float(row[objects.index(o)] > 0))
    return out


def coverage_curve(
    history: History,
    start: int,
    checkpoints: np.ndarray,
    region: Any,
    bins: tuple[int, int],
    min_motion: float,
) -> np.ndarray:
    """Coverage (mean over objects) of moved-object positions in rows [start, start + s) for each s.

    Args:
        history: the agent's history (true positions are read).
        start: first row of the budget.
        checkpoints: (K,) step counts s.
        region: ((x0, y0), (x1, y1)) table region, m.
        bins: grid cells per axis (x, y).
        min_motion: an object counts as moved when it moved more than this in the step, m.

    Returns:
        (K,) shares of grid cells.
    """
    truth, truth_prev = history.array("truth"), history.array("truth_prev")
    (x0, y0), (x1, y1) = region
    out = []
    for s in checkpoints:
        rows = slice(start, start + int(s))
        values = []
        for k in range(len(history.objects)):
            moved = np.linalg.norm(truth[rows, k] - truth_prev[rows, k], axis=1) > min_motion
            pts = truth[rows, k][moved]
            values.append(grid_occupancy(pts, (x0, y0), (x1, y1), bins) if len(pts) else 0.0)
        out.append(float(np.mean(values)))
    return np.array(out)


def _explore(config: Config, checkpoints: np.ndarray, progress_bar: bool) -> tuple[dict, dict, list, dict]:
    """Per condition the coverage and contact curves of every seed, the decision modes, gate rows, limit shares.

    Returns ``(curves, contacts, modes, extra)``; ``extra`` holds the curious agent's gate rows
    (:func:`gate_rows`) and per condition the shares of actions at a joint limit.
    """
    warmup, budget = config.setup.babble_steps, config.budget
    curves: dict[str, list[np.ndarray]] = {c: [] for c in _CONDITIONS}
    contacts: dict[str, list[np.ndarray]] = {c: [] for c in _CONDITIONS}
    extra: dict[str, Any] = {"gate": [], "at_limit": {c: [] for c in _CONDITIONS}}
    modes: list[dict[str, int]] = []
    region, bins = config.setup.agent.curiosity.region, config.setup.agent.curiosity.bins
    for seed in config.seeds:
        curious = babbled_agent(config.setup, seed, progress_bar=progress_bar)
        curious.refit()
        decisions = curious.run(budget, "curious", progress_bar=progress_bar)
        modes.append({m: sum(d.mode == m for d in decisions) for m in ("curious", "babble")})
        touch = curious.history.array("touch")[warmup:]
        extra["gate"].append(gate_rows(decisions, touch, tuple(curious.history.objects)))
        randomly = babbled_agent(
            replace(config.setup, babble_steps=warmup + budget), seed, progress_bar=progress_bar
        )
        for c, agent in (("curiosity", curious), ("random", randomly)):
            curves[c].append(
                coverage_curve(agent.history, warmup, checkpoints, region, bins, config.min_motion)
            )
            contacts[c].append(contact_curve(agent.history, warmup, checkpoints))
            limit = at_limit(agent.history.array("act")[warmup:], agent.low, agent.high)
            extra["at_limit"][c].append(float(limit.mean()))
            agent.env.close()
        log.info(
            "C4 seed %d: curiosity %.3f, random %.3f",
            seed,
            curves["curiosity"][-1][-1],
            curves["random"][-1][-1],
        )
    return curves, contacts, modes, extra


def _gate_auc(rows: list[dict[str, list[float]]]) -> dict[str, Any]:
    """AUCs against touch of the gate, its contact probability and CAI over the pooled (step, object) pairs."""
    pooled = {k: np.concatenate([np.asarray(r[k], dtype=float) for r in rows]) for k in rows[0]}
    touch = pooled["touch"] > 0
    return {
        "gate": roc_auc(pooled["gate"], touch),
        "p_on": roc_auc(pooled["p_on"], touch),
        "influence": roc_auc(pooled["influence"], touch),
        "pairs": int(touch.size),
        "touch_pairs": int(touch.sum()),
    }


def _metrics(
    config: Config, checkpoints: np.ndarray, curves: dict, contacts: dict, modes: list, extra: dict
) -> dict[str, Any]:
    at_budget = {c: float(np.mean([v[-1] for v in curves[c]])) for c in _CONDITIONS}
    per_seed = {c: [float(v[-1]) for v in curves[c]] for c in _CONDITIONS}
    rate = {c: float(np.mean([v[-1] for v in contacts[c]])) for c in _CONDITIONS}
    rate_seed = {c: [float(v[-1]) for v in contacts[c]] for c in _CONDITIONS}
    region, bins = config.setup.agent.curiosity.region, config.setup.agent.curiosity.bins
    return {
        "seeds": list(config.seeds),
        "coverage_at_budget": at_budget,
        "per_seed": per_seed,
        "coverage_gain": at_budget["curiosity"] - at_budget["random"],
        "contact_rate": rate,
        "contact_per_seed": rate_seed,
        "contact_gain": rate["curiosity"] - rate["random"],
        "paired_test": {
            "coverage_p": paired_test(per_seed["curiosity"], per_seed["random"]),
            "contact_p": paired_test(rate_seed["curiosity"], rate_seed["random"]),
            "coverage_wilcoxon_p": wilcoxon_test(per_seed["curiosity"], per_seed["random"]),
            "contact_wilcoxon_p": wilcoxon_test(rate_seed["curiosity"], rate_seed["random"]),
        },
        "gate_auc": _gate_auc(extra["gate"]),
        "at_limit": {c: float(np.mean(v)) for c, v in extra["at_limit"].items()},
        "at_limit_per_seed": extra["at_limit"],
        "curiosity_over_random": at_budget["curiosity"] / at_budget["random"]
        if at_budget["random"]
        else None,
        "curves": {
            "steps": checkpoints.tolist(),
            **{c: [v.tolist() for v in curves[c]] for c in _CONDITIONS},
            "contact": {c: [v.tolist() for v in contacts[c]] for c in _CONDITIONS},
        },
        "curious_decisions": modes,
        "info": {"region": [list(p) for p in region], "bins": list(bins)},
    }


def _targets(config: Config, metrics: dict[str, Any]) -> list[Target]:
    """The gains, their paired tests and the gate's AUC, evaluated only with ``MIN_SEEDS`` seeds of ``MIN_BUDGET`` steps."""
    bins, tests, auc = config.setup.agent.curiosity.bins, metrics["paired_test"], metrics["gate_auc"]
    enough = Precondition(
        len(config.seeds) >= MIN_SEEDS and config.budget >= MIN_BUDGET,
        f"at least {MIN_SEEDS} seeds of at least {MIN_BUDGET} budget steps "
        f"(ran {len(config.seeds)} x {config.budget})",
    )
    touches = auc.get("touch_pairs", 0)
    classes = Precondition(
        enough.holds and min(touches, auc.get("pairs", 0) - touches) >= MIN_CLASS,
        f"{enough.reason}, and at least {MIN_CLASS} touch and {MIN_CLASS} no-touch (step, object) pairs "
        f"(had {touches} of {auc.get('pairs', 0)})",
    )
    tested = [
        (
            f"{what}_{test}",
            tests[key],
            f"one-sided paired {name} over seeds, {words} of curiosity > random (p-value)",
        )
        for what, words in (("coverage", "coverage"), ("contact", "contact rate"))
        for test, name, key in (
            ("paired_p", "t-test", f"{what}_p"),
            ("wilcoxon_p", "Wilcoxon signed-rank test", f"{what}_wilcoxon_p"),
        )
    ]
    return [
        Target(
            "coverage_gain",
            metrics["coverage_gain"],
            0.0,
            ">",
            f"coverage at the budget, curiosity minus random babbling (share of the {bins[0]} x {bins[1]} "
            "table cells an object was pushed into, mean over seeds)",
            enough,
        ),
        Target(
            "contact_gain",
            metrics["contact_gain"],
            0.0,
            ">",
            "share of the budget's steps with touch, curiosity minus random (mean over seeds)",
            enough,
        ),
        *[Target(name, value, 0.05, "<=", text, enough) for name, value, text in tested],
        Target(
            "gate_auc",
            auc["gate"],
            0.9,
            ">=",
            "ROC AUC against realized touch of the contact gate P(contact | a) x on-branch disagreement of the "
            f"executed actions, held-out budget steps (CAI at the belief beside it: {_fmt(auc['influence'])}; "
            f"P(contact | a) alone: {_fmt(auc['p_on'])})",
            classes,
        ),
    ]


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"


def _table(config: Config, metrics: dict[str, Any]) -> Table:
    at_budget, per_seed = metrics["coverage_at_budget"], metrics["per_seed"]
    rate, rate_seed = metrics["contact_rate"], metrics["contact_per_seed"]
    limit = metrics["at_limit"]
    return Table(
        "Coverage of pushed object positions and contact rate at the budget",
        [
            "condition",
            "coverage, mean",
            *[f"coverage, seed {s}" for s in config.seeds],
            "contact rate, mean",
            *[f"contact, seed {s}" for s in config.seeds],
            "actions at a joint limit",
        ],
        [[c, at_budget[c], *per_seed[c], rate[c], *rate_seed[c], limit[c]] for c in _CONDITIONS],
        caption="Coverage: share of table cells an object was pushed into. Contact rate: share of steps with touch. "
        "Actions at a joint limit: share of executed actions with a joint target within 1 % of its range of a bound. "
        "The thesis reports occupancy only for a finger joint (§5.2.4), not for object variables.",
    )


@register("c4", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """C4: coverage of pushed object positions, curiosity-driven vs random babbling."""
    warmup, budget = config.setup.babble_steps, config.budget
    checkpoints = np.unique(
        np.append(np.arange(config.checkpoint_every, budget + 1, config.checkpoint_every), budget)
    )
    curves, contacts, modes, extra = _explore(config, checkpoints, progress_bar)
    metrics = _metrics(config, checkpoints, curves, contacts, modes, extra)
    stacked = {
        "coverage": {c: np.stack(v) for c, v in curves.items()},
        "contact rate": {c: np.stack(v) for c, v in contacts.items()},
    }
    c = config.setup.agent.curiosity
    return Report(
        title="C4: exploration of the object positions, curiosity vs random babbling",
        metrics=metrics,
        tables=[_table(config, metrics)],
        targets=_targets(config, metrics),
        notes=[
            f"After {warmup} warm-up babbling steps, {budget} more steps per seed "
            f"(seeds {', '.join(str(s) for s in config.seeds)}).",
            f"Curiosity: method {c.method!r}, horizon {c.horizon}, search from hold with a spread of "
            f"{c.sampling.init_std} of the action range, babbling below a score of {c.min_score}, "
            f"refit every {c.refit_every} steps.",
        ],
        figures={"exploration": _curves_figure(checkpoints, stacked)},
    )


def _curves_figure(steps: np.ndarray, curves: dict[str, dict[str, np.ndarray]]) -> Figure:
    """Coverage and contact rate (mean ± sd over seeds) against the steps of the budget, curiosity against random."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(curves), figsize=(9, 3.4))
    for ax, (what, per) in zip(axes, curves.items(), strict=True):
        for c, colour in zip(_CONDITIONS, ("C0", "C3"), strict=True):
            mean, sd = per[c].mean(0), per[c].std(0)
            ax.plot(steps, mean, color=colour, label=c)
            ax.fill_between(steps, mean - sd, mean + sd, color=colour, alpha=0.2)
        ax.set(xlabel="steps after warm-up", ylabel=what, title=f"C4 {what} (mean ± sd over seeds)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
