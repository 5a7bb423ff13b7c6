"""Multi-step refinement of the object layer: the objects' sites trained through their own rollouts.

A one-step fit (Eq. 4.33) trains ``contact.o`` and ``dpos.o`` on the recorded ``pos_prev.o``. The
planner, however, chains them: from step 2 on, member k reads its own predicted position, so a
small bias per push adds up over a horizon of 25 steps. This refinement continues the fit of
those two sites on windows of ``window`` consecutive recorded steps, with the arm's sites set to
their recorded values (``do(q, v, ee, ... = recorded)``: the body is known or fitted apart) and
the object chained as the planner chains it, the expected prediction of each member::

    p^k_0 = pos_prev_0,  u^k_0 = vel_prev_0
    d^k_t = pi^k_t f^k_on(rel_prev^k_t, rel^k_t, u^k_t) + (1 - pi^k_t) * 0      (gated dpos, Eq. of models.gated)
    p^k_{t+1} = p^k_t + d^k_t,  u^k_{t+1} = d^k_t,  rel^k_t from the recorded effector and p^k_t

    loss = mean over windows, steps t = 1..H and members k of ||p^k_t - pos_t||^2 / s^2

with ``s`` the RMS of the recorded one-step displacements of the training windows (so the loss is
unitless). Adam on the parameters of the two sites only, whole episodes held out for validation;
the parameters with the lowest validation loss are kept, and the one-step fit stays when no
epoch beats it. Only the locations learn from this loss; the fitted scales are not recalibrated.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from inference import FitSchedule
from models import WorldModel
from pal.agent.graph_frame import frame_columns
from pal.agent.history import History
from pal.checks import check_choice, check_int

__all__ = ["ROLLOUT_SCHEDULE", "RolloutFit", "object_windows", "refine_objects"]

log = logging.getLogger(__name__)

#: The previous-position field of each position source of :meth:`History.columns`.
_PREV = {"perceived": "meas_prev", "truth": "truth_prev"}


#: The refinement's optimiser: 30 epochs of Adam at 3e-4 on batches of 64 windows, a fifth of the
#: episodes held out.
ROLLOUT_SCHEDULE = FitSchedule(epochs=30, batch_size=64, lr=3e-4, validation=0.2)


@dataclass(frozen=True)
class RolloutFit:
    """Settings of :func:`refine_objects` (module docstring).

    Attributes:
        window: steps per window H (0: off, the one-step fit alone).
        stride: a window starts every ``stride`` steps of an episode.
        schedule: the optimiser; read are ``epochs``, ``batch_size`` (windows), ``lr``,
            ``validation`` (the share of the episodes whose windows are held out to pick the
            best epoch: whole episodes, since the windows of one episode overlap) and
            ``patience`` (stop after this many epochs without a better validation loss).
    """

    window: int = 0
    stride: int = 2
    schedule: FitSchedule = ROLLOUT_SCHEDULE

    def __post_init__(self) -> None:
        check_int("rollout.window", self.window, minimum=0)
        check_int("rollout.stride", self.stride)
        if not isinstance(self.schedule, FitSchedule):
            raise ValueError(f"rollout.schedule must be a FitSchedule, got {type(self.schedule).__name__}")


def object_windows(history: History, window: int, stride: int, source: str = "perceived") -> np.ndarray:
    """Row indices ``(W, window)`` of consecutive steps of one episode with every object known.

    Consecutive: the same ``episode`` and the previous row's position the next row's ``pos_prev``
    (a restart from a saved state is a new episode). A window starts at every ``stride``-th row
    of an episode.
    """
    check_int("window", window)
    check_int("stride", stride)
    check_choice("source", source, tuple(_PREV))
    n = len(history)
    if n < window:
        return np.zeros((0, window), dtype=np.int64)
    prev, now = history.array(_PREV[source]), history.array(_PREV[source].removesuffix("_prev"))
    ok = np.isfinite(prev).all((1, 2)) & np.isfinite(now).all((1, 2))
    if history.momentum:
        ok &= np.isfinite(history.array("vel_prev")).all((1, 2))
    episode = history.array("episode").reshape(n)
    new = np.ones(n, dtype=bool)  # row i starts an episode
    new[1:] = episode[1:] != episode[:-1]
    first = np.maximum.accumulate(np.where(new, np.arange(n), 0))
    link = ~new
    link[1:] &= np.all(np.abs(prev[1:] - now[:-1]) <= 1e-9, axis=(1, 2))
    # a window of rows s .. s + H - 1 needs every row known and every row after s linked
    ok_run = np.convolve(ok.astype(int), np.ones(window, dtype=int), "valid") == window
    link_run = (
        np.convolve(link[1:].astype(int), np.ones(window - 1, dtype=int), "valid") == window - 1
        if window > 1
        else ok_run
    )
    starts = np.flatnonzero(
        ok_run & link_run[: len(ok_run)] & ((np.arange(len(ok_run)) - first[: len(ok_run)]) % stride == 0)
    )
    return starts[:, None] + np.arange(window)


def _window_columns(
    model: WorldModel, history: History, windows: np.ndarray, contact: str, floor: float, source: str
) -> dict[str, np.ndarray]:
    """Every column of :meth:`History.columns` on the windows' rows (in ``model``'s frame), ``(W, H, dim)``."""
    w, h = windows.shape
    arm, objects = history.columns(source, windows.reshape(-1), contact=contact, floor=floor)
    cols = dict(arm)
    for o in objects.values():
        cols.update(frame_columns(model, o))
    return {k: v.reshape(w, h, v.shape[-1]) for k, v in cols.items()}


def _chained(model: WorldModel, cols: dict[str, torch.Tensor], objects: list[str]) -> dict[str, torch.Tensor]:
    """Member-wise expected rollouts ``(K, B, H, d)`` of each object's position, the rest assigned."""
    graph = model.graph
    lag1 = [r for r in graph.roots if graph[r].lag == 1]
    lag0 = [r for r in graph.roots if graph[r].lag == 0]
    simulated = {s for o in objects for s in graph.names if s.endswith(f".{o}")}
    assign = {k: v for k, v in cols.items() if k in graph and not graph.is_root(k) and k not in simulated}
    out = model.rollout(
        {r: cols[r][:, 0] for r in lag1},
        {r: cols[r] for r in lag0},
        grad=True,
        members=True,
        assign=assign,
    )
    return {o: out[f"pos.{o}"] for o in objects}


