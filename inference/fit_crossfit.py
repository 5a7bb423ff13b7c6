"""Cross-fitted calibration rows for the on branches of gated sites (``CalibrationOptions.folds``).

A gated site trains its on branch on the rows where its switch is on (:mod:`inference.fit_rows`);
when the switch is rarely on, the validation share holds few of them (10 % of 1200 rows at 12 %
contact: ~15), too few to set a scale. With K folds every on row is held out once:

    on = train_on ++ val_on                      (the training, then the validation on rows)
    fold(r) = perm(len(on))[r] mod K              (a seeded permutation)
    refit k: a fresh on branch, trained on {r in train_on : fold(r) != k}
             and early-stopped on {r in val_on : fold(r) != k}
    held-out rows of refit k: {r in on : fold(r) = k}

Each refit starts from a fresh initialisation built from the on branch's config (a deep copy of
it before training when it has none), with the on branch's normalisers, so it has seen none of
its held-out rows even when :func:`inference.fit` refits a trained model; it is trained with the
same schedule, loss and bootstraps as the on branch, for up to the same epochs, by the same loop
(:mod:`inference.fit_loop`; all refits in one Adam loop, their parameters being disjoint). Its
random streams are derived from the fit's seed and are not the ones of the main fit, so the on
branch that :func:`inference.fit` returns is trained exactly as without folds.
:mod:`inference.fit_sigma` then calibrates that on branch on the pooled held-out residuals of
the refits. This is the cross-fitting of :mod:`inference.crossfit`'s structure scores, with the
site's own mechanism in place of its ridge regression.
"""

from __future__ import annotations

import copy
import logging
import time

import torch
from torch import Tensor

from inference.fit_loop import Run, restore_best, train
from inference.fit_rows import derived_seed, epoch_rows, site_rows
from inference.fit_rows import members as _members
from inference.fit_types import FitSchedule
from models.gated import GatedMechanism
from models.mechanisms import Mechanism, make_mechanism

__all__: list[str] = []

log = logging.getLogger(__name__)

#: A site's refits: ``[(refit k of the on branch, its held-out rows (n_k,)), ...]``.
Folds = list[tuple[Mechanism, Tensor]]


def _fresh(on: Mechanism, seed: int) -> Mechanism:
    """A new copy of the on branch from its config (a deep copy when it has none), its normalisers, its dtype."""
    ref = _members(on)[0]
    buildable = on.serialisable and all(m.serialisable for m in _members(on))
    new = make_mechanism(on.config(), seed=seed) if buildable else copy.deepcopy(on)
    new = new.to(ref.out_loc.dtype)
    new.set_normalization(ref.in_loc, ref.in_scale, ref.out_loc, ref.out_scale)
    return new


def _split(
    on_train: Tensor, on_val: Tensor, folds: int, gen: torch.Generator
) -> list[tuple[Tensor, Tensor, Tensor]]:
    """Per fold ``(training rows, early-stopping rows, held-out rows)``; empty when a fold has no training row."""
    on = torch.cat([on_train, on_val])
    fold = torch.randperm(len(on), generator=gen) % folds
    n_train = len(on_train)
    out = []
    for k in range(folds):
        held = fold == k
        fit_rows = on_train[~held[:n_train]]
        if not len(fit_rows):
            return []
        out.append((fit_rows, on_val[~held[n_train:]], on[held]))
    return out


def cross_fit(
    run: Run, schedule: FitSchedule, seed: int, progress_bar: bool
) -> tuple[dict[str, Folds], float]:
    """Train the K refits of every gated target's on branch; returns ``(site -> folds, wall seconds)``.

    Sites with fewer than 2 K on rows (or a fold without training rows) get no folds: they are
    calibrated on their validation on rows (logged). ``run`` is the main fit's prepared run
    (normalisers set, not yet trained or already trained: the refits do not read its weights).
    """
    folds = schedule.calibration.folds
    if folds is None or not any(isinstance(run.mechs[v], GatedMechanism) for v in run.targets):
        return {}, 0.0
    gen = torch.Generator().manual_seed(derived_seed(seed, "crossfit"))
    boot_gen = torch.Generator().manual_seed(derived_seed(seed, "crossfit bootstrap"))
    refits = Run([], {}, {}, set(), {}, {}, run.train_idx, run.val_idx[:0], {}, boot_gen)
    held: dict[str, list[tuple[str, Tensor]]] = {}
    for v in run.targets:
        site = run.mechs[v]
        if not isinstance(site, GatedMechanism):
            continue
        on_train = site_rows(v, site, run.inputs[v], run.train_idx)
        on_val = site_rows(v, site, run.inputs[v], run.val_idx, "validation")
        parts = _split(on_train, on_val, folds, gen) if len(on_train) + len(on_val) >= 2 * folds else []
        if not parts:
            log.info(
                "fit: %r has %d on rows, too few for %d calibration folds; its on branch is calibrated on "
                "its %d validation on rows",
                v,
                len(on_train) + len(on_val),
                folds,
                len(on_val),
            )
            continue
        held[v] = []
        for k, (fit_rows, stop_rows, held_rows) in enumerate(parts):
            name = f"{v} [fold {k}]"
            mech = _fresh(site.on, derived_seed(seed, name))
            refits.targets.append(name)
            refits.mechs[name], refits.losses[name] = mech, run.losses[v]
            refits.inputs[name], refits.outputs[name] = run.inputs[v], run.outputs[v]
            members = len(_members(mech))
            refits.rows[name] = epoch_rows(
                fit_rows, len(run.train_idx), members, schedule.bootstrap, boot_gen
            )
            refits.val_rows[name] = stop_rows
            held[v].append((name, held_rows))
    if not refits.targets:
        return {}, 0.0
    start = time.perf_counter()
    train(refits, schedule, gen, progress_bar, desc="cross-fit")
    restore_best(refits)
    seconds = time.perf_counter() - start
    log.info("fit: %d calibration refits of %s in %.2f s", len(refits.targets), sorted(held), seconds)
    return {v: [(refits.mechs[name], rows) for name, rows in parts] for v, parts in held.items()}, seconds
