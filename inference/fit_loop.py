"""The training loop of :func:`inference.fit`: one Adam loop over disjoint mechanisms, with early stopping.

A :class:`Run` holds what the loop needs: per target the mechanism it trains (a site's, or a
stand-alone copy such as a cross-fitting fold's on branch), its loss, its standardised columns,
the training rows of each member per epoch and its validation rows. Every target's parameters
are disjoint, so summing the losses in one Adam loop trains each one as if it were alone:

    per epoch: minibatches of ``batch_size`` of the ``n_train`` training positions; each member
    reads its own row order (its bootstrap, or a gated site's tiled on rows);
    validation: the MSE of the loc (and the site's NLL for ``"nll"`` / ``"beta_nll"``, the
    cross-entropy for a discrete site); with ``patience`` a target stops when its criterion
    has not improved for ``patience`` epochs and its best epoch is restored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor
from tqdm import tqdm

from inference.fit_rows import members as _members
from inference.fit_types import FitSchedule
from models.discrete import DiscreteMechanism
from models.mechanisms import Mechanism

__all__: list[str] = []


def member_loss(member: Mechanism, x: Tensor, y: Tensor, loss: str, beta: float) -> tuple[Tensor, Tensor]:
    """``(training loss, residual)`` of one member on a batch, in standardised units.

    For a discrete member the "residual" is the per-row cross-entropy ``(B, 1)`` (nats).
    """
    if isinstance(member, DiscreteMechanism):
        nll = -member.distribution(x).log_prob(y)
        return nll.mean(), nll.detach()[:, None].sqrt()
    if member.log_sigma is None:
        loc, scale = member.loc_scale(x)
    else:
        loc, scale = member(x), None
    resid = y - loc
    z = resid / member.out_scale
    if loss == "mse":
        return (z**2).mean(), resid
    s = member.sigma / member.out_scale if scale is None else scale / member.out_scale
    nll = 0.5 * (z / s) ** 2 + torch.log(s)
    if loss == "beta_nll" and beta > 0:
        nll = s.detach() ** (2 * beta) * nll
    return nll.mean() + member.penalty(), resid


@dataclass
class Run:
    """The data and the state of one training run: mechanisms, columns, rows, curves, best epochs.

    Attributes:
        targets: the names trained (site names, or a site's name with a fold suffix).
        mechs: name -> the mechanism trained (a gated site's whole mechanism: its on branch is trained).
        inputs, outputs: name -> ``(N, in_dim)`` parents and ``(N, out_dim)`` values.
        train_idx: ``(n_train,)`` the training rows; an epoch has ``n_train`` positions.
        val_idx: the validation rows of every target without its own in ``val_rows``.
        rows: name -> per member the ``(n_train,)`` rows of its epoch (None: the minibatch rows).
        val_rows: name -> that target's own validation rows.
    """

    targets: list[str]
    mechs: dict[str, Mechanism]
    losses: dict[str, str]
    discrete: set[str]
    inputs: dict[str, Tensor]
    outputs: dict[str, Tensor]
    train_idx: Tensor
    val_idx: Tensor
    rows: dict[str, list[Tensor | None]]
    boot_gen: torch.Generator
    train_curves: dict[str, list[float]] = field(default_factory=dict)
    val_curves: dict[str, list[float]] = field(default_factory=dict)
    nll_curves: dict[str, list[float]] = field(default_factory=dict)
    best: dict[str, tuple[float, int, dict[str, Tensor]]] = field(default_factory=dict)
    lowest: dict[str, tuple[float, float]] = field(default_factory=dict)
    se_curves: dict[str, list[float]] = field(default_factory=dict)
    tolerant: set[str] = field(default_factory=set)
    active: list[str] = field(default_factory=list)
    val_rows: dict[str, Tensor] = field(default_factory=dict)

    def validation(self, name: str) -> Tensor:
        """The validation rows of ``name``."""
        return self.val_rows.get(name, self.val_idx)


def train(
    run: Run, schedule: FitSchedule, gen: torch.Generator, progress_bar: bool, desc: str = "fit"
) -> int:
    """The Adam epochs with validation and early stopping; returns the epochs run.

    ``gen`` draws the minibatch order (``run.boot_gen`` the members' row orders). A target
    without validation rows runs every epoch.
    """
    params = []
    for v in run.targets:
        for member in _members(run.mechs[v]):
            params += [
                p for name, p in member.named_parameters() if run.losses[v] != "mse" or name != "log_sigma"
            ]
    optim = torch.optim.Adam(params, lr=schedule.lr)
    for curves in (run.train_curves, run.val_curves, run.nll_curves, run.se_curves):
        curves.update({v: [] for v in run.targets})
    run.active = list(run.targets)
    run.tolerant = {v for v in run.targets if _few_parameters(run.mechs[v], len(run.train_idx))}
    for v in run.targets:
        run.mechs[v].train()
    bar = tqdm(range(schedule.epochs), desc=desc, disable=not progress_bar, leave=False)
    epochs_run = 0
    for epoch in bar:
        epochs_run = epoch + 1
        worst = _epoch(run, optim, schedule, gen)
        _validate(run)
        if schedule.patience is not None:
            _early_stop(run, epoch, schedule.patience, schedule.plateau_se)
            if not run.active:
                break
        bar.set_postfix(mse=f"{worst:.4g}")
    for v in run.targets:
        run.mechs[v].eval()
    return epochs_run


def _epoch(run: Run, optim: torch.optim.Optimizer, schedule: FitSchedule, gen: torch.Generator) -> float:
    """One pass over the training rows in minibatches; returns the worst mean training loss."""
    train_idx, batch_size, active = run.train_idx, schedule.batch_size, run.active
    n_train = len(train_idx)
    order = train_idx[torch.randperm(n_train, generator=gen)]
    member_order = {
        v: [b if b is None else b[torch.randperm(n_train, generator=run.boot_gen)] for b in run.rows[v]]
        for v in active
    }
    sums = dict.fromkeys(active, 0.0)
    for b in range(0, n_train, batch_size):
        idx = order[b : b + batch_size]
        optim.zero_grad()
        total = 0.0
        for v in active:
            members = _members(run.mechs[v])
            for member, m_order in zip(members, member_order[v], strict=True):
                m_idx = idx if m_order is None else m_order[b : b + batch_size]
                term, resid = member_loss(
                    member, run.inputs[v][m_idx], run.outputs[v][m_idx], run.losses[v], schedule.beta
                )
                total = total + term
                sums[v] += float((resid.detach() ** 2).mean(-1).sum()) / len(members)
        total.backward()
        optim.step()
    for v in active:
        run.train_curves[v].append(sums[v] / n_train)
    worst = max(run.train_curves[v][-1] for v in active)
    if not math.isfinite(worst):
        raise FloatingPointError(f"training diverged (loss {worst}); lower lr")
    return worst


def _validate(run: Run) -> None:
    """Append the validation criterion of every active site and its standard error.

    The criterion is the MSE of the loc (and the NLL for ``"nll"`` / ``"beta_nll"``), the
    cross-entropy of a discrete site; ``se_curves`` holds ``sd(per-row criterion) / sqrt(n_val)``
    of the one that early stopping reads.
    """
    with torch.no_grad():
        for v in run.active:
            mech, rows = run.mechs[v], run.validation(v)
            if not len(rows):
                continue
            x, y = run.inputs[v][rows], run.outputs[v][rows]
            if v in run.discrete:  # the validation criterion is the cross-entropy
                per_row = -mech.distribution(x).log_prob(y)
                run.val_curves[v].append(float(per_row.mean()))
                run.nll_curves[v].append(run.val_curves[v][-1])
                run.se_curves[v].append(_se(per_row))
                continue
            per_row = ((y - mech(x)) ** 2).mean(-1)
            run.val_curves[v].append(float(per_row.mean()))
            if run.losses[v] != "mse":
                loc, scale = mech.loc_scale(x)
                per_row = -torch.distributions.Normal(loc, scale).log_prob(y).mean(-1)
                run.nll_curves[v].append(float(per_row.mean()))
            run.se_curves[v].append(_se(per_row))


#: A mechanism with at most this many trainable parameters per training row cannot overfit
#: noticeably; :attr:`FitSchedule.plateau_se` applies to it.
ROWS_PER_PARAMETER = 100


def _few_parameters(mech: Mechanism, n_train: int) -> bool:
    """Whether ``mech`` has at most ``n_train / ROWS_PER_PARAMETER`` trainable parameters."""
    count = sum(p.numel() for p in mech.parameters() if p.requires_grad)
    return count * ROWS_PER_PARAMETER <= n_train


def _se(per_row: Tensor) -> float:
    """Standard error of the mean of ``per_row`` (0 for one row)."""
    n = per_row.numel()
    return float(per_row.std() / math.sqrt(n)) if n > 1 else 0.0


def _early_stop(run: Run, epoch: int, patience: int, tolerance: float = 0.0) -> None:
    """Keep each site's epoch; stop the sites without a kept epoch for ``patience`` epochs.

    An epoch is kept when its criterion is below the lowest so far, or, for a mechanism with
    few parameters (``run.tolerant``: at most one per ``ROWS_PER_PARAMETER`` training rows),
    within ``tolerance`` standard errors of that lowest value: such a mechanism cannot
    overfit, so its longest-trained parameters whose held-out criterion is not
    distinguishably worse than the best are kept (a slow optimiser is not stopped by noise).
    """
    for v in list(run.active):
        if not len(run.validation(v)):
            continue
        score = run.val_curves[v][-1] if run.losses[v] == "mse" else run.nll_curves[v][-1]
        if not math.isfinite(score):
            raise FloatingPointError(f"validation loss of {v!r} is {score}; lower lr")
        lowest = run.lowest.get(v)
        if lowest is None or score < lowest[0]:
            lowest = run.lowest[v] = (score, run.se_curves[v][-1])
        within = v in run.tolerant and score <= lowest[0] + tolerance * lowest[1]
        if score == lowest[0] or (tolerance > 0 and within):
            state = {key: t.detach().clone() for key, t in run.mechs[v].state_dict().items()}
            run.best[v] = (score, epoch + 1, state)
        elif epoch + 1 - run.best[v][1] >= patience:
            run.active.remove(v)


def restore_best(run: Run) -> dict[str, int]:
    """Load each early-stopped site's best parameters; returns name -> the 1-based epoch kept."""
    best_epoch = {v: len(run.train_curves[v]) for v in run.targets}
    for v, (_, epoch_kept, state) in run.best.items():
        run.mechs[v].load_state_dict(state)
        best_epoch[v] = epoch_kept
    return best_epoch
