"""The sampling stage of action inference: iCEM (the default) or plain CEM over the action box.

For every unit n at once (one tensor program for all units x candidates), with the action
sequence a in R^{H x D} (H steps, D the optimised actions' dims concatenated) and the box
``[low, high]^D`` (iCEM: Pinneri et al. 2020, "Sample-efficient cross-entropy method for
real-time planning"):

    mu_0 = a_start (the thesis midpoint, or the previous plan shifted by one step),
    sigma_0 = init_std * (high - low)
    for i = 0 .. I-1:
        P_i   = max(ceil(P * gamma^-i), min(2 E, P))                      (population decay)
        a^(p) = clip(mu + sigma * eps^(p), low, high),  p = 1 .. P_i,   a^(1) = clip(mu)
        eps^(p) ~ coloured Gaussian noise over the horizon, PSD ~ 1 / f^beta   (beta = 0: white)
        E_i   = the E candidates of lowest L(a) among these and the kept ones K_{i-1}
        K_i   = the best ceil(xi E) of E_i                                   (kept elites)
        mu    <- alpha mu    + (1 - alpha) mean(E_i)
        sigma <- alpha sigma + (1 - alpha) sd(E_i)

with beta = ``noise_beta``, xi = ``keep_elites`` and gamma = ``population_decay``. Plain CEM
is ``noise_beta=0, keep_elites=0, population_decay=1``. The current mean is a member of
every population, so the first population contains the start; the result is the E best
candidates seen over all iterations, so the best loss never rises. :func:`plan` then refines
the best elites with projected Adam (Alg. 4.2, CEM-GD) when ``refine_steps`` > 0 and keeps per
unit the best candidate. In model-predictive control the previous plan, shifted by one step
(:func:`shift_plan`), is the next start. Randomness comes only from the generator passed in.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor
from tqdm import tqdm

from models.checks import check_float, check_int

__all__ = [
    "SamplingConfig",
    "SearchResult",
    "colored_noise",
    "cross_entropy_search",
    "plan",
    "projected_adam",
    "shift_plan",
]

Objective = Callable[[Tensor], Tensor]


@dataclass(frozen=True)
class SamplingConfig:
    """Sizes of the sampling stage (iCEM by default, plain CEM as an option) and of the refinement after it.

    Attributes:
        population: new candidates P per unit in the first iteration (the current mean among them).
        elites: candidates E per unit that refit the sampling distribution; <= population.
        iterations: iterations I, >= 1.
        alpha: momentum in [0, 1): weight of the previous mean and sd in the refit.
        noise_beta: coloured-noise exponent beta >= 0 over the horizon (0: white noise, plain
            CEM; 2, the default: Brownian-like, smooth action sequences, as iCEM uses).
        keep_elites: fraction xi in [0, 1] of the elites carried into the next iteration's
            population (iCEM: 0.3; plain CEM: 0).
        population_decay: gamma >= 1; iteration i samples ``max(ceil(P gamma^-i), min(2E, P))``
            new candidates (iCEM: 1.25; plain CEM: 1).
        init_std: initial sd sigma_0 as a fraction of the box width (high - low), > 0.
        refine_steps: projected Adam steps on the refined elites (Alg. 4.2); None uses
            ``infer_action``'s ``steps``; 0 skips the refinement.
        refine_elites: how many of the best elites per unit Adam refines, 1 .. elites.

    Raises:
        ValueError: a field of the wrong type or out of range, or population < elites or
            refine_elites > elites.
    """

    population: int = 128
    elites: int = 16
    iterations: int = 3
    alpha: float = 0.1
    noise_beta: float = 2.0
    keep_elites: float = 0.3
    population_decay: float = 1.25
    init_std: float = 0.5
    refine_steps: int | None = None
    refine_elites: int = 1

    def __post_init__(self) -> None:
        check_int("population", self.population)
        check_int("elites", self.elites)
        if self.population < self.elites:
            raise ValueError(
                f"population {self.population} is smaller than elites {self.elites}; "
                "give population >= elites"
            )
        check_int("iterations", self.iterations)
        check_float("alpha", self.alpha, minimum=0.0, maximum=1.0, max_open=True)
        check_float("noise_beta", self.noise_beta, minimum=0.0)
        check_float("keep_elites", self.keep_elites, minimum=0.0, maximum=1.0)
        check_float("population_decay", self.population_decay, minimum=1.0)
        check_float("init_std", self.init_std, minimum=0.0, min_open=True)
        if self.refine_steps is not None:
            check_int("refine_steps", self.refine_steps, minimum=0)
        check_int("refine_elites", self.refine_elites)
        if self.refine_elites > self.elites:
            raise ValueError(
                f"refine_elites {self.refine_elites} is larger than elites {self.elites}; "
                "Adam refines some of the elites"
            )

    @property
    def kept(self) -> int:
        """Elites carried into the next iteration, ``ceil(keep_elites * elites)``."""
        return math.ceil(self.keep_elites * self.elites - 1e-9)

    def sizes(self) -> tuple[int, ...]:
        """New candidates per iteration, ``P_i = max(ceil(P gamma^-i), min(2E, P))``, length I."""
        floor = min(2 * self.elites, self.population)
        return tuple(
            max(math.ceil(self.population * self.population_decay**-i - 1e-9), floor)
            for i in range(self.iterations)
        )


@dataclass(frozen=True)
class SearchResult:
    """Outcome of :func:`cross_entropy_search`.

    Attributes:
        elites: ``(E, N, H, D)`` the E best candidates seen over all iterations per unit, best first,
            within the box.
        losses: ``(E, N)`` their losses L(a).
        history: mean over units of the best loss after each iteration, length I.
    """

    elites: Tensor
    losses: Tensor
    history: tuple[float, ...]


def colored_noise(
    shape: tuple[int, ...], beta: float, generator: torch.Generator, dtype: torch.dtype
) -> Tensor:
    """Gaussian noise of unit variance whose power spectrum along the last axis is ~ 1 / f^beta.

    The iCEM sampler (Pinneri et al. 2020): frequencies f = 0, 1/H, .., 1/2 get Gaussian
    amplitudes of sd ``max(f, 1/H)^(-beta / 2)`` (Timmer & Koenig 1995), the inverse real
    FFT gives the sequence, and it is divided by its exact sd, so every step has unit
    variance. ``beta = 0`` or a last axis of length 1 draws white noise ``torch.randn``.

    Args:
        shape: output shape; the last axis is the horizon H.
        beta: exponent >= 0.
        generator: the only source of randomness.
        dtype: floating dtype of the result.

    Returns:
        ``shape`` tensor of ``dtype``.
    """
    h = shape[-1]
    if beta == 0 or h == 1:
        return torch.randn(shape, generator=generator, dtype=dtype)
    freqs = torch.fft.rfftfreq(h, dtype=torch.float64)
    freqs[0] = 1.0 / h
    amp = freqs ** (-beta / 2)
    # Var y_t = (2 a_0^2 + 4 sum_{0<k<h/2} a_k^2 + 2 a_{h/2}^2 [h even]) / h^2, the same for every t
    power = 4 * amp**2
    power[0] /= 2
    if h % 2 == 0:
        power[-1] /= 2
    sd = math.sqrt(float(power.sum())) / h
    lead = (*shape[:-1], freqs.shape[0])
    real = torch.randn(lead, generator=generator, dtype=torch.float64) * amp
    imag = torch.randn(lead, generator=generator, dtype=torch.float64) * amp
    imag[..., 0] = 0.0
    real[..., 0] *= math.sqrt(2)
    if h % 2 == 0:
        imag[..., -1] = 0.0
        real[..., -1] *= math.sqrt(2)
    return (torch.fft.irfft(torch.complex(real, imag), n=h) / sd).to(dtype)


def _select(candidates: Tensor, losses: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """The k candidates of lowest loss per unit, best first: ``(k, N, H, D)``, ``(k, N)``."""
    best, idx = torch.topk(losses, k, dim=0, largest=False, sorted=True)
    index = idx[:, :, None, None].expand(k, *candidates.shape[1:])
    return candidates.gather(0, index), best


def cross_entropy_search(
    objective: Objective,
    start: Tensor,
    low: Tensor,
    high: Tensor,
    config: SamplingConfig,
    generator: torch.Generator,
) -> SearchResult:
    """ICEM / CEM over the action box for every unit at once (see the module docstring).

    Args:
        objective: ``a (R, N, H, D) -> L (R, N)`` losses per candidate and unit (called
            under ``torch.no_grad`` once per iteration with R = ``config.sizes()[i]``; the kept
            elites keep their losses); NaN losses rank last.
        start: ``(N, H, D)`` initial mean mu_0 within the box (the thesis midpoint start,
            or a shifted previous plan).
        low: ``(D,)`` lower box bounds.
        high: ``(D,)`` upper box bounds.
        config: population and its decay, elites and the kept share, iterations, momentum
            alpha, noise exponent, init sd.
        generator: the only source of randomness.

    Returns:
        :class:`SearchResult`: the ``E`` best candidates seen over all iterations, best first.
    """
    n, horizon, d = start.shape
    e, keep = config.elites, config.kept
    mean = start.clone()
    std = (config.init_std * (high - low)).expand(n, horizon, d).clone()
    kept = start.new_empty((0, n, horizon, d))
    kept_losses = start.new_empty((0, n))
    best = start.new_empty((0, n, horizon, d))
    best_losses = start.new_empty((0, n))
    history: list[float] = []
    with torch.no_grad():
        for p in config.sizes():
            eps = colored_noise((p, n, d, horizon), config.noise_beta, generator, start.dtype)
            cand = mean + std * eps.transpose(-1, -2)
            cand[0] = mean
            cand = torch.clamp(cand, low, high)
            fresh = torch.nan_to_num(objective(cand), nan=math.inf)
            elites, elite_losses = _select(torch.cat([cand, kept]), torch.cat([fresh, kept_losses]), e)
            kept, kept_losses = elites[:keep], elite_losses[:keep]
            best, best_losses = _select(torch.cat([best, cand]), torch.cat([best_losses, fresh]), e)
            mean = config.alpha * mean + (1 - config.alpha) * elites.mean(0)
            std = config.alpha * std + (1 - config.alpha) * elites.std(0, unbiased=False)
            history.append(float(best_losses[0].mean()))
    return SearchResult(best, best_losses, tuple(history))


def shift_plan(sequence: Tensor, fill: Tensor | None = None, steps: int = 1) -> Tensor:
    """The previous plan shifted by ``steps`` (k) steps: the warm start of the next MPC step.

        a'_t = a_{t+k}  (t < H - k),    a'_t = fill  (t >= H - k; default: a_{H-1}, the last step repeated)

    Args:
        sequence: ``(..., H, D)`` the plan made k steps before.
        fill: optional ``(D,)`` value of the new last steps (e.g. the box midpoint).
        steps: k >= 1, the plan's actions executed since it was made (k >= H: all ``fill``).

    Returns:
        ``(..., H, D)``; a horizon of 1 gives ``fill`` or the sequence itself.

    Raises:
        ValueError: a sequence with fewer than 2 dims, a ``fill`` of the wrong shape, steps < 1.
    """
    steps = check_int("steps", steps, minimum=1)
    if not isinstance(sequence, Tensor) or sequence.ndim < 2:
        got = tuple(sequence.shape) if isinstance(sequence, Tensor) else type(sequence).__name__
        raise ValueError(f"sequence has shape {got}, expected (..., H, D)")
    last = sequence[..., -1:, :]
    if fill is not None:
        if not isinstance(fill, Tensor) or fill.shape != sequence.shape[-1:]:
            got = tuple(fill.shape) if isinstance(fill, Tensor) else type(fill).__name__
            raise ValueError(f"fill has shape {got}, expected ({sequence.shape[-1]},)")
        last = fill.to(sequence.dtype).expand_as(last)
    k = min(steps, sequence.shape[-2])
    return torch.cat([sequence[..., k:, :], last.expand(*last.shape[:-2], k, last.shape[-1])], dim=-2)


def projected_adam(
    objective: Objective,
    start: Tensor,
    low: Tensor,
    high: Tensor,
    steps: int,
    lr: float,
    progress_bar: bool,
) -> tuple[Tensor, tuple[float, ...]]:
    """Projected Adam on candidates through the objective (Alg. 4.2).

        a <- clip(a - eta * Adam(grad_a sum_{r,n} L(a)_{rn}), low, high)     ``steps`` times

    The loss is a sum, so every candidate follows its own Adam trajectory. A loss without
    a gradient (only discrete sites, an argmax, between the actions and the targets) stops
    the refinement: the start is returned.

    Args:
        objective: ``a (R, N, H, D) -> L (R, N)``, differentiable in ``a``.
        start: ``(R, N, H, D)`` start values within the box.
        low: ``(D,)`` lower box bounds.
        high: ``(D,)`` upper box bounds.
        steps: Adam steps K_act (0 returns the start).
        lr: Adam learning rate eta_act.
        progress_bar: show a tqdm bar.

    Returns:
        ``(a (R, N, H, D), mean loss over candidates and units before each step)``.
    """
    params = start.clone().requires_grad_(True)
    optim = torch.optim.Adam([params], lr=lr)
    rows = params.shape[0] * params.shape[1]
    history: list[float] = []
    for _ in tqdm(range(steps), desc="infer_action", disable=not progress_bar, leave=False):
        optim.zero_grad()
        loss = objective(params).sum()
        if not loss.requires_grad:  # e.g. only discrete sites (argmax) follow the actions
            break
        loss.backward()
        optim.step()
        with torch.no_grad():
            params.copy_(torch.clamp(params, low, high))
        history.append(float(loss.detach()) / rows)
    return params.detach(), tuple(history)


def plan(
    objective: Objective,
    start: Tensor,
    low: Tensor,
    high: Tensor,
    sampling: SamplingConfig | None,
    steps: int,
    lr: float,
    generator: torch.Generator,
    progress_bar: bool,
) -> tuple[Tensor, tuple[float, ...], tuple[float, ...], Tensor]:
    """The sampling stage (if any), then projected Adam on its best elites; the best per unit wins.

    Without ``sampling`` Adam runs from ``start``. With it, Adam refines the best
    ``sampling.refine_elites`` elites for ``sampling.refine_steps`` steps (default
    ``steps``), and each unit keeps the lowest loss among the refined elites and the
    unrefined best elite. With ``refine_steps == 0`` the search's best elite is returned with the
    loss it was ranked by (no further evaluation), and the search runs in ``torch.inference_mode``.

    Args:
        objective: ``a (R, N, H, D) -> L (R, N)``.
        start: ``(N, H, D)`` start within the box (the thesis midpoint by default).
        low: ``(D,)`` lower box bounds.
        high: ``(D,)`` upper box bounds.
        sampling: None or the sampling sizes.
        steps: Adam steps when ``sampling.refine_steps`` is None.
        lr: Adam learning rate.
        generator: the only source of randomness.
        progress_bar: show a tqdm bar over the Adam steps.

    Returns:
        ``(best (N, H, D), Adam loss curve, sampling loss curve, L(best) (N,))``.
    """
    if sampling is None:
        refined, history = projected_adam(objective, start[None], low, high, steps, lr, progress_bar)
        with torch.no_grad():
            final = objective(refined)[0]
        return refined[0], history, (), final
    refine_steps = steps if sampling.refine_steps is None else sampling.refine_steps
    if refine_steps == 0:  # nothing refined: the search's best elite, with the loss it was ranked by
        with torch.inference_mode():  # no gradient is ever taken: no autograd bookkeeping either
            found = cross_entropy_search(objective, start, low, high, sampling, generator)
        return found.elites[0].clone(), (), found.history, found.losses[0].clone()
    found = cross_entropy_search(objective, start, low, high, sampling, generator)
    refined, history = projected_adam(
        objective, found.elites[: sampling.refine_elites], low, high, refine_steps, lr, progress_bar
    )
    with torch.no_grad():
        losses = objective(refined)
    cands = torch.cat([refined, found.elites[:1]])
    losses = torch.nan_to_num(torch.cat([losses, found.losses[:1]]), nan=float("inf"))
    pick = losses.argmin(0)
    units = torch.arange(start.shape[0])
    return cands[pick, units], history, found.history, losses[pick, units]
