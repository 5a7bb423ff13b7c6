"""Hold a module's parameters fixed while a query optimises something else."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ["frozen_parameters"]


@contextmanager
def frozen_parameters(module: object) -> Iterator[object]:
    """Turn off ``requires_grad`` on every parameter of ``module`` and restore it on exit.

    State and action inference optimise guide parameters or actions through the world
    model; without this the model's own parameters would also build graphs and accumulate
    ``.grad`` on every step, which costs time and leaks gradients into a later ``fit``.
    Anything that is not a ``torch.nn.Module`` has no parameters to hold and passes through.
    """
    params = list(module.parameters()) if isinstance(module, torch.nn.Module) else []
    before = [p.requires_grad for p in params]
    for p in params:
        p.requires_grad_(False)
    try:
        yield module
    finally:
        for p, flag in zip(params, before, strict=True):
            p.requires_grad_(flag)
