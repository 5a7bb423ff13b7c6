"""Local mechanism learning (thesis Eq. 4.33) with a validation split and early stopping.

    theta_i* = argmin_theta_i  sum_tau L_i( x_i(tau), f_{i,theta_i}(x_pa(i)(tau)) )

Each mechanism is trained on its own realised (parents, child) pairs; all of them share
one Adam loop because their parameters are disjoint. Inputs and outputs are standardised
with the training statistics (stored in the mechanism's normalisers), and the losses are
computed in those standardised units, ``z = (x - loc) / out_scale`` and ``s = scale / out_scale``:

- ``"mse"``: ``mean(z^2)``; trains the location only, and sigma_i is then set from residuals.
- ``"nll"``: the Gaussian NLL ``mean(0.5 z^2 / s^2 + log s)``, location and scale jointly.
- ``"beta_nll"``: ``mean(sg[s^(2 beta)] * (0.5 z^2 / s^2 + log s))`` (Seitzer et al. 2022),
  ``sg`` a stop-gradient; ``beta = 0`` is the NLL, ``beta = 1`` gives the location the MSE
  gradient. The default (``loss=None``) is ``"mse"`` for homoscedastic mechanisms and
  ``"beta_nll"`` with ``beta = 0.5`` for heteroscedastic ones. Heteroscedastic mechanisms
  add their bound penalty (:meth:`models.mechanisms.Mechanism.penalty`).

A seeded random share ``validation`` of the rows is held out. On it the scales are set
(the homoscedastic sigma_i from the validation residuals, whatever the loss; predicted scales
rescaled; ``schedule.calibration`` chooses the rule, and cross-fitted rows for gated sites), and with
``patience`` each mechanism stops when its validation criterion (MSE for ``"mse"``, the
site's NLL otherwise) has not improved for ``patience`` epochs and its best epoch is
restored. The members of an ensemble (:class:`models.EnsembleMechanism`) are trained on their
own bootstrap resamples of the training rows, from a generator derived from ``seed``.

A discrete site (:mod:`models.discrete`) is trained by its cross-entropy ``-mean log p(x | pa)``
(``"cross_entropy"``, reported in nats), with the same split and early stopping; a discrete
root gets the training frequencies (plus 1/2 per category) as its prior.

The training loop is :mod:`inference.fit_loop`, the rows of each site :mod:`inference.fit_rows`,
the sigma rules :mod:`inference.fit_sigma` (how held-out residuals set a scale:
:class:`CalibrationOptions`, nested in the schedule, with the cross-fitted calibration rows of
gated sites of :mod:`inference.fit_crossfit`); the schedule and result types
(:class:`FitSchedule`, its default :meth:`FitSchedule.auto`, the thesis protocol, :class:`FitResult`)
are in :mod:`inference.fit_types`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from inference.fit_crossfit import cross_fit
from inference.fit_loop import Run, restore_best, train
from inference.fit_rows import derived_seed, member_rows, site_rows
from inference.fit_rows import members as _members
from inference.fit_sigma import _RULE_TEXT, _set_sigmas, reset_recalibration
from inference.fit_types import FIT_KWARGS, LOSSES, CalibrationOptions, FitResult, FitSchedule, _schedule
from models.checks import check_bool, check_choice, check_names, check_seed
from models.discrete import DiscreteMechanism
from models.mechanisms import Mechanism
from models.variables import Role
from models.world import WorldModel, as_values, require_world_model

__all__ = ["FIT_KWARGS", "LOSSES", "CalibrationOptions", "FitResult", "FitSchedule", "fit"]

log = logging.getLogger(__name__)


def _standardiser(x: Tensor) -> tuple[Tensor, Tensor]:
    loc = x.mean(0)
    scale = x.std(0, unbiased=False)
    return loc, torch.where(scale > 1e-8, scale, torch.ones_like(scale))


def _predicts_scale(mech: Mechanism) -> bool:
    return any(m.log_sigma is None for m in _members(mech))


def _select(model: WorldModel, cols: Mapping[str, Tensor], variables: Sequence[str] | None) -> list[str]:
    """The trainable mechanisms to fit; every refusal happens here, before anything changes."""
    graph = model.graph
    if variables is None:
        supported = [v for v in graph.non_roots if v in cols and all(p in cols for p in graph.parents(v))]
        targets = [v for v in supported if model.mechanism(v).trainable]
        if not targets:
            fixed = [v for v in supported if not model.mechanism(v).trainable]
            why = f"the mechanisms of {fixed} are fixed functions, which fit does not train" if fixed else ""
            raise ValueError(
                f"no mechanism can be trained from columns {sorted(cols)}" + (f": {why}" if why else "")
            )
        skipped = [v for v in graph.non_roots if v not in targets]
        if skipped:
            log.debug("fit: not training %s (fixed, not requested or columns missing)", skipped)
        return targets
    for v in variables:
        graph.check_name(v, what="variable to fit")
        if graph.is_root(v):
            raise ValueError(f"{v!r} is a root and has no mechanism to fit")
        missing = [c for c in (v, *graph.parents(v)) if c not in cols]
        if missing:
            raise ValueError(f"cannot fit {v!r}: data has no column for {missing}")
        if not model.mechanism(v).trainable:
            raise ValueError(
                f"cannot fit {v!r}: its mechanism is a fixed {type(model.mechanism(v)).__name__}, which "
                "fit does not train; leave it out of variables"
            )
    return list(variables)


def fit(
    model: WorldModel,
    data: Mapping[str, Any],
    *,
    variables: Sequence[str] | None = None,
    loss: str | None = None,
    schedule: FitSchedule | None = None,
    seed: int = 0,
    progress_bar: bool = False,
) -> FitResult:
    """Train the local mechanisms (and their scales) of ``model`` in place.

    See the module docstring for the losses, the validation split and early stopping,
    :mod:`inference.fit_sigma` for the sigma rules and :mod:`inference.fit_types` for the
    default schedule.

    Args:
        model: the world model.
        data: name -> ``(N, dim)`` realised values (category codes for discrete sites), or
            a table (a DataFrame, :class:`models.tables.Table` or structured array; columns
            named like the variables are used); every trained variable needs its own column
            and its parents' columns.
        variables: mechanisms to train; default every non-root whose columns are present
            and whose mechanism is trainable. Fixed :class:`models.FunctionMechanism`
            mechanisms are never modified; :attr:`FitResult.skipped` says why a site was
            left out.
        loss: ``"mse"`` (thesis §5.2.1), ``"nll"`` or ``"beta_nll"``; None picks ``"mse"``
            for homoscedastic and ``"beta_nll"`` for heteroscedastic mechanisms. Discrete
            sites always use their cross-entropy.
        schedule: the :class:`FitSchedule`; None uses :meth:`FitSchedule.auto` for N rows.
        seed: seeds the split, the minibatch order and the bootstraps (local generators).
        progress_bar: show a tqdm bar over epochs.

    Returns:
        :class:`FitResult`. Non-action roots present in ``data`` also get their prior set
        from the training rows (Normal: mean and sd; discrete: frequencies).

    Raises:
        ValueError: a model that is not a :class:`WorldModel`, bad data (see
            :func:`models.world.as_values`; category codes out of range), fewer than 2 rows,
            unknown, root, fixed or repeated ``variables``, no trainable mechanism,
            ``loss="mse"`` for a mechanism that predicts its scale, a schedule that is not a
            FitSchedule, or a bad schedule argument (type or range: ``beta`` outside [0, 1],
            ``validation`` outside [0, 1), ``patience`` < 1 or without validation rows, a
            calibration that is not a :class:`CalibrationOptions`: rule, level in (0, 1), folds >= 2).
        FloatingPointError: the training loss became NaN or inf.
    """
    model = require_world_model(model)
    if loss is not None:
        loss = check_choice("loss", loss, LOSSES)
    seed = check_seed("seed", seed)
    progress_bar = check_bool("progress_bar", progress_bar)
    if variables is not None:
        variables = check_names("variables", variables, allow_empty=False)
    cols, n = _columns(model, data)
    schedule = _schedule(schedule, n)
    targets = _select(model, cols, variables)
    skipped = _skipped(model, cols, targets)
    for v, why in skipped.items():
        log.info("fit: %r not trained: %s", v, why)
    gen = torch.Generator().manual_seed(seed)
    run = _prepare(model, cols, n, targets, _losses(model, targets, loss), schedule, gen, seed)
    folds, calibration_seconds = cross_fit(run, schedule, seed, progress_bar)
    start = time.perf_counter()
    model.train()
    epochs_run = train(run, schedule, gen, progress_bar)
    model.eval()
    best_epoch = restore_best(run)
    seconds = time.perf_counter() - start
    sigma, sigma_rule = _set_sigmas(run, schedule.calibration, folds)
    for v, rule in sigma_rule.items():
        text = _RULE_TEXT[rule].format(level=schedule.calibration.level, folds=schedule.calibration.folds)
        log.info("fit: sigma of %r from %s", v, text)
    model.provenance = {
        **model.provenance,
        "fit": _provenance(run, schedule, loss, seed, n, best_epoch, sigma_rule),
    }
    result = _result(run, schedule, loss, epochs_run, seconds, sigma, sigma_rule, skipped, best_epoch)
    return dataclasses.replace(result, calibration_seconds=calibration_seconds)


def _columns(model: WorldModel, data: Any) -> tuple[dict[str, Tensor], int]:
    """The data as name -> ``(N, dim)`` columns, with at least 2 rows and valid category codes."""
    cols, n = as_values(model.graph, data, dtype=model.dtype)
    if n is None:
        raise ValueError("data is empty; fit needs name -> (N, dim) columns")
    if n < 2:
        raise ValueError(f"fit needs at least 2 rows of data, got {n}")
    model.check_codes(cols, "data")
    return cols, n


def _losses(model: WorldModel, targets: Sequence[str], loss: str | None) -> dict[str, str]:
    """The loss of each target: the cross-entropy for discrete sites, else ``loss`` or its default."""
    losses = {
        v: "cross_entropy"
        if isinstance(model.mechanism(v), DiscreteMechanism)
        else loss or ("beta_nll" if _predicts_scale(model.mechanism(v)) else "mse")
        for v in targets
    }
    bad = [v for v in targets if losses[v] == "mse" and _predicts_scale(model.mechanism(v))]
    if bad:
        raise ValueError(
            f"loss='mse' cannot train the scale of the heteroscedastic mechanisms of {bad}; "
            "use loss='beta_nll' (their default) or 'nll'"
        )
    return losses


def _prepare(
    model: WorldModel,
    cols: Mapping[str, Tensor],
    n: int,
    targets: list[str],
    losses: dict[str, str],
    schedule: FitSchedule,
    gen: torch.Generator,
    seed: int,
) -> Run:
    """Split the rows, draw the bootstraps, set the root priors and the normalisers."""
    validation, patience = schedule.validation, schedule.patience
    perm = torch.randperm(n, generator=gen)
    n_val = round(validation * n)
    train_idx, val_idx = perm[n_val:], perm[:n_val]
    if len(train_idx) < 1:
        raise ValueError(f"validation={validation:g} of {n} rows leaves no training rows")
    if patience is not None and n_val == 0:
        raise ValueError(
            f"patience={patience} needs validation rows; validation={validation:g} of {n} rows holds out none"
        )
    boot_gen = torch.Generator().manual_seed(derived_seed(seed, "bootstrap"))
    rows: dict[str, list[Tensor | None]] = {}
    _set_root_priors(model, cols, train_idx)
    inputs, outputs = {}, {}
    for v in targets:  # a gated site trains its on branch on the rows where the switch is on
        mech, inputs[v], outputs[v] = model.mechanism(v), model._parents(v, cols), cols[v]
        k = len(_members(mech))
        rows[v] = member_rows(v, mech, inputs[v], train_idx, k, schedule.bootstrap, boot_gen)
        norm_idx = site_rows(v, mech, inputs[v], train_idx)
        in_loc, in_scale = _standardiser(inputs[v][norm_idx])
        out_loc, out_scale = _standardiser(outputs[v][norm_idx])
        mech.set_normalization(in_loc, in_scale, out_loc, out_scale)
        reset_recalibration(mech)
    discrete = {v for v in targets if losses[v] == "cross_entropy"}
    mechs = {v: model.mechanism(v) for v in targets}
    return Run(targets, mechs, losses, discrete, inputs, outputs, train_idx, val_idx, rows, boot_gen)


def _set_root_priors(model: WorldModel, cols: Mapping[str, Tensor], train_idx: Tensor) -> None:
    """Non-action roots with a column: the Normal prior (or the category frequencies) of the training rows."""
    graph, categories = model.graph, model.discrete
    for r in graph.roots:
        if r in cols and graph[r].role is not Role.ACTION:
            if r in categories:
                counts = torch.bincount(cols[r][train_idx, 0].long(), minlength=categories[r])
                model.set_root_probs(r, counts.to(model.dtype) + 0.5)
                continue
            loc, scale = _standardiser(cols[r][train_idx])
            model.set_root_prior(r, loc, scale)


def _provenance(
    run: Run,
    schedule: FitSchedule,
    loss: str | None,
    seed: int,
    n: int,
    best_epoch: Mapping[str, int],
    sigma_rule: Mapping[str, str],
) -> dict[str, Any]:
    """The ``fit`` entry of the model's provenance."""
    return {
        "loss": loss or "auto",
        "losses": dict(run.losses),
        "beta": schedule.beta,
        "epochs": schedule.epochs,
        "batch_size": schedule.batch_size,
        "lr": schedule.lr,
        "seed": seed,
        "validation": schedule.validation,
        "patience": schedule.patience,
        "bootstrap": schedule.bootstrap,
        "calibration": schedule.calibration.to_dict(),
        "n": n,
        "trained": list(run.targets),
        "best_epoch": dict(best_epoch),
        "sigma_rule": dict(sigma_rule),
    }


