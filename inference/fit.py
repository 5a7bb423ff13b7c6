"""Local mechanism learning (thesis Eq. 4.33).

    theta_i* = argmin_theta_i  sum_tau L_i( x_i(tau), f_{i,theta_i}(x_pa(i)(tau)) )

Each mechanism is trained on its own realised (parents, child) pairs; all of them share
one Adam loop because their parameters are disjoint. ``loss="mse"`` trains f_i with the
squared error and then sets sigma_i to the RMS training residual; ``loss="nll"`` trains
f_i and sigma_i jointly with the Gaussian negative log-likelihood. Inputs and outputs are
standardised with the training statistics (stored in the mechanism's normalisers).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor
from tqdm import tqdm

from models.checks import check_bool, check_choice, check_float, check_int, check_names, check_seed
from models.variables import Role
from models.world import WorldModel, as_values, require_world_model

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["FIT_KWARGS", "LOSSES", "FitResult", "fit"]

log = logging.getLogger(__name__)

LOSSES = ("mse", "nll")

#: The keyword arguments of :func:`fit`; wrappers that forward ``**fit_kwargs`` check against it.
FIT_KWARGS = ("variables", "loss", "epochs", "batch_size", "lr", "val_fraction", "seed", "progress_bar")


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit`.

    Attributes:
        train_loss: name -> per-epoch mean training MSE, in the variable's units squared.
        val_loss: name -> per-epoch validation MSE (empty tuples without a split).
        sigma: name -> fitted residual sd per component.
        trained: names of the mechanisms trained.
        loss: ``"mse"`` or ``"nll"``.
        epochs, n_train, n_val, seconds: run facts.
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

    def plot(self) -> Figure:
        """Loss curves per mechanism (log scale); returns the Figure."""
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, len(self.trained), figsize=(3.2 * len(self.trained), 2.8), squeeze=False)
        for ax, name in zip(axes[0], self.trained, strict=True):
            ax.plot(range(1, self.epochs + 1), self.train_loss[name], label="train")
            if self.val_loss[name]:
                ax.plot(range(1, self.epochs + 1), self.val_loss[name], label="validation")
            ax.set_yscale("log")
            ax.set_title(name, fontsize=9)
            ax.set_xlabel("epoch")
            ax.set_ylabel("MSE")
            ax.legend(fontsize=7)
        fig.tight_layout()
        return fig


def _standardiser(x: Tensor) -> tuple[Tensor, Tensor]:
    loc = x.mean(0)
    scale = x.std(0, unbiased=False)
    return loc, torch.where(scale > 1e-8, scale, torch.ones_like(scale))


def fit(
    model: WorldModel,
    data: Mapping[str, Any],
    *,
    variables: Sequence[str] | None = None,
    loss: str = "mse",
    epochs: int = 120,
    batch_size: int = 2048,
    lr: float = 0.01,
    val_fraction: float = 0.0,
    seed: int = 0,
    progress_bar: bool = False,
) -> FitResult:
    """Train the local mechanisms f_i (and sigma_i) of ``model`` in place.

    Args:
        model: the world model.
        data: name -> ``(N, dim)`` realised values; every trained variable needs its own
            column and its parents' columns.
        variables: mechanisms to train; default every non-root whose columns are present.
        loss: ``"mse"`` (thesis §5.2.1; sigma from residuals) or ``"nll"`` (Gaussian NLL).
        epochs: passes over the training rows (thesis: 120).
        batch_size: Adam minibatch rows (thesis: 2048).
        lr: Adam learning rate (thesis: 0.01).
        val_fraction: share of rows held out for validation curves, in [0, 1).
        seed: seeds the split and the minibatch order (local generator).
        progress_bar: show a tqdm bar over epochs.

    Returns:
        :class:`FitResult`. Non-action roots present in ``data`` also get their Normal
        prior set to the data mean and sd.

    Raises:
        ValueError: a model that is not a :class:`WorldModel`, bad data (see
            :func:`models.world.as_values`), fewer than 2 rows, unknown, root or repeated
            ``variables``, or a bad schedule argument (type or range).
        FloatingPointError: the training loss became NaN or inf.
    """
    model = require_world_model(model)
    loss = check_choice("loss", loss, LOSSES)
    epochs = check_int("epochs", epochs, minimum=1)
    batch_size = check_int("batch_size", batch_size, minimum=1)
    lr = check_float("lr", lr, minimum=0.0, min_open=True)
    val_fraction = check_float("val_fraction", val_fraction, minimum=0.0, maximum=1.0, max_open=True)
    seed = check_seed("seed", seed)
    progress_bar = check_bool("progress_bar", progress_bar)
    if variables is not None:
        variables = check_names("variables", variables, allow_empty=False)
    graph = model.graph
    cols, n = as_values(graph, data, dtype=model.dtype)
    if n is None:
        raise ValueError("data is empty; fit needs name -> (N, dim) columns")
    if n < 2:
        raise ValueError(f"fit needs at least 2 rows of data, got {n}")
    trainable = [v for v in graph.non_roots if v in cols and all(p in cols for p in graph.parents(v))]
    if variables is None:
        targets = trainable
        if not targets:
            raise ValueError(f"no mechanism can be trained from columns {sorted(cols)}")
    else:
        targets = variables
        for v in targets:
            graph.check_name(v, what="variable to fit")
            if graph.is_root(v):
                raise ValueError(f"{v!r} is a root and has no mechanism to fit")
            missing = [c for c in (v, *graph.parents(v)) if c not in cols]
            if missing:
                raise ValueError(f"cannot fit {v!r}: data has no column for {missing}")
    skipped = [v for v in graph.non_roots if v not in targets]
    if skipped:
        log.debug("fit: not training %s (not requested or columns missing)", skipped)

    gen = torch.Generator().manual_seed(seed)
    perm = torch.randperm(n, generator=gen)
    n_val = round(val_fraction * n)
    train_idx, val_idx = perm[n_val:], perm[:n_val]
    if len(train_idx) < 1:
        raise ValueError("val_fraction leaves no training rows")

    for r in graph.roots:
        if r in cols and graph[r].role is not Role.ACTION:
            loc, scale = _standardiser(cols[r][train_idx])
            model.set_root_prior(r, loc, scale)

    inputs, outputs = {}, {}
    for v in targets:
        parents = graph.parents(v)
        inputs[v] = torch.cat([cols[p] for p in parents], -1)
        outputs[v] = cols[v]
        mech = model.mechanism(v)
        in_loc, in_scale = _standardiser(inputs[v][train_idx])
        out_loc, out_scale = _standardiser(outputs[v][train_idx])
        mech.set_normalization(in_loc, in_scale, out_loc, out_scale)

    params = []
    for v in targets:
        mech = model.mechanism(v)
        params += [p for name, p in mech.named_parameters() if loss == "nll" or name != "log_sigma"]
    optim = torch.optim.Adam(params, lr=lr)
    train_curves: dict[str, list[float]] = {v: [] for v in targets}
    val_curves: dict[str, list[float]] = {v: [] for v in targets}
    n_train = len(train_idx)
    start = time.perf_counter()
    model.train()
    bar = tqdm(range(epochs), desc="fit", disable=not progress_bar, leave=False)
    for _ in bar:
        order = train_idx[torch.randperm(n_train, generator=gen)]
        sums = dict.fromkeys(targets, 0.0)
        for b in range(0, n_train, batch_size):
            idx = order[b : b + batch_size]
            optim.zero_grad()
            total = 0.0
            for v in targets:
                mech = model.mechanism(v)
                pred = mech(inputs[v][idx])
                resid = outputs[v][idx] - pred
                z = resid / mech.out_scale
                if loss == "mse":
                    total = total + (z**2).mean()
                else:
                    s = mech.sigma / mech.out_scale
                    total = total + (0.5 * (z / s) ** 2 + torch.log(s)).mean()
                sums[v] += float((resid.detach() ** 2).mean(-1).sum())
            total.backward()
            optim.step()
        for v in targets:
            train_curves[v].append(sums[v] / n_train)
        if n_val:
            with torch.no_grad():
                for v in targets:
                    resid = outputs[v][val_idx] - model.mechanism(v)(inputs[v][val_idx])
                    val_curves[v].append(float((resid**2).mean()))
        worst = max(train_curves[v][-1] for v in targets)
        if not math.isfinite(worst):
            raise FloatingPointError(f"training diverged (loss {worst}); lower lr")
        bar.set_postfix(mse=f"{worst:.4g}")
    model.eval()
    if loss == "mse":
        with torch.no_grad():
            for v in targets:
                mech = model.mechanism(v)
                resid = outputs[v][train_idx] - mech(inputs[v][train_idx])
                mech.set_sigma(resid.pow(2).mean(0).sqrt().clamp_min(1e-6))
    seconds = time.perf_counter() - start
    sigma = {v: tuple(float(s) for s in model.mechanism(v).sigma.detach()) for v in targets}
    model.provenance = {
        **model.provenance,
        "fit": {
            "loss": loss,
            "epochs": epochs,
            "batch_size": batch_size,
            "lr": lr,
            "seed": seed,
            "val_fraction": val_fraction,
            "n": n,
            "trained": list(targets),
        },
    }
    return FitResult(
        {v: tuple(c) for v, c in train_curves.items()},
        {v: tuple(c) for v, c in val_curves.items()},
        sigma,
        tuple(targets),
        loss,
        epochs,
        n_train,
        n_val,
        seconds,
    )
