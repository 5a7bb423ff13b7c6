"""The loss of candidate action sequences under the world model (Eq. 4.45-4.49).

Candidates come as one tensor ``a: (R, N, H, D)``: R candidates for each of N units, H
steps, D the optimised actions' dims concatenated. The forward query Phi is
:meth:`models.WorldModel.predict` (H = 1) or :meth:`models.WorldModel.rollout` (H > 1,
Alg. 4.1) on ``R x N`` rows, with the state given, the other roots at their expected values
(prior mean; action midpoint) and residuals replayed (expected, or the given ones). These
are the torch twins of ``Intervene(do(actions = a))`` + ``ReplayNoise`` on the program.
The world model's parameters are not touched here; :func:`inference.infer_action` freezes them.

Per candidate and unit, with log p the log-preference (Eq. 4.45) taken on the final step
(``target_at="final"``) or summed over the H steps (``"every"``):

    risk None:                 L(a) = -log p(Phi(s, a, u))
    risk "mean":               L(a) = (1 / K) sum_k -log p(Phi^(k)(s, a, u))
    risk ("disagreement", w):  L(a) = -log p(mean_k Phi^(k)) + w sum_i sum_d Var_k[Phi^(k)_id] / scale_i^2
    risk ("quantile", q):      L(a) = Q_q over k of -log p(Phi^(k)(s, a, u))   (q > 0.5: risk averse)

Phi^(k) is ensemble member k (``predict(..., members=True)``): the particles propagate TS-style,
each particle keeping one member over the whole horizon (member k's state feeds member k's next
step; with expected residuals one particle per member is exact, more would repeat it). Q_q is
the q-quantile over the K particles with linear interpolation (``torch.quantile``: q = 0 the
best member, 1 the worst, 0.5 the median). Var_k the population variance
over members of the target sites i at the scored steps. w > 0 penalises disagreement (risk
averse), w < 0 rewards it (exploration). For the Gaussian preference, "mean" equals
("disagreement", 0.5): the expected squared error is the squared error of the mean plus
the variance.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from models.checks import as_float_tensor, check_finite_tensor, check_float, check_mapping, describe
from models.variables import Role
from models.world import WorldModel

__all__ = [
    "TARGET_AT",
    "ActionObjective",
    "LogPreference",
    "Risk",
    "check_risk",
    "gaussian_log_preference",
    "scales",
]

TARGET_AT = ("final", "every")

Risk = str | tuple[str, float] | None
LogPreference = Callable[[Mapping[str, Tensor]], Tensor]


def scales(scale: float | Mapping[str, float], names: Sequence[str]) -> dict[str, float]:
    """One finite scale > 0 per target name (a scalar applies to all)."""
    if isinstance(scale, Mapping):
        unknown = sorted(str(k) for k in scale if k not in names)
        missing = [k for k in names if k not in scale]
        if unknown or missing:
            raise ValueError(
                f"scale must give one value per target; unknown names {unknown}, missing {missing}"
            )
        return {k: check_float(f"scale[{k!r}]", scale[k], minimum=0.0, min_open=True) for k in names}
    s = check_float("scale", scale, minimum=0.0, min_open=True)
    return dict.fromkeys(names, s)


def gaussian_log_preference(
    targets: Mapping[str, Tensor], scale: float | Mapping[str, float] = 1.0
) -> LogPreference:
    """Gaussian log-preference around the targets (Eq. 4.45).

    Per unit, ``log p(x_tar | C) = sum_i -0.5 ((x_i - target_i) / scale_i)^2``. Up to
    constants this is ``sum_i log N(x_i; target_i, scale_i^2)``; with a common scale it is
    ``-SSE / (2 scale^2)``.

    Args:
        targets: name -> ``(N, dim)`` finite target values.
        scale: finite scale > 0 in the targets' units, one for all or name -> scale.

    Returns:
        A callable ``predicted -> (N,)``.
    """
    targets = check_mapping("targets", targets)
    if not targets:
        raise ValueError("targets is empty; give name -> (N, dim) target values")
    tgt = {}
    for name, value in targets.items():
        if not isinstance(name, str):
            raise ValueError(f"target names must be str, got {describe(name)}")
        tgt[name] = check_finite_tensor(f"targets[{name!r}]", as_float_tensor(value, f"targets[{name!r}]"))
    per_name = scales(scale, list(tgt))

    def log_pref(pred: Mapping[str, Tensor]) -> Tensor:
        missing = [k for k in tgt if k not in pred]
        if missing:
            raise ValueError(f"predicted values have no {missing}; the targets name them")
        total = 0.0
        for name, target in tgt.items():
            total = total - (0.5 * ((pred[name] - target) / per_name[name]) ** 2).sum(-1)
        return total

    return log_pref


def check_risk(risk: Any) -> tuple[str | None, float]:
    """``(kind, weight)`` from ``None``, ``"mean"``, ``("disagreement", weight)`` or ``("quantile", q)``.

    Raises:
        ValueError: anything else, a weight that is not a finite number, or a quantile
            level q outside [0, 1].
    """
    expected = "None, 'mean', ('disagreement', weight) or ('quantile', q) with q in [0, 1]"
    if risk is None:
        return None, 0.0
    if isinstance(risk, str):
        if risk == "mean":
            return "mean", 0.0
        raise ValueError(f"risk {risk!r} unknown; expected {expected}")
    if isinstance(risk, tuple) and len(risk) == 2 and risk[0] == "disagreement":
        return "disagreement", check_float("disagreement weight", risk[1])
    if isinstance(risk, tuple) and len(risk) == 2 and risk[0] == "quantile":
        return "quantile", check_float("risk quantile q", risk[1], minimum=0.0, maximum=1.0)
    raise ValueError(f"risk must be {expected}, got {describe(risk)}")


def _tile(value: Tensor, r: int) -> Tensor:
    """``(N, ...) -> (r * N, ...)``, candidate-major (row ``c * N + n``)."""
    return value.unsqueeze(0).expand(r, *value.shape).reshape(r * value.shape[0], *value.shape[1:])


class ActionObjective:
    """``a (R, N, H, D) -> L (R, N)`` for one batch of units (see the module docstring).

    Args:
        model: the world model.
        given: name -> ``(N, dim)`` state values and fixed actions (H = 1: also observed
            non-roots, which keep their values; H > 1: roots only, lag-0 ones held on every step).
        actions: the optimised action names, in the order of the D axis.
        noise: name -> ``(N, dim)`` or ``(N, H, dim)`` standardised residuals of non-roots;
            the others are expected (zero).
        log_preference: ``values -> log p`` broadcasting over leading axes: values
            ``(..., N, dim)`` give ``(..., N)``, as :func:`inference.gaussian_log_preference` does.
        n: number of units N.
        horizon: steps H >= 1.
        target_at: ``"final"`` or ``"every"``.
        risk: ``(kind, weight)`` from :func:`check_risk`.
        scales: target name -> preference scale; the sites whose member spread counts.
    """

    def __init__(
        self,
        model: WorldModel,
        given: Mapping[str, Tensor],
        actions: Sequence[str],
        noise: Mapping[str, Tensor],
        log_preference: LogPreference,
        n: int,
        horizon: int,
        target_at: str,
        risk: tuple[str | None, float],
        scales: Mapping[str, float],
    ) -> None:
        self.model, self.n, self.horizon, self.target_at = model, n, horizon, target_at
        self.actions = list(actions)
        self.log_preference = log_preference
        self.risk, self.weight = risk
        self.scales = dict(scales)
        graph = model.graph
        self.dims = [graph[a].dim for a in self.actions]
        fixed = dict(given)
        for root in graph.roots:
            if root in fixed or root in self.actions:
                continue
            if graph[root].role is Role.ACTION:
                low, high = model.bounds(root)
                fixed[root] = ((low + high) / 2).expand(n, graph[root].dim)
            else:
                fixed[root] = model.root_priors.get(root)[0].expand(n, graph[root].dim)
        self.fixed = fixed
        if noise:
            predicted = [v for v in graph.non_roots if v not in fixed]
            # the sites not replayed take residual 0: a continuous site its loc, a discrete one its
            # mode (K zero Gumbels), so a gated site follows its switch's mode, not the mixture
            self.noise: dict[str, Tensor] | None = {
                v: noise[v]
                if v in noise
                else torch.zeros(n, model.categories(v) or graph[v].dim, dtype=model.dtype)
                for v in predicted
            }
        else:
            self.noise = None
        self._cache: dict[int, tuple[dict[str, Tensor], dict[str, Tensor] | str]] = {}

    def _inputs(self, r: int) -> tuple[dict[str, Tensor], dict[str, Tensor] | str]:
        """The given values and residuals tiled to ``r * N`` rows (cached per r)."""
        if r not in self._cache:
            graph, h = self.model.graph, self.horizon
            fixed = {k: _tile(v, r) for k, v in self.fixed.items()}
            if h > 1:
                fixed = {
                    k: v if graph[k].lag == 1 else v.unsqueeze(1).expand(v.shape[0], h, v.shape[-1])
                    for k, v in fixed.items()
                }
            noise = "expected" if self.noise is None else {k: _tile(v, r) for k, v in self.noise.items()}
            self._cache[r] = (fixed, noise)
        return self._cache[r]

    def predict(self, a: Tensor, members: bool = False) -> dict[str, Tensor]:
        """Phi for every site: name -> ``(R, N, dim)`` (H = 1) or ``(R, N, H, dim)``.

        With ``members`` each value has a leading member axis K. Keeps the autograd graph
        when grad mode is on.
        """
        r = a.shape[0]
        fixed, noise = self._inputs(r)
        rows = r * self.n
        split = torch.split(a, self.dims, dim=-1)
        grad = torch.is_grad_enabled()
        extra: dict[str, Any] = {"members": True} if members else {}
        if self.horizon == 1:
            values = {
                **fixed,
                **{
                    k: v[:, :, 0].reshape(rows, v.shape[-1]) for k, v in zip(self.actions, split, strict=True)
                },
            }
            out = self.model.predict(values, noise=noise, grad=grad, **extra)
        else:
            graph = self.model.graph
            initial = {k: v for k, v in fixed.items() if graph[k].lag == 1}
            inputs = {k: v for k, v in fixed.items() if graph[k].lag != 1}
            inputs |= {
                k: v.reshape(rows, self.horizon, v.shape[-1])
                for k, v in zip(self.actions, split, strict=True)
            }
            out = self.model.rollout(initial, inputs, noise=noise, grad=grad, **extra)
        lead = 1 if members else 0
        return {k: v.reshape(*v.shape[:lead], r, self.n, *v.shape[lead + 1 :]) for k, v in out.items()}

    def _log_p(self, values: Mapping[str, Tensor], lead: tuple[int, ...]) -> Tensor:
        """Log p at the scored steps, ``lead``-shaped (e.g. ``(R, N)``)."""
        if self.horizon == 1:
            steps = [values]
        elif self.target_at == "final":
            steps = [{k: v[..., -1, :] for k, v in values.items()}]
        else:
            steps = [{k: v[..., t, :] for k, v in values.items()} for t in range(self.horizon)]
        total: Tensor | float = 0.0
        for step in steps:
            out = self.log_preference(step)
            if not isinstance(out, Tensor) or tuple(out.shape) != lead:
                got = tuple(out.shape) if isinstance(out, Tensor) else describe(out)
                raise ValueError(
                    f"log_preference returned {got}, expected shape {lead}: it gets values with leading "
                    "candidate axes (..., N, dim) and must broadcast over them like gaussian_log_preference"
                )
            total = total + out
        return total  # type: ignore[return-value]

    def spread(self, values: Mapping[str, Tensor]) -> Tensor:
        """``sum_i sum_d Var_k[Phi^(k)_id] / scale_i^2`` at the scored steps: ``(R, N)``."""
        total: Tensor | float = 0.0
        for name, scale in self.scales.items():
            var = values[name].var(0, unbiased=False) / scale**2
            if self.horizon > 1:
                var = var[..., -1, :] if self.target_at == "final" else var.sum(-2)
            total = total + var.sum(-1)
        return total  # type: ignore[return-value]

    def __call__(self, a: Tensor) -> Tensor:
        """L(a): ``(R, N, H, D) -> (R, N)``."""
        lead = (a.shape[0], self.n)
        if self.risk is None:
            return -self._log_p(self.predict(a), lead)
        values = self.predict(a, members=True)
        k = next(iter(values.values())).shape[0]
        if self.risk == "mean":
            return -self._log_p(values, (k, *lead)).mean(0)
        if self.risk == "quantile":
            return torch.quantile(-self._log_p(values, (k, *lead)), self.weight, dim=0)
        mean = {name: v.mean(0) for name, v in values.items()}
        return -self._log_p(mean, lead) + self.weight * self.spread(values)
