"""The sigma rules of :func:`inference.fit`: how each site's scale is set after training.

The rules, reported per site in :attr:`inference.fit_types.FitResult.sigma_rule` and logged:
``"validation"`` (RMS validation residual of the loc), ``"training"`` (RMS training residual,
no split), ``"nll"`` (the sigma learned by the NLL, no split), ``"predicted"`` (a
heteroscedastic scale head, trained by the NLL, no split), ``"recalibrated"`` (that head
rescaled per component so that the validation residuals have ``mean(z^2) = 1``,
:meth:`models.heteroscedastic.HeteroscedasticMechanism.recalibrate`; for an ensemble of K > 1
the moment-matched site scale is rescaled the same way after its members,
:meth:`models.ensemble.EnsembleMechanism.recalibrate`) and ``"none"`` (discrete sites).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from inference.fit_rows import site_rows, trained
from models.discrete import DiscreteMechanism
from models.ensemble import EnsembleMechanism
from models.mechanisms import Mechanism
from models.world import WorldModel

__all__: list[str] = []

_RULE_TEXT = {
    "validation": "the RMS residual on the validation rows",
    "training": "the RMS residual on the training rows (no validation split)",
    "nll": "the NLL fit (no validation split)",
    "predicted": "its scale head, trained by the NLL",
    "recalibrated": "its scale (the head's, or the ensemble's) rescaled to unit validation z-variance",
    "none": "nothing: the site is discrete",
}


def _members(mech: Mechanism) -> list[Mechanism]:
    """The members that fit trains: an ensemble's, or the mechanism (a gated site's on branch)."""
    mech = trained(mech)
    return list(mech.members) if isinstance(mech, EnsembleMechanism) else [mech]


def _set_sigmas(
    model: WorldModel,
    targets: Sequence[str],
    losses: Mapping[str, str],
    inputs: Mapping[str, Tensor],
    outputs: Mapping[str, Tensor],
    all_val: Tensor,
    all_train: Tensor,
    rows: Mapping[str, Sequence[Tensor | None]],
) -> tuple[dict[str, tuple[float, ...]], dict[str, str]]:
    """Set each homoscedastic member's sigma from residuals and report every site's sd.

    With validation rows, sigma is the RMS validation residual (whatever the loss);
    without, the RMS training residual (the member's own bootstrap rows) for ``"mse"``,
    and the learned sigma otherwise.
    """
    out: dict[str, tuple[float, ...]] = {}
    rules: dict[str, str] = {}
    with torch.no_grad():
        for v in targets:
            site = model.mechanism(v)  # a gated site: its on branch on the rows where it is on
            mech = trained(site)
            val_idx = site_rows(v, site, inputs[v], all_val, "validation")
            train_idx = site_rows(v, site, inputs[v], all_train)
            if isinstance(mech, DiscreteMechanism):
                rules[v] = "none"
                continue
            if mech.heteroscedastic and all(m.log_sigma is None for m in _members(mech)):
                rules[v] = "recalibrated" if len(val_idx) else "predicted"
            elif len(val_idx):
                rules[v] = "validation"
            else:
                rules[v] = "training" if losses[v] == "mse" else "nll"
            for member, boot in zip(_members(mech), rows[v], strict=True):
                if member.log_sigma is None:
                    if len(val_idx):
                        loc, scale = member.loc_scale(inputs[v][val_idx])
                        z2 = ((outputs[v][val_idx] - loc) / scale).pow(2).mean(0)
                        member.recalibrate(z2.sqrt().clamp_min(1e-6))
                    continue
                if len(val_idx):
                    idx = val_idx
                elif losses[v] == "mse":
                    idx = train_idx if boot is None else boot
                else:
                    continue
                resid = outputs[v][idx] - member(inputs[v][idx])
                member.set_sigma(resid.pow(2).mean(0).sqrt().clamp_min(1e-6))
            if isinstance(mech, EnsembleMechanism) and mech.size > 1 and len(val_idx):
                loc, scale = mech.loc_scale(inputs[v][val_idx])
                mech.recalibrate(((outputs[v][val_idx] - loc) / scale).pow(2).mean(0).sqrt().clamp_min(1e-6))
                rules[v] = "recalibrated"
            if not mech.heteroscedastic:
                out[v] = tuple(float(s) for s in mech.sigma.detach())
            else:
                idx = val_idx if len(val_idx) else train_idx
                scale = mech.loc_scale(inputs[v][idx])[1]
                out[v] = tuple(float(s) for s in scale.pow(2).mean(0).sqrt())
    return out, rules
