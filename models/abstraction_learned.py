"""Learned abstraction mechanisms h_k (Eq. 6.2): a temporal encoder and a motor primitive.

**Temporal encoder.** ``z = g(vec(x_S(t : t + Δt)))``, an MLP over the flattened window. It is
fitted supervised (:meth:`TemporalEncoder.fit`): to a label of each window (e.g. contact
happened) or to a state it should summarise (e.g. the window's end state, which makes z a
learned summary of where the movement went). The loss is the mean squared error.

**Motor primitive.** A trajectory of one variable over the window, ``x(s_j)`` for phases
``s_j = j / (W - 1)``, is represented by basis weights ``w`` (``(n_basis, d)``):

    x(s) ≈ Σ_b φ_b(s) w_b,    φ_b(s) = exp(-(s - c_b)^2 / (2 h^2)) (b < n_basis - 1),  φ_last = 1

with centres ``c_b`` evenly on [0, 1] and width ``h = 1 / n_basis``. Bottom-up, ``w`` is the
least-squares fit ``w = Φ^+ x`` (Φ ``(W, n_basis)``); top-down, :meth:`MotorPrimitive.generate`
maps weights to the trajectory ``Φ w``, which is exact for trajectories in the span of Φ.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from models.checks import as_float_tensor, check_float, check_int, check_seed

__all__ = ["MotorPrimitive", "TemporalEncoder"]


class TemporalEncoder(nn.Module):
    """An MLP over the flattened window of its support: ``{name: (B, W, d)} -> (B, dim)``.

    Args:
        support: names read, in order. dims: their dims. window: W. dim: the code's size.
        hidden: hidden widths. seed: initial weights (local generator).
    """

    def __init__(
        self,
        support: Sequence[str],
        dims: Sequence[int],
        window: int,
        dim: int,
        hidden: Sequence[int] = (16,),
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.support = tuple(support)
        if len(self.support) != len(dims):
            raise ValueError(f"support {self.support} and dims {tuple(dims)} differ in length")
        self.window = check_int("window", window)
        self.dim = check_int("dim", dim)
        width = self.window * sum(check_int("dims", d) for d in dims)
        gen = torch.Generator().manual_seed(check_seed("seed", seed))
        layers: list[nn.Module] = []
        for h in hidden:
            layers += [nn.Linear(width, check_int("hidden", h)), nn.Tanh()]
            width = h
        layers.append(nn.Linear(width, self.dim))
        self.net = nn.Sequential(*layers).double()
        with torch.no_grad():
            for p in self.net.parameters():
                p.copy_(0.3 * torch.randn(p.shape, generator=gen, dtype=p.dtype))

    def _flat(self, wins: Mapping[str, Tensor]) -> Tensor:
        parts = []
        for n in self.support:
            if n not in wins:
                raise ValueError(f"windows have no variable {n!r}; the encoder reads {self.support}")
            x = as_float_tensor(wins[n], f"window {n!r}", torch.float64)
            if x.ndim != 3 or x.shape[1] != self.window:
                raise ValueError(f"window {n!r} has shape {tuple(x.shape)}, expected (B, {self.window}, d)")
            parts.append(x.reshape(x.shape[0], -1))
        return torch.cat(parts, -1)

    def forward(self, wins: Mapping[str, Tensor]) -> Tensor:
        """The code z: ``(B, dim)``."""
        return self.net(self._flat(wins))

    def fit(
        self, wins: Mapping[str, Tensor], targets: Any, *, epochs: int = 200, lr: float = 0.01
    ) -> tuple[float, ...]:
        """Adam on the mean squared error to ``targets`` ``(B, dim)``; returns the loss per epoch (full batch)."""
        y = as_float_tensor(targets, "targets", torch.float64)
        x = self._flat(wins)
        if y.shape != (x.shape[0], self.dim):
            raise ValueError(f"targets have shape {tuple(y.shape)}, expected ({x.shape[0]}, {self.dim})")
        opt = torch.optim.Adam(self.net.parameters(), lr=check_float("lr", lr, minimum=0.0, min_open=True))
        losses = []
        for _ in range(check_int("epochs", epochs)):
            opt.zero_grad()
            loss = (self.net(x) - y).pow(2).mean()
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
        return tuple(losses)


class MotorPrimitive:
    """Basis-function weights of one variable's trajectory over the window (module docstring).

    Args:
        variable: the joint (or effector) variable the primitive reads.
        window: W samples per trajectory, >= ``n_basis`` (so the fit is unique).
        n_basis: basis functions (the last one is the constant).

    The abstraction's variable has dim ``n_basis * d`` (weights flattened basis-major).
    """

    def __init__(self, variable: str, window: int, n_basis: int = 5) -> None:
        self.variable = variable
        self.window = check_int("window", window, minimum=2)
        self.n_basis = check_int("n_basis", n_basis, minimum=1)
        if self.n_basis > self.window:
            raise ValueError(
                f"n_basis {self.n_basis} exceeds the window {self.window}; the fit would not be unique"
            )
        s = torch.linspace(0.0, 1.0, self.window, dtype=torch.float64)[:, None]
        k = self.n_basis - 1
        cols = [torch.ones(self.window, 1, dtype=torch.float64)]
        if k:
            c = torch.linspace(0.0, 1.0, k, dtype=torch.float64)[None]
            cols.insert(0, torch.exp(-((s - c) ** 2) / (2 * (1.0 / self.n_basis) ** 2)))
        #: Φ: (W, n_basis) basis values at the window's phases.
        self.basis = torch.cat(cols, 1)
        self._pinv = torch.linalg.pinv(self.basis)

    def weights(self, trajectory: Any) -> Tensor:
        """Least-squares weights ``(B, n_basis, d)`` of trajectories ``(B, W, d)``."""
        x = as_float_tensor(trajectory, "trajectory", torch.float64)
        if x.ndim != 3 or x.shape[1] != self.window:
            raise ValueError(f"trajectory has shape {tuple(x.shape)}, expected (B, {self.window}, d)")
        return self._pinv @ x

    def generate(self, weights: Any) -> Tensor:
        """The trajectory ``(B, W, d)`` of weights ``(B, n_basis, d)`` or flattened ``(B, n_basis * d)``."""
        w = as_float_tensor(weights, "weights", torch.float64)
        if w.ndim == 2:
            w = w.reshape(w.shape[0], self.n_basis, -1)
        if w.ndim != 3 or w.shape[1] != self.n_basis:
            raise ValueError(f"weights have shape {tuple(w.shape)}, expected (B, {self.n_basis}, d)")
        return self.basis @ w

    def error(self, trajectory: Any) -> Tensor:
        """Root-mean-square reconstruction error per trajectory ``(B,)``, the variable's units."""
        x = as_float_tensor(trajectory, "trajectory", torch.float64)
        return (self.generate(self.weights(x)) - x).pow(2).mean((1, 2)).sqrt()

    def __call__(self, wins: Mapping[str, Tensor]) -> Tensor:
        """The abstraction mechanism: flattened weights ``(B, n_basis * d)``."""
        if self.variable not in wins:
            raise ValueError(f"windows have no variable {self.variable!r}")
        w = self.weights(wins[self.variable])
        return w.reshape(w.shape[0], -1)
