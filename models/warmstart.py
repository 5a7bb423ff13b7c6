"""Warm starts across graph edits: a mechanism rewired to read a new parent set.

A copy of a mechanism keeps the input columns (first-layer weights and input normalisers) of
the parents that remain and gets zero weight columns for the new ones, so its output is
unchanged when parents are only added. :meth:`models.WorldModel.with_graph` uses it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch

from models.gated import GatedMechanism
from models.graph import CausalGraph
from models.mechanisms import Mechanism, Seed, make_mechanism

__all__ = ["rewire_mechanism"]


def _columns(graph: CausalGraph, parents: Sequence[str]) -> dict[str, slice]:
    out, start = {}, 0
    for p in parents:
        out[p] = slice(start, start + graph[p].dim)
        start += graph[p].dim
    return out


def _with_in_dim(config: Mapping[str, Any], in_dim: int) -> dict[str, Any]:
    """``config`` of the same mechanism reading ``in_dim`` inputs (ensemble members too)."""
    if config.get("kind") == "ensemble":
        return {**config, "members": [_with_in_dim(c, in_dim) for c in config["members"]]}
    if config.get("kind") == "gated":
        off = config.get("off")
        return {**config, "on": _with_in_dim(config["on"], in_dim), "off": off and _with_in_dim(off, in_dim)}
    return {**config, "in_dim": in_dim}


def rewire_mechanism(
    mech: Mechanism,
    old_graph: CausalGraph,
    old_parents: Sequence[str],
    new_graph: CausalGraph,
    new_parents: Sequence[str],
    seed: Seed = None,
) -> Mechanism | None:
    """A copy of ``mech`` reading ``new_parents``, or None if it cannot be rewired.

    Kept parents keep their input columns (the weights of :meth:`Mechanism.input_weights`
    and the input normalisers), new ones start with zero weights; everything else (sigma,
    scale heads, output normalisers) is copied. Function mechanisms cannot be rewired, nor a
    gated mechanism whose switch is not among the new parents.

    Args:
        mech: the mechanism.
        old_graph: the graph ``mech`` was made for.
        old_parents: the parents ``mech`` reads, in order.
        new_graph: the edited graph.
        new_parents: the parents the copy reads, in order.
        seed: int or generator for the initial draws of the copy (all overwritten; they
            only advance the generator, as building a fresh mechanism would).
    """
    keys = mech.input_weights()
    if not keys or (isinstance(mech, GatedMechanism) and mech.switch not in new_parents):
        return None
    new_dim = sum(new_graph[p].dim for p in new_parents)
    out = make_mechanism(_with_in_dim(mech.config(), new_dim), seed=seed)
    state = {k: v.clone() for k, v in mech.state_dict().items()}
    old_cols, new_cols = _columns(old_graph, old_parents), _columns(new_graph, new_parents)
    for key in keys:
        old = state[key]
        weight = torch.zeros(old.shape[0], new_dim, dtype=old.dtype)
        for p, cols in new_cols.items():
            if p in old_cols:
                weight[:, cols] = old[:, old_cols[p]]
        state[key] = weight
    for key in [k for k in state if k.rsplit(".", 1)[-1] in ("in_loc", "in_scale")]:
        old = state[key]
        fresh = (
            torch.zeros(new_dim, dtype=old.dtype)
            if key.endswith("in_loc")
            else torch.ones(new_dim, dtype=old.dtype)
        )
        for p, cols in new_cols.items():
            if p in old_cols:
                fresh[cols] = old[old_cols[p]]
        state[key] = fresh
    out.load_state_dict(state, strict=True)
    return out
