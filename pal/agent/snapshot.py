"""An agent's learned state in one file, restored into an agent built the same way.

A snapshot holds what an :class:`pal.agent.Agent` has learned and what its future draws
depend on: the world model's ``state_dict`` (``model/<key>`` arrays), the history
(``history/<field>`` arrays and its layout), the agent's random generator, its step and
episode counters, whether it was fitted, and the learner's residual monitor and revisions.
Episode-level state (the percept, the estimate, a half-executed plan, the correction) is not
kept: a snapshot is taken between episodes, right after a refit, which clears it.

:func:`restore_agent` loads a snapshot into an agent constructed with the same spec, config
and seed (its MJCF mechanisms are rebuilt from its environment, so the model need not be
serialisable by :mod:`models.io`); the graph fingerprint and every state key and shape must
match, so a snapshot of another model is refused, never half-applied. An agent restored and run
on draws the same actions and fits the same weights as the one that was never stopped (tested).

Files are ``.npz`` without pickle, written atomically by :func:`pal.io.files.write_npz`, with the
format tag :data:`FORMAT`, library versions and a checksum.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from inference.residual_monitor import ResidualMonitor
from pal.agent.history import History
from pal.io.files import FileFormatError, read_npz, write_npz

if TYPE_CHECKING:
    from pal.agent.loop import Agent

__all__ = ["FORMAT", "restore_agent", "save_agent", "snapshot_metadata"]

#: The format tag of an agent snapshot.
FORMAT = "pal.agent-snapshot/1"


def save_agent(agent: Agent, path: str | os.PathLike[str], metadata: Mapping[str, Any] | None = None) -> Path:
    """Write ``agent``'s learned state (module docstring) to ``path`` atomically.

    Args:
        agent: the agent, between episodes.
        path: destination ``.npz``.
        metadata: JSON-compatible extras, returned by :func:`restore_agent`.

    Raises:
        ValueError: a NaN/inf model parameter (names it) or metadata that is not strict JSON.
    """
    arrays: dict[str, np.ndarray] = {}
    for key, value in agent.model.state_dict().items():
        if not bool(torch.isfinite(value).all()):
            raise ValueError(f"model state {key!r} has NaN/inf entries; refusing to snapshot a broken model")
        arrays[f"model/{key}"] = value.detach().cpu().numpy()
    arrays |= {f"history/{k}": v for k, v in agent.history.arrays().items()}
    monitor = agent.learner.monitor
    meta = {
        "graph_fingerprint": agent.model.graph.fingerprint(),
        "history": agent.history.layout_meta(),
        "rng": _json_state(agent.rng.bit_generator.state),
        "fitted": agent.fitted,
        "counters": {"episode": agent.episode, "steps": agent.steps, "clock": agent.clock},
        "monitor": None if monitor is None else monitor.state(),
        "revisions": list(agent.learner.revisions),
        "metadata": dict(metadata or {}),
    }
    return write_npz(path, arrays, meta, format=FORMAT, compress=True)


def restore_agent(agent: Agent, path: str | os.PathLike[str]) -> dict[str, Any]:
    """Load the snapshot at ``path`` into ``agent`` (built with the snapshot's spec, config and seed).

    Returns:
        the ``metadata`` given to :func:`save_agent`.

    Raises:
        FileFormatError: a missing or corrupted file, or one of another model (another graph, or
            state keys or shapes that differ; names them). ``agent`` is unchanged then.
    """
    f = read_npz(path, format=FORMAT)
    meta, source = f.meta, str(path)
    if meta.get("graph_fingerprint") != agent.model.graph.fingerprint():
        raise FileFormatError(f"{source}: snapshot of another graph than the agent's ({agent.model.graph!r})")
    state = {k[len("model/") :]: torch.as_tensor(v) for k, v in f.arrays.items() if k.startswith("model/")}
    _check_state(source, agent.model.state_dict(), state)
    history = History.from_arrays(
        meta["history"],
        {k[len("history/") :]: v for k, v in f.arrays.items() if k.startswith("history/")},
        source,
    )
    try:
        monitor = (
            None if meta["monitor"] is None else ResidualMonitor.from_state(agent.model, meta["monitor"])
        )
    except ValueError as err:
        raise FileFormatError(f"{source}: {err}") from None
    agent.model.load_state_dict(state, strict=True)  # nothing is changed before this line
    agent.history = history
    agent.rng.bit_generator.state = _rng_state(meta["rng"])
    agent.fitted = bool(meta["fitted"])
    counters = meta["counters"]
    agent.episode, agent.steps, agent.clock = (
        int(counters["episode"]),
        int(counters["steps"]),
        counters["clock"],
    )
    agent.learner.monitor = monitor
    agent.learner.revisions = list(meta["revisions"])
    return dict(meta["metadata"])


def snapshot_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``metadata`` of a snapshot, read without touching an agent (e.g. to check it first).

    Raises:
        FileFormatError: a missing or corrupted file.
    """
    return dict(read_npz(path, format=FORMAT).meta["metadata"])


def _check_state(
    source: str, current: Mapping[str, torch.Tensor], stored: Mapping[str, torch.Tensor]
) -> None:
    """Refuse stored model state whose keys, shapes or dtypes differ from the agent's model."""
    missing, unexpected = sorted(set(current) - set(stored)), sorted(set(stored) - set(current))
    if missing or unexpected:
        raise FileFormatError(
            f"{source}: the snapshot's model state does not fit the agent's: missing {missing[:5]}, "
            f"unexpected {unexpected[:5]} (a model revised structurally, or another configuration)"
        )
    bad = [k for k, v in current.items() if v.shape != stored[k].shape or v.dtype != stored[k].dtype]
    if bad:
        raise FileFormatError(f"{source}: model state {bad[:5]} differ in shape or dtype from the agent's")


def _json_state(state: Mapping[str, Any]) -> dict[str, Any]:
    """A numpy bit generator's state as JSON (its integers may exceed 64 bits: stored as strings)."""
    return {
        k: _json_state(v)
        if isinstance(v, Mapping)
        else (str(v) if isinstance(v, int) and not isinstance(v, bool) else v)
        for k, v in state.items()
    }


def _rng_state(state: Mapping[str, Any]) -> dict[str, Any]:
    """Inverse of :func:`_json_state`."""
    return {
        k: _rng_state(v) if isinstance(v, Mapping) else (int(v) if isinstance(v, str) and v.isdigit() else v)
        for k, v in state.items()
    }