def _loss(model: WorldModel, cols: dict[str, torch.Tensor], objects: list[str], scale: float) -> torch.Tensor:
    pred = _chained(model, cols, objects)
    return sum(((pred[o] - cols[f"pos.{o}"]) / scale).pow(2).sum(-1).mean() for o in objects)  # type: ignore[return-value]


def _split(episode: np.ndarray, share: float, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """``(held-out, training)`` window indices: a ``share`` of the episodes (at least one) held out whole."""
    ids = np.unique(episode)
    if share == 0 or len(ids) < 2:
        return torch.zeros(0, dtype=torch.long), torch.arange(len(episode))
    order = ids[torch.randperm(len(ids), generator=gen).numpy()]
    held = np.isin(episode, order[: max(1, round(share * len(ids)))])
    return torch.as_tensor(np.flatnonzero(held)), torch.as_tensor(np.flatnonzero(~held))


def _descend(
    mechs: list[Any],
    train: Any,
    train_idx: torch.Tensor,
    validation: Any,
    config: RolloutFit,
    gen: torch.Generator,
) -> tuple[float, float, int]:
    """Adam on ``mechs`` for ``config.schedule.epochs``; keeps the parameters of the lowest validation loss.

    ``train(batch)`` and ``validation()`` return losses. Returns ``(first, best, best epoch)``.
    """
    params = [p for m in mechs for p in m.parameters() if p.requires_grad]
    sched = config.schedule
    opt = torch.optim.Adam(params, lr=sched.lr)

    def checked() -> float:
        with torch.no_grad():
            return float(validation())

    first = best = checked()
    best_state, best_epoch = [{k: v.clone() for k, v in m.state_dict().items()} for m in mechs], 0
    for epoch in range(1, sched.epochs + 1):
        if sched.patience is not None and epoch - best_epoch > sched.patience:
            break
        for b in torch.randperm(len(train_idx), generator=gen).split(sched.batch_size):
            opt.zero_grad()
            train(train_idx[b]).backward()
            opt.step()
        current = checked()
        if current < best:
            best, best_epoch = current, epoch
            best_state = [{k: v.clone() for k, v in m.state_dict().items()} for m in mechs]
    for m, state in zip(mechs, best_state, strict=True):
        m.load_state_dict(state)
    return first, best, best_epoch


def refine_objects(
    model: WorldModel,
    history: History,
    objects: list[str],
    config: RolloutFit,
    *,
    contact: str,
    floor: float,
    source: str = "perceived",
    rows: Any = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Refine the objects' ``contact.o`` and ``dpos.o`` through their rollouts (module docstring), in place.

    Args:
        model: the fitted world model; the two sites of each object change in place.
        history: the recorded steps.
        objects: the objects to refine.
        config: the windows and the optimiser.
        contact: the rule of the ``contact.o`` column (:func:`pal.agent.graph.contact_rule`).
        floor: the moved rule's noise floor, m.
        source: the positions trained on (:meth:`History.columns`).
        rows: only windows of these rows (indices, boolean mask or slice of the history; default all).
        seed: the split and the batches.

    Returns:
        ``{"windows": W, "loss": (one-step, best) validation losses, "rms_m": the same as the
        RMS position error over members, steps and windows, m, "epoch": best epoch (0: the
        one-step fit kept)}``; ``{"windows": 0}`` when off or without windows.
    """
    if config.window == 0:
        return {"windows": 0}
    windows = object_windows(history, config.window, config.stride, source)
    if rows is not None:
        keep = np.zeros(len(history), dtype=bool)
        keep[np.arange(len(history))[rows]] = True
        windows = windows[keep[windows].all(1)]
    sites = [
        s
        for o in objects
        for s in (f"contact.{o}", f"dpos.{o}")
        if s in model.graph and model.mechanism(s).trainable
    ]
    if len(windows) < 4 or not sites:
        return {"windows": len(windows)}
    gen = torch.Generator().manual_seed(seed)
    cols = {
        k: torch.as_tensor(v, dtype=model.dtype)
        for k, v in _window_columns(model, history, windows, contact, floor, source).items()
    }
    val_idx, train_idx = _split(
        history.array("episode").reshape(-1)[windows[:, 0]], config.schedule.validation, gen
    )
    scale = float(torch.cat([cols[f"dpos.{o}"][train_idx].reshape(-1) for o in objects]).pow(2).mean().sqrt())
    scale = max(scale, 1e-6)
    train = lambda batch: _loss(model, {k: v[batch] for k, v in cols.items()}, objects, scale)  # noqa: E731
    val = {k: v[val_idx if len(val_idx) else train_idx] for k, v in cols.items()}
    first, best, best_epoch = _descend(
        [model.mechanism(s) for s in sites],
        train,
        train_idx,
        lambda: _loss(model, val, objects, scale),
        config,
        gen,
    )
    log.info(
        "rollout refinement: %d windows, validation loss %.4g -> %.4g (epoch %d)",
        len(windows),
        first,
        best,
        best_epoch,
    )
    rms = (scale * first**0.5, scale * best**0.5)
    return {"windows": len(windows), "loss": (first, best), "rms_m": rms, "epoch": best_epoch}
