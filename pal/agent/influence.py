"""Curiosity that seeks what the agent can change and does not yet know: gated ensemble disagreement.

For a candidate action sequence a_0 .. a_{H-1} from the belief s_0, every ensemble member rolls
the model forward on its own trajectory (Alg. 4.1, ``members=True``). Its score is

    score(a) = sum_t sum_o  g(I_o(s_t)) * D_o(s_t, a_t)

- **disagreement** ``D_o = sum_d Var_k[dpos^(k)_o,d] / scale^2``: the epistemic spread of the
  members' predicted displacement of object o at step t (in units of the preference scale);
- **causal action influence** (CAI, Seitzer et al. 2021) ``I_o(s) = I(dpos_o ; A | S = s)``, the
  conditional mutual information between the action and the object's next state given the
  state, estimated from the model through ``do(A = a_m)`` for M actions drawn uniformly from
  the action box: with ``p_m = Normal(mu_m, sd_m)`` the model's predictive distribution of
  ``dpos_o`` under a_m and ``x_m ~ p_m``,

      I_o(s) ~= (1/M) sum_m [ log p_m(x_m) - log (1/M) sum_m' p_m'(x_m) ]      (nats, >= 0);

- **gate** ``g(I) = min(1, I / influence_scale)``: disagreement counts only where the action can
  move the object, so members that disagree about an object the arm cannot reach (or about
  noise) do not attract the agent.

:func:`explore` searches the sequences with CEM (:func:`inference.planning.cross_entropy_search`)
and returns the best; :func:`influence` is the score's gate alone (it is reported by the
experiments as the agent's estimate of where it has control).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import torch
from torch import Tensor

from inference.planning import cross_entropy_search
from models import WorldModel
from pal.agent.config import CuriosityConfig

__all__ = ["explore", "influence"]


def _next_roots(model: WorldModel, values: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """The lag-1 roots of the next step from one step's values (``q_prev <- q`` ...)."""
    return {r: values[src] for r, src in model.graph.lagged.items() if model.graph.is_root(r)}


def influence(
    model: WorldModel,
    state: Mapping[str, Tensor],
    objects: tuple[str, ...],
    samples: int,
    generator: torch.Generator,
) -> dict[str, Tensor]:
    """CAI score ``I_o(s)`` per state row (module docstring), nats.

    Args:
        model: the world model.
        state: lag-1 root name -> ``(R, dim)`` states.
        objects: the objects to score.
        samples: M actions per state.
        generator: source of the actions and of the draws x_m.

    Returns:
        object -> ``(R,)`` scores >= 0.
    """
    low, high = model.bounds("act")
    r = next(iter(state.values())).shape[0]
    m = samples
    acts = low + (high - low) * torch.rand(r, m, low.shape[0], generator=generator, dtype=model.dtype)
    tiled = {k: v[:, None].expand(r, m, v.shape[-1]).reshape(r * m, -1) for k, v in state.items()}
    tiled["act"] = acts.reshape(r * m, -1)
    with torch.no_grad():
        mean = model.predict(tiled)
        sd = model.predict_scale(tiled)
    out = {}
    for o in objects:
        mu = mean[f"dpos.{o}"].reshape(r, m, -1)
        s = sd[f"dpos.{o}"].reshape(r, m, -1).clamp_min(1e-6)
        x = mu + s * torch.randn(mu.shape, generator=generator, dtype=mu.dtype)
        # log p_m'(x_m) for all pairs: (R, M, M')
        z = (x[:, :, None] - mu[:, None]) / s[:, None]
        logp = (-0.5 * z.pow(2) - s[:, None].log() - 0.5 * math.log(2 * math.pi)).sum(-1)
        own = torch.diagonal(logp, dim1=1, dim2=2)
        mix = torch.logsumexp(logp, dim=2) - math.log(m)
        out[o] = (own - mix).mean(1).clamp_min(0.0)
    return out


def explore(
    model: WorldModel,
    belief: Mapping[str, np.ndarray],
    objects: tuple[str, ...],
    config: CuriosityConfig,
    scale: float,
    generator: torch.Generator,
) -> tuple[np.ndarray, float, dict[str, float]]:
    """The action sequence of highest gated disagreement from ``belief`` (module docstring).

    Args:
        model: the world model (an ensemble; with K = 1 every score is 0).
        belief: lag-1 root name -> (dim,) current state.
        objects: the objects whose variables are explored.
        config: the search sizes and the gate.
        scale: the disagreement's unit, m.
        generator: the search's only source of randomness.

    Returns:
        ``(sequence (H, A), score, influence at the belief per object, nats)``.
    """
    dtype = model.dtype
    h = config.horizon
    low, high = model.bounds("act")
    start = ((low + high) / 2).expand(1, h, low.shape[0]).clone()
    init = {k: torch.as_tensor(np.asarray(v, dtype=np.float64)[None], dtype=dtype) for k, v in belief.items()}

    def objective(a: Tensor) -> Tensor:  # (R, 1, H, A) -> (R, 1) loss = -score
        r = a.shape[0]
        state = {k: v.expand(r, v.shape[-1]) for k, v in init.items()}
        score = torch.zeros(r, dtype=dtype)
        for t in range(h):
            gate = influence(model, state, objects, config.influence_samples, generator)
            values = {**state, "act": a[:, 0, t]}
            members = model.predict(values, members=True)
            for o in objects:
                spread = members[f"dpos.{o}"].var(0, unbiased=False).sum(-1) / scale**2
                score = score + (gate[o] / config.influence_scale).clamp(max=1.0) * spread
            state = _next_roots(model, {k: v.mean(0) for k, v in members.items()})
        return -score[:, None]

    with torch.no_grad():
        found = cross_entropy_search(objective, start, low, high, config.sampling, generator)
        now = influence(model, {k: v for k, v in init.items()}, objects, config.influence_samples, generator)
    best = found.elites[0, 0].numpy().astype(np.float64)
    return best, float(-found.losses[0, 0]), {o: float(v[0]) for o, v in now.items()}
