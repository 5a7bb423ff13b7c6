"""Stability selection for :func:`inference.discover`: how often each edge is found on row subsamples.

The whole search is repeated on B random subsamples of the rows (without replacement, a share
``options.subsample`` each); an edge's stability is the share of them whose graph holds it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from inference.admissible import StructureData

__all__ = ["edge_stability"]


def edge_stability(
    vs: Sequence[Any],
    sdata: StructureData,
    allowed: Mapping[str, tuple[str, ...]],
    required: set[tuple[str, str]],
    opts: Any,
    seed: int,
    progress_bar: bool,
    search: Callable[..., tuple[Any, ...]],
) -> tuple[dict[tuple[str, str], float], dict[tuple[str, str], float]]:
    """Edge and adjacency frequencies over ``opts.bootstrap`` subsamples of the rows.

    ``opts`` is the :class:`inference.discovery.DiscoveryOptions` (``bootstrap``, ``subsample``);
    ``search`` is one search on a :class:`StructureData` (the discovery pipeline's), called as
    ``search(vs, data, allowed, required, opts, seed, None)`` and returning the graph first.
    """
    if not opts.bootstrap:
        return {}, {}
    n = sdata.n
    m = max(8, round(opts.subsample * n))
    gen = np.random.default_rng([seed, 0x5AB])
    index = {name: i for i, name in enumerate(sdata.names)}
    edges: Counter[tuple[str, str]] = Counter()
    pairs: Counter[tuple[str, str]] = Counter()
    for b in tqdm(range(opts.bootstrap), desc="discover: subsamples", disable=not progress_bar, leave=False):
        rows = torch.from_numpy(np.sort(gen.choice(n, size=m, replace=False)))
        sub = StructureData(
            sdata.names, sdata.x[rows], sdata.slices, {k: v[rows] for k, v in sdata.rows.items()}
        )
        graph = search(vs, sub, allowed, required, opts, seed + 1 + b, None)[0]
        edges.update(graph.edges)
        pairs.update((p, c) if index[p] < index[c] else (c, p) for p, c in graph.edges)
    key = lambda e: (index[e[1]], index[e[0]])  # noqa: E731
    return (
        {e: edges[e] / opts.bootstrap for e in sorted(edges, key=key)},
        {e: pairs[e] / opts.bootstrap for e in sorted(pairs, key=key)},
    )
