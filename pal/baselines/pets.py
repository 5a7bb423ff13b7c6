"""A PETS-style baseline in plain torch: a probabilistic ensemble over the full observation, planned with CEM.

This is the reference the ``pusher`` experiment measures pal against (Chua et al. 2018), written
here from the paper's description so that it runs in the same process, on the same data budget
and with the same planner settings as the agent:

- **model**: K members, each an MLP (SiLU, ``hidden`` widths) from the standardised observation
  and action to the mean and log-variance of the next observation's change
  ``o(t+1) - o(t) ~ Normal(mu_k, exp(logvar_k))``, the log-variance softly bounded by learned
  limits; each member is trained on its own bootstrap of the transitions by the Gaussian NLL
  (Adam, weight decay), on standardised targets;
- **planner**: the agent's sampling stage, :func:`inference.planning.cross_entropy_search`
  (iCEM by default: coloured noise over the horizon, kept elites, population decay), over action
  sequences of ``horizon`` steps within the action box, with the same
  ``PlanConfig.action.sampling`` as the agent; each candidate is rolled forward by every member
  on its own mean trajectory (TS-style particles, one per member) and scored by the mean over
  members of the summed step cost; the best sequence's first action is executed and the
  sequence shifted by one step (:func:`inference.planning.shift_plan`) warm-starts the next
  step (MPC).

It is not the authors' code: no trajectory sampling of the outputs (each member propagates its
mean, as the agent's ``risk="mean"`` does), and no holdout-based early stopping.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from inference.planning import cross_entropy_search, shift_plan
from pal.agent.config import PlanConfig
from pal.agent.replan import Replanning
from pal.checks import check_float, check_int

__all__ = ["BaselineConfig", "CEMPlanner", "ProbabilisticEnsemble", "act_together"]

Cost = Callable[[Tensor, Tensor], Tensor]


@dataclass(frozen=True)
class BaselineConfig:
    """The PETS-style baseline's model and training.

    Attributes:
        members: ensemble size K.
        hidden: MLP widths.
        epochs, batch_size, lr, weight_decay: training (Adam).
    """

    members: int = 5
    hidden: tuple[int, ...] = (200, 200, 200)
    epochs: int = 60
    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-4

    def __post_init__(self) -> None:
        for name in ("members", "epochs", "batch_size"):
            check_int(name, getattr(self, name))
        object.__setattr__(self, "hidden", tuple(check_int("hidden", h) for h in self.hidden))
        check_float("lr", self.lr, 0.0, open_low=True)
        check_float("weight_decay", self.weight_decay, 0.0)


class _Layer(nn.Module):
    """K parallel affine maps: ``(K, N, i) -> (K, N, o)``."""

    def __init__(self, k: int, i: int, o: int, generator: torch.Generator) -> None:
        super().__init__()
        bound = 1.0 / math.sqrt(i)
        self.weight = nn.Parameter((torch.rand(k, i, o, generator=generator) * 2 - 1) * bound)
        self.bias = nn.Parameter(torch.zeros(k, 1, o))

    def forward(self, x: Tensor) -> Tensor:
        return torch.baddbmm(self.bias, x, self.weight)


class ProbabilisticEnsemble(nn.Module):
    """K Gaussian MLPs ``(o, a) -> o' - o`` (module docstring).

    Args:
        obs_dim: observation size D. act_dim: action size A.
        config: sizes and training.
        seed: initial weights, bootstraps and minibatches.
    """

    def __init__(self, obs_dim: int, act_dim: int, config: BaselineConfig, seed: int = 0) -> None:
        super().__init__()
        self.config, self.obs_dim = config, obs_dim
        self.generator = torch.Generator().manual_seed(seed)
        k, widths = config.members, [obs_dim + act_dim, *config.hidden]
        self.layers = nn.ModuleList(_Layer(k, i, o, self.generator) for i, o in itertools.pairwise(widths))
        self.head = _Layer(k, widths[-1], 2 * obs_dim, self.generator)
        self.max_logvar = nn.Parameter(torch.full((obs_dim,), 0.5))
        self.min_logvar = nn.Parameter(torch.full((obs_dim,), -10.0))
        for name in ("in_loc", "in_scale", "out_loc", "out_scale"):
            self.register_buffer(name, torch.zeros(0))

    def _raw(self, x: Tensor) -> tuple[Tensor, Tensor]:
        z = (x - self.in_loc) / self.in_scale
        for layer in self.layers:
            z = nn.functional.silu(layer(z))
        mean, logvar = self.head(z).chunk(2, -1)
        logvar = self.max_logvar - nn.functional.softplus(self.max_logvar - logvar)
        return mean, self.min_logvar + nn.functional.softplus(logvar - self.min_logvar)

    def forward(self, obs: Tensor, act: Tensor) -> Tensor:
        """Each member's mean next observation: ``(K, N, D)`` from ``(K, N, D)`` and ``(K, N, A)``."""
        mean, _ = self._raw(torch.cat([obs, act], -1))
        return obs + self.out_loc + self.out_scale * mean

    def fit(self, obs: np.ndarray, act: np.ndarray, nxt: np.ndarray) -> list[float]:
        """Train on transitions ``(N, D)``, ``(N, A)``, ``(N, D)``; returns the mean NLL per epoch."""
        x = torch.as_tensor(np.concatenate([obs, act], 1), dtype=torch.float32)
        y = torch.as_tensor(nxt - obs, dtype=torch.float32)
        self.in_loc, self.in_scale = x.mean(0), x.std(0).clamp_min(1e-6)
        self.out_loc, self.out_scale = y.mean(0), y.std(0).clamp_min(1e-6)
        yz = (y - self.out_loc) / self.out_scale
        c, n, k = self.config, x.shape[0], self.config.members
        boot = torch.randint(0, n, (k, n), generator=self.generator)
        optim = torch.optim.Adam(self.parameters(), lr=c.lr, weight_decay=c.weight_decay)
        history = []
        for _ in range(c.epochs):
            order = boot[:, torch.randperm(n, generator=self.generator)]
            total = 0.0
            for start in range(0, n, c.batch_size):
                idx = order[:, start : start + c.batch_size]
                mean, logvar = self._raw(x[idx])
                nll = (0.5 * (mean - yz[idx]).pow(2) * torch.exp(-logvar) + 0.5 * logvar).mean()
                loss = nll + 0.01 * (self.max_logvar.sum() - self.min_logvar.sum())
                optim.zero_grad()
                loss.backward()
                optim.step()
                total += float(nll.detach()) * idx.shape[1]
            history.append(total / n)
        return history