def _result(
    run: Run,
    schedule: FitSchedule,
    loss: str | None,
    epochs_run: int,
    seconds: float,
    sigma: dict[str, tuple[float, ...]],
    sigma_rule: dict[str, str],
    skipped: dict[str, str],
    best_epoch: dict[str, int],
) -> FitResult:
    return FitResult(
        {v: tuple(c) for v, c in run.train_curves.items()},
        {v: tuple(c) for v, c in run.val_curves.items()},
        sigma,
        tuple(run.targets),
        loss or "auto",
        epochs_run,
        len(run.train_idx),
        len(run.val_idx),
        seconds,
        val_nll={v: tuple(c) for v, c in run.nll_curves.items()},
        best_epoch=best_epoch,
        losses=run.losses,
        beta=schedule.beta,
        patience=schedule.patience,
        sigma_rule=sigma_rule,
        skipped=skipped,
        schedule=schedule,
    )


def _skipped(model: WorldModel, cols: Mapping[str, Tensor], targets: Sequence[str]) -> dict[str, str]:
    """Why each non-root outside ``targets`` was not trained."""
    graph, out = model.graph, {}
    for v in graph.non_roots:
        if v in targets:
            continue
        missing = [c for c in (v, *graph.parents(v)) if c not in cols]
        if not model.mechanism(v).trainable:
            out[v] = f"its mechanism is a fixed {type(model.mechanism(v)).__name__}; it is left unchanged"
        elif missing:
            out[v] = f"data has no column for {missing}"
        else:
            out[v] = "not in variables"
    return out
