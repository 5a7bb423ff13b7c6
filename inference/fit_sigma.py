"""The sigma rules of :func:`inference.fit`: how each site's scale is set after training.

The rules, reported per site in :attr:`inference.fit_types.FitResult.sigma_rule` and logged
(:data:`_RULE_TEXT`): ``"validation"`` (RMS validation residual of the loc), ``"training"`` (RMS
training residual, no split), ``"nll"`` (the sigma learned by the NLL, no split),
``"predicted"`` (a heteroscedastic scale head, trained by the NLL, no split), ``"recalibrated"``
(that head rescaled per component so that the validation residuals have ``mean(z^2) = 1``,
:meth:`models.heteroscedastic.HeteroscedasticMechanism.recalibrate`; for an ensemble of K > 1
the moment-matched site scale is rescaled the same way after its members,
:meth:`models.ensemble.EnsembleMechanism.recalibrate`) and ``"none"`` (discrete sites).

:class:`inference.fit_types.CalibrationOptions` chooses the factor (:func:`scale_factor`):
``"variance"`` as above, or ``"conformal"`` (the k-th smallest ``|z|`` over the Normal's
quantile), reported with the word ``conformal``; and for a gated site's on branch the held-out
rows: its validation on rows, or with ``folds`` the out-of-fold rows of its refits
(:mod:`inference.fit_crossfit`), reported with ``out-of-fold``. A homoscedastic sigma is the
factor of its raw residuals (``z`` with scale 1): the RMS residual, or their conformal quantile
over the Normal's. A site without held-out rows keeps the rules without a split.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from statistics import NormalDist

import torch
from torch import Tensor

from inference.fit_loop import Run
from inference.fit_rows import members as _members
from inference.fit_rows import site_rows, trained
from inference.fit_types import CalibrationOptions
from models.discrete import DiscreteMechanism
from models.ensemble import EnsembleMechanism
from models.heteroscedastic import HeteroscedasticMechanism
from models.mechanisms import Mechanism

__all__: list[str] = []

log = logging.getLogger(__name__)

_VARIANCE = "rescaled to unit z-variance"
_CONFORMAL = "rescaled so that its Normal {level:g} interval holds the conformal share of |z|"
_OOF = "on the out-of-fold residuals of {folds} refits over all the rows where the switch is on"
_RULE_TEXT = {
    "validation": "the RMS residual on the validation rows",
    "validation conformal": "the conformal {level:g} quantile of the |residuals| on the validation rows, "
    "over the Normal's",
    "out-of-fold": f"the RMS residual {_OOF}",
    "out-of-fold conformal": f"the conformal {{level:g}} quantile of the |residuals| {_OOF}, over the Normal's",
    "training": "the RMS residual on the training rows (no validation split)",
    "nll": "the NLL fit (no validation split)",
    "predicted": "its scale head, trained by the NLL",
    "recalibrated": f"its scale (the head's, or the ensemble's) {_VARIANCE} on the validation rows",
    "recalibrated conformal": f"its scale (the head's, or the ensemble's) {_CONFORMAL} on the validation rows",
    "recalibrated out-of-fold": f"its scale (the head's, or the ensemble's) {_VARIANCE} {_OOF}",
    "recalibrated conformal out-of-fold": f"its scale (the head's, or the ensemble's) {_CONFORMAL} {_OOF}",
    "none": "nothing: the site is discrete",
}


def reset_recalibration(mech: Mechanism) -> None:
    """Zero the recalibration offsets of what fit trains (the site and its members) before a fit.

    The offset enters training through the scale, so a warm fit that kept the previous
    fit's offset would learn around it and recalibrate on top of it; on a component whose
    residuals are all 0 the offsets then fall without bound (a scale of 0 after a few refits).
    """
    site = trained(mech)
    for m in {id(m): m for m in [site, *_members(mech)]}.values():
        if isinstance(m, (HeteroscedasticMechanism, EnsembleMechanism)):
            m.reset_recalibration()


def scale_factor(z: Tensor, options: CalibrationOptions) -> Tensor:
    """The per-component factor ``(dim,)`` of held-out standardised residuals ``z`` ``(n, dim)``, n >= 1.

    ``"variance"``: ``sqrt(mean z^2)``; ``"conformal"``: ``|z|_(k) / Phi^-1((1 + level) / 2)``,
    ``k = ceil((n + 1) level)`` cut to n (:class:`inference.fit_types.CalibrationOptions`).
    Both at least 1e-6.
    """
    if options.rule == "variance":
        return z.pow(2).mean(0).sqrt().clamp_min(1e-6)
    n, level = z.shape[0], options.level
    k = math.ceil((n + 1) * level - 1e-9)  # (n + 1) level may land a rounding error above an integer
    if k > n:
        log.info(
            "fit: %d held-out rows are too few for a conformal %g quantile (it needs %d); using the largest |z|",
            n,
            level,
            math.ceil(level / (1 - level)),
        )
        k = n
    q = z.abs().sort(0).values[k - 1]
    return (q / NormalDist().inv_cdf((1 + level) / 2)).clamp_min(1e-6)


def _standardised(member: Mechanism, x: Tensor, y: Tensor) -> Tensor:
    """``(y - loc) / scale`` of a member with a scale head, the raw residual of one with a sigma."""
    if member.log_sigma is None:
        loc, scale = member.loc_scale(x)
        return (y - loc) / scale
    return y - member(x)


def _calibrate(
    mech: Mechanism,
    held: Sequence[tuple[Mechanism, Tensor]],
    x: Tensor,
    y: Tensor,
    options: CalibrationOptions,
) -> None:
    """Set the scales of ``mech`` (and of each held-out model) from the pooled held-out residuals.

    ``held``: ``[(model, rows)]``, each model a copy of ``mech`` (or ``mech`` itself) whose
    residuals on its ``rows`` are held out. Member j of ``mech`` (and of every model) gets the
    factor of member j's pooled z; then an ensemble's site scale that of the site's pooled z,
    computed with the members' new scales.
    """
    own = _members(mech)
    models = [(_members(m), rows) for m, rows in held]
    for j, member in enumerate(own):
        factor = scale_factor(torch.cat([_standardised(ms[j], x[r], y[r]) for ms, r in models]), options)
        for m in [member, *(ms[j] for ms, _ in models if ms[j] is not member)]:
            if m.log_sigma is None:
                m.recalibrate(factor)
            else:
                m.set_sigma(factor)
    if isinstance(mech, EnsembleMechanism) and mech.size > 1:
        z = []
        for m, r in held:
            loc, scale = m.loc_scale(x[r])
            z.append((y[r] - loc) / scale)
        mech.recalibrate(scale_factor(torch.cat(z), options))


def _rule(mech: Mechanism, options: CalibrationOptions, out_of_fold: bool) -> str:
    """The reported rule of a site calibrated on held-out rows (a key of :data:`_RULE_TEXT`)."""
    scaled = (mech.heteroscedastic and all(m.log_sigma is None for m in _members(mech))) or (
        isinstance(mech, EnsembleMechanism) and mech.size > 1
    )
    words = ["recalibrated" if scaled else ("out-of-fold" if out_of_fold else "validation")]
    if options.rule == "conformal":
        words.append("conformal")
    if scaled and out_of_fold:
        words.append("out-of-fold")
    return " ".join(words)


def _set_sigmas(
    run: Run,
    options: CalibrationOptions,
    folds: Mapping[str, Sequence[tuple[Mechanism, Tensor]]],
) -> tuple[dict[str, tuple[float, ...]], dict[str, str]]:
    """Set the scales calibrated on held-out rows (or, without any, from training) and report every site's sd.

    A site's held-out rows are its refits' out-of-fold rows when ``folds`` has it, else its
    validation rows (a gated site's: those where the switch is on). Without either, a
    homoscedastic ``"mse"`` member's sigma is the RMS training residual (on its own bootstrap
    rows), a sigma learned by the NLL and a scale head stay as trained.
    """
    out: dict[str, tuple[float, ...]] = {}
    rules: dict[str, str] = {}
    with torch.no_grad():
        for v in run.targets:
            site = run.mechs[v]  # a gated site: its on branch on the rows where it is on
            mech = trained(site)
            x, y = run.inputs[v], run.outputs[v]
            val_idx = site_rows(v, site, x, run.val_idx, "validation")
            train_idx = site_rows(v, site, x, run.train_idx)
            if isinstance(mech, DiscreteMechanism):
                rules[v] = "none"
                continue
            held = list(folds.get(v, ())) or ([(mech, val_idx)] if len(val_idx) else [])
            if held:
                _calibrate(mech, held, x, y, options)
                rules[v] = _rule(mech, options, v in folds)
            elif mech.heteroscedastic and all(m.log_sigma is None for m in _members(mech)):
                rules[v] = "predicted"
            else:
                rules[v] = "training" if run.losses[v] == "mse" else "nll"
                for member, boot in zip(_members(mech), run.rows[v], strict=True):
                    if member.log_sigma is not None and run.losses[v] == "mse":
                        idx = train_idx if boot is None else boot
                        member.set_sigma((y[idx] - member(x[idx])).pow(2).mean(0).sqrt().clamp_min(1e-6))
            if not mech.heteroscedastic:
                out[v] = tuple(float(s) for s in mech.sigma.detach())
            else:
                idx = val_idx if len(val_idx) else train_idx
                scale = mech.loc_scale(x[idx])[1]
                out[v] = tuple(float(s) for s in scale.pow(2).mean(0).sqrt())
    return out, rules