class CEMPlanner:
    """iCEM / CEM over action sequences through the ensemble, replanned every k steps (module docstring).

    Args:
        model: the fitted ensemble.
        low, high: (A,) action bounds.
        config: ``action.horizon``, ``action.sampling``, ``warm_start`` and ``replan_every`` = k
            (the agent's planner settings; the preference fields are the cost's business).
        cost: ``(obs (..., D), act (..., A)) -> (...)`` step cost.
        seed: the sampling's only source of randomness.
    """

    def __init__(
        self,
        model: ProbabilisticEnsemble,
        low: np.ndarray,
        high: np.ndarray,
        config: PlanConfig,
        cost: Cost,
        seed: int = 0,
    ) -> None:
        self.model, self.config, self.cost = model, config, cost
        self.low = torch.as_tensor(low, dtype=torch.float32)
        self.high = torch.as_tensor(high, dtype=torch.float32)
        self.generator = torch.Generator().manual_seed(seed)
        self._mean: Tensor | None = None
        self._final: np.ndarray | None = None  # the plan's predicted final observation
        self._replan = Replanning(config.replan_every)

    def reset(self) -> None:
        """Forget the warm start (a new episode)."""
        self._mean = None
        self._replan.reset()

    def costs(self, obs: Tensor, seqs: Tensor) -> tuple[Tensor, Tensor]:
        """Mean over members of the summed cost ``(P,)`` and the members' mean final observation ``(P, D)``.

        Args:
            obs: ``(1, D)`` the observation now, or ``(P, D)`` one per candidate.
            seqs: ``(P, H, A)`` candidate action sequences.
        """
        k = self.model.config.members
        p, h, _ = seqs.shape
        o = obs.expand(k, p, obs.shape[-1])
        total = torch.zeros(k, p)
        for t in range(h):
            a = seqs[:, t].expand(k, p, seqs.shape[-1])
            o = self.model(o, a)
            total = total + self.cost(o, a)
        return total.mean(0), o.mean(0)

    def act(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(first action (A,), predicted final observation of the plan (D,))`` from ``obs`` (D,)."""
        return act_together([self], np.asarray(obs)[None])[0]

    def _held(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The current plan's next action and final observation while no new plan is due, else None."""
        if self._mean is None or self._final is None or self._replan.due(self.config.action.horizon):
            return None
        return self._mean[self._replan.take()].numpy().astype(np.float64), self._final.copy()


def act_together(planners: Sequence[CEMPlanner], obs: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """:meth:`CEMPlanner.act` for N planners over one ensemble, their searches in one batched call.

    A planner that holds a plan (``replan_every``) takes its next action; the others search
    together, each unit with its own warm start and elites, the batch's samples drawn from the
    first searching planner's generator (one planner: exactly its :meth:`CEMPlanner.act`).

    Args:
        planners: planners over the same ensemble with the same settings and cost.
        obs: ``(N, D)`` each planner's observation.

    Raises:
        ValueError: no planners, other ensembles or settings, or ``obs`` not ``(N, D)``.
    """
    if not planners:
        raise ValueError("act_together needs at least one planner, got none")
    first = planners[0]
    if any(
        p.model is not first.model or p.config != first.config or p.cost is not first.cost for p in planners
    ):
        raise ValueError("act_together needs planners over one ensemble with the same settings and cost")
    obs = np.asarray(obs, dtype=np.float64)
    if obs.ndim != 2 or obs.shape[0] != len(planners):
        raise ValueError(
            f"obs has shape {obs.shape}, expected ({len(planners)}, D): one observation per planner"
        )
    out: list[tuple[np.ndarray, np.ndarray] | None] = [p._held() for p in planners]
    due = [k for k, held in enumerate(out) if held is None]
    if due:
        for k, result in zip(due, _search([planners[k] for k in due], obs[due]), strict=True):
            out[k] = result
    return [r for r in out if r is not None]


def _search(planners: Sequence[CEMPlanner], obs: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """One batched iCEM search for the planners' observations ``(n, D)``; each planner adopts its plan."""
    first = planners[0]
    h, a_dim = first.config.action.horizon, first.low.shape[0]
    o = torch.as_tensor(obs, dtype=torch.float32)
    mid = ((first.low + first.high) / 2).expand(h, a_dim)
    start = torch.stack(
        [
            shift_plan(p._mean, steps=p._replan.shift())
            if p.config.warm_start and p._mean is not None
            else mid
            for p in planners
        ]
    ).clone()

    def objective(a: Tensor) -> Tensor:  # (R, n, H, A) -> (R, n)
        r, n = a.shape[:2]
        rows = o[None].expand(r, n, o.shape[-1]).reshape(r * n, o.shape[-1])
        return first.costs(rows, a.reshape(r * n, h, a_dim))[0].reshape(r, n)

    with torch.inference_mode():  # the search takes no gradient
        found = cross_entropy_search(
            objective, start, first.low, first.high, first.config.action.sampling, first.generator
        )
    best = found.elites[0].clone()
    with torch.no_grad():
        _, final = first.costs(o, best)
    results = []
    for k, p in enumerate(planners):
        p._mean, p._final = best[k], final[k].numpy().astype(np.float64)
        p._replan.planned()
        results.append((best[k, 0].numpy().astype(np.float64), p._final.copy()))
    return results
