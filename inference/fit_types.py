"""The arguments and the outcome of :func:`inference.fit`: losses, schedule, calibration and result.

:data:`LOSSES`, :data:`FIT_KWARGS`, :class:`FitSchedule` (with its default :meth:`FitSchedule.auto`),
:class:`CalibrationOptions` (how held-out residuals set the scales, nested in the schedule) and
:class:`FitResult`.

The default schedule (``schedule=None``, :meth:`FitSchedule.auto`) scales with the number of
rows N so that it behaves from N = 200 to N = 10^6:

    validation = 0.2 (N < 10 000) or 0.1,        n_train = N - round(validation * N)
    small tables (n_train <= 20 000): full batch, epochs 3000, patience 100, lr 0.02,
        plateau_se 1 (a mechanism with at most one parameter per 100 training rows keeps its
        latest epoch within one standard error of its best held-out criterion)
    larger tables: batch_size = clip(n_train // 8, 32, 2048),
        epochs = clip(ceil(10 000 / steps per epoch), 10, 500)   (~10 000 Adam steps),
        patience = max(5, epochs // 10),  lr = 0.01

Every small-table epoch is one Adam step on every training row, so the held-out curve is
smooth and early stopping reads it without minibatch noise; a flexible mechanism (an MLP on a
few hundred rows) stops after tens to hundreds of steps, and one that cannot overfit (a linear
or logistic mechanism on thousands of rows) runs until it has converged, not until noise in
its held-out loss first rises. A plain schedule without held-out rows overfits (the noise sd
shrinks towards 0). Below 20 rows there is no split and no early stopping.

The thesis protocol (§5.2.1) is ``fit(model, data, loss="mse",
schedule=FitSchedule(epochs=120, batch_size=2048, lr=0.01, validation=0.0))``: no held-out
rows, sigma_i the RMS training residual, every epoch kept, the same random streams (split,
minibatch order) as always; a test holds its numbers fixed.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from models.checks import check_bool, check_choice, check_float, check_int, describe

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["CALIBRATION_RULES", "FIT_KWARGS", "LOSSES", "CalibrationOptions", "FitResult", "FitSchedule"]

LOSSES = ("mse", "nll", "beta_nll")

#: Most training rows for which :meth:`FitSchedule.auto` trains full batch.
FULL_BATCH_ROWS = 20_000

#: The rules of :class:`CalibrationOptions`: unit z-variance, or the conformal quantile at a level.
CALIBRATION_RULES = ("variance", "conformal")

#: The keyword arguments of :func:`fit`; wrappers that forward ``**fit_kwargs`` check against it.
FIT_KWARGS = ("variables", "loss", "schedule", "seed", "progress_bar")


@dataclass(frozen=True)
class CalibrationOptions:
    """How :func:`fit` sets the scales it takes from held-out residuals (:mod:`inference.fit_sigma`).

    With held-out standardised residuals ``z = (x - loc(pa)) / scale(pa)`` (n rows, per
    component; ``scale = 1`` for a homoscedastic sigma, which is then the factor itself), each
    component's scale is multiplied by

        "variance":  c = sqrt(mean z^2)                             (unit held-out z-variance)
        "conformal": c = |z|_(k) / Phi^-1((1 + level) / 2),  k = ceil((n + 1) level)

    ``|z|_(k)`` the k-th smallest ``|z|`` (split-conformal: the Normal interval at ``level``
    then covers at least ``level`` of exchangeable new rows; k is cut to n below
    ``n = level / (1 - level)`` rows, 9 at 0.9, where that guarantee is lost). The site stays a
    Normal; only its scale changes. The held-out rows are the validation rows, or for a gated
    site's on branch with ``folds``, out-of-fold rows:

        folds = K:   the on rows (training and validation) fall into K seeded folds; refit k is a
                     fresh initialisation of the on branch (from its config, so it has seen none
                     of fold k, also when ``fit`` refits a trained model), trained with the same
                     schedule on the training on rows outside fold k, early-stopped on the
                     validation on rows outside fold k; its z on fold k are the held-out ones.
                     The on branch that ``fit`` returns is trained as without ``folds``; it gets
                     the factors of the pooled out-of-fold z. Fewer than 2 K on rows: the
                     validation rows are used.

    An ensemble is calibrated member by member, then its moment-matched site scale (the members'
    factors applied to the refits too).

    Attributes:
        rule: ``"variance"`` or ``"conformal"`` (:data:`CALIBRATION_RULES`).
        level: the conformal rule's probability, in (0, 1).
        folds: K >= 2 cross-fitting folds for gated sites' on branches; None: their validation on rows.
    """

    rule: str = "variance"
    level: float = 0.9
    folds: int | None = None

    def __post_init__(self) -> None:
        check_choice("calibration rule", self.rule, CALIBRATION_RULES)
        check_float("calibration level", self.level, minimum=0.0, maximum=1.0, min_open=True, max_open=True)
        if self.folds is not None:
            check_int("calibration folds", self.folds, minimum=2)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class FitSchedule:
    """The training schedule of :func:`fit` (see the module docstring for :meth:`auto`).

    Attributes:
        epochs: the most passes over the training rows, >= 1.
        batch_size: Adam minibatch rows, >= 1.
        lr: Adam learning rate, > 0.
        validation: share of rows held out (seeded), in [0, 1); 0 is the thesis protocol.
        patience: stop a mechanism after this many epochs (>= 1) without a better
            validation criterion and restore its best epoch; None keeps the last epoch.
        bootstrap: train each member of an ensemble on its own bootstrap resample.
        beta: the beta of ``"beta_nll"``, in [0, 1].
        calibration: how held-out residuals set the scales (:class:`CalibrationOptions`).
        plateau_se: with ``patience``, a mechanism with at most one trainable parameter per
            100 training rows keeps a later epoch whose validation criterion is within
            ``plateau_se`` standard errors of its lowest (>= 0; 0: the lowest epoch).
    """

    epochs: int = 120
    batch_size: int = 2048
    lr: float = 0.01
    validation: float = 0.1
    patience: int | None = None
    bootstrap: bool = True
    beta: float = 0.5
    calibration: CalibrationOptions = CalibrationOptions()
    plateau_se: float = 0.0

    def __post_init__(self) -> None:
        check_int("epochs", self.epochs, minimum=1)
        check_float("plateau_se", self.plateau_se, minimum=0.0)
        check_int("batch_size", self.batch_size, minimum=1)
        check_float("lr", self.lr, minimum=0.0, min_open=True)
        check_float("validation", self.validation, minimum=0.0, maximum=1.0, max_open=True)
        if self.patience is not None:
            check_int("patience", self.patience, minimum=1)
        check_bool("bootstrap", self.bootstrap)
        check_float("beta", self.beta, minimum=0.0, maximum=1.0)
        if not isinstance(self.calibration, CalibrationOptions):
            raise ValueError(f"calibration must be a CalibrationOptions, got {describe(self.calibration)}")

    @classmethod
    def auto(cls, n: int) -> FitSchedule:
        """The default schedule for ``n`` rows (module docstring)."""
        n = check_int("n", n, minimum=1)
        if n < 20:
            return cls(epochs=200, batch_size=max(n, 1), lr=0.01, validation=0.0, patience=None)
        validation = 0.2 if n < 10_000 else 0.1
        n_train = n - round(validation * n)
        if n_train <= FULL_BATCH_ROWS:
            return cls(3000, n_train, 0.02, validation, 100, plateau_se=1.0)
        batch = int(min(2048, max(32, n_train // 8)))
        steps = math.ceil(n_train / batch)
        epochs = int(min(500, max(10, math.ceil(10_000 / steps))))
        return cls(epochs, batch, 0.01, validation, max(5, epochs // 10))

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit`.

    Attributes:
        train_loss: name -> per-epoch mean training MSE, in the variable's units squared
            (for an ensemble, the mean over members on their own bootstrap rows).
        val_loss: name -> per-epoch validation MSE of the site's loc (empty without a split).
        sigma: name -> residual sd per component: sigma_i for homoscedastic sites, else the
            RMS predictive sd over the validation rows (training rows without a split).
        trained: names of the mechanisms trained.
        loss: the requested loss, or ``"auto"`` for the per-mechanism default.
        epochs: epochs run (the most any mechanism ran).
        n_train, n_val: training and validation rows.
        seconds: wall time of the training loop.
        val_nll: name -> per-epoch validation NLL of the site's Normal, nats per unit and
            dim (empty for ``"mse"`` sites, whose sigma is set after training, and without
            a split).
        best_epoch: name -> the 1-based epoch whose parameters were kept.
        losses: name -> the loss each mechanism was trained with.
        beta: the beta of ``"beta_nll"``.
        patience: the early-stopping patience (None: every epoch kept).
        sigma_rule: name -> how the site's scale was set, a key of :data:`inference.fit_sigma.RULES`:
            ``"validation"``, ``"training"``, ``"nll"``, ``"predicted"``, ``"recalibrated"``,
            ``"none"``, and with :class:`CalibrationOptions` the conformal and out-of-fold forms
            (``"recalibrated conformal out-of-fold"`` ...).
        skipped: name -> why a non-root was not trained (fixed function, columns missing).
        schedule: the schedule used.
        calibration_seconds: wall time of the cross-fitting refits (0 without them).
    """

    train_loss: dict[str, tuple[float, ...]]
    val_loss: dict[str, tuple[float, ...]]
    sigma: dict[str, tuple[float, ...]]
    trained: tuple[str, ...]
    loss: str
    epochs: int
    n_train: int
    n_val: int
    seconds: float
    val_nll: dict[str, tuple[float, ...]] = field(default_factory=dict)
    best_epoch: dict[str, int] = field(default_factory=dict)
    losses: dict[str, str] = field(default_factory=dict)
    beta: float = 0.5
    patience: int | None = None
    sigma_rule: dict[str, str] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    schedule: FitSchedule | None = None
    calibration_seconds: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible summary: per-site losses, sigmas, rules and the schedule."""
        return {
            "trained": list(self.trained),
            "losses": dict(self.losses),
            "sigma": {k: list(v) for k, v in self.sigma.items()},
            "sigma_rule": dict(self.sigma_rule),
            "skipped": dict(self.skipped),
            "best_epoch": dict(self.best_epoch),
            "final_train_loss": {k: v[-1] for k, v in self.train_loss.items() if v},
            "final_val_loss": {k: v[-1] for k, v in self.val_loss.items() if v},
            "epochs": self.epochs,
            "n_train": self.n_train,
            "n_val": self.n_val,
            "seconds": self.seconds,
            "calibration_seconds": self.calibration_seconds,
            "schedule": None if self.schedule is None else self.schedule.to_dict(),
        }

    def plot(self) -> Figure:
        """Loss curves per mechanism (log scale), the kept epoch marked; returns the Figure."""
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, len(self.trained), figsize=(3.2 * len(self.trained), 2.8), squeeze=False)
        for ax, name in zip(axes[0], self.trained, strict=True):
            train = self.train_loss[name]
            ax.plot(range(1, len(train) + 1), train, label="train")
            if self.val_loss.get(name):
                ax.plot(range(1, len(self.val_loss[name]) + 1), self.val_loss[name], label="validation")
            if name in self.best_epoch:
                ax.axvline(self.best_epoch[name], color="0.5", lw=0.8, ls="--")
            ax.set_yscale("log")
            ax.set_title(name, fontsize=9)
            ax.set_xlabel("epoch")
            ax.set_ylabel("MSE")
            ax.legend(fontsize=7)
        fig.tight_layout()
        return fig


def _schedule(schedule: Any, n: int) -> FitSchedule:
    """The schedule: the one given, or :meth:`FitSchedule.auto` for n rows."""
    if schedule is not None and not isinstance(schedule, FitSchedule):
        raise ValueError(f"schedule must be a FitSchedule or None, got {describe(schedule)}")
    return schedule if schedule is not None else FitSchedule.auto(n)
