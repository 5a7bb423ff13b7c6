"""The driven part of a rollout: sites the inputs alone determine, rolled over the horizon first.

A non-root site is *driven* when its mechanism is a single one (not an ensemble, not gated, not
discrete) and each of its parents is a lag-0 root (an input such as the action), an assigned
site, another driven site, or a lag-1 root whose ``lag_of`` variable is driven. Such a site's
trajectory ``x_tau = loc(pa_tau) + scale(pa_tau) eps_tau`` (``eps = 0`` for expected residuals)
over the whole horizon follows from the inputs and the initial values alone: nothing the rest of
the model predicts feeds it. A body given by its MJCF is the common case: its joints' dynamics,
their limits, and the kinematics of its points.

:func:`driven_trajectories` computes those trajectories before the step loop of
:meth:`models.forward.ForwardQueries.rollout`, which then treats them as assigned values. The
trajectories are computed over the strongly connected components of their dependency graph, in
topological order, where a lag-1 root depends on its ``lag_of`` variable's trajectory shifted by
one step: a component without a cycle (e.g. the kinematics of the body's points) is one
mechanism call over all ``N * H`` rows; a cycle (e.g. the joints' dynamics and their previous
angles) is stepped in time, one call per site and step. Each row gets the same function of the
same inputs as in the step loop, so the rollout's values are unchanged (the batched calls may
round differently in the last bits); the Python cost of the per-step calls is what goes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import networkx as nx
import torch
from torch import Tensor

from models.gated import GatedMechanism

if TYPE_CHECKING:
    from models.graph import CausalGraph
    from models.mechanisms import Mechanism

__all__ = ["driven_sites", "driven_trajectories", "roll_driven"]

#: ``(name, values) -> concat(pa_name)`` over any leading dims (the model's ``_parents``).
ParentsFn = Callable[[str, Mapping[str, Tensor]], Tensor]


def roll_driven(
    graph: CausalGraph,
    mechanisms: Mapping[str, Mechanism],
    discrete: set[str],
    parents: ParentsFn,
    known: Mapping[str, Tensor],
    initial: Mapping[str, Tensor],
    noise: str | Mapping[str, Tensor],
) -> dict[str, Tensor]:
    """The trajectories ``(N, H, dim)`` of a rollout's driven sites, for its step loop to take as assigned.

    Empty with sampled residuals (their draws keep the step loop's order) or with a residual
    mapping that lacks one of them (the step loop reports it). Arguments as
    :func:`driven_sites` and :func:`driven_trajectories`; ``noise`` as the rollout's.
    """
    if isinstance(noise, str) and noise == "sampled":
        return {}
    sites = driven_sites(graph, mechanisms, discrete, set(known))
    if not sites or (isinstance(noise, Mapping) and any(s not in noise for s in sites)):
        return {}
    residuals = noise if isinstance(noise, Mapping) else None
    return driven_trajectories(graph, mechanisms, parents, sites, known, initial, residuals)


def driven_sites(
    graph: CausalGraph,
    mechanisms: Mapping[str, Mechanism],
    discrete: set[str] | frozenset[str],
    known: set[str],
) -> list[str]:
    """The driven non-root sites, in the graph's topological order (module docstring).

    Args:
        graph: the model's graph.
        mechanisms: name -> f_i of every non-root.
        discrete: the discrete sites (never driven).
        known: the sites whose trajectories are given (lag-0 roots and assigned sites).
    """
    lagged = graph.lagged
    candidates = [
        n
        for n in graph.non_roots
        if n not in known
        and n not in discrete
        and mechanisms[n].size == 1
        and not isinstance(mechanisms[n], GatedMechanism)
    ]
    driven = set(candidates)
    while True:  # the greatest set closed under "every parent known or driven"
        drop = {
            n for n in driven if not all(_ready(p, graph, lagged, known, driven) for p in graph.parents(n))
        }
        if not drop:
            return [n for n in graph.non_roots if n in driven]
        driven -= drop


def _ready(
    parent: str, graph: CausalGraph, lagged: Mapping[str, str], known: set[str], driven: set[str]
) -> bool:
    """Whether a parent's trajectory is known or driven (a lag-1 root's: its ``lag_of`` site's)."""
    if parent in known or parent in driven:
        return True
    if graph.is_root(parent) and graph[parent].lag == 1:
        return lagged.get(parent) in driven or lagged.get(parent) in known
    return False


def driven_trajectories(
    graph: CausalGraph,
    mechanisms: Mapping[str, Mechanism],
    parents: ParentsFn,
    sites: list[str],
    known: Mapping[str, Tensor],
    initial: Mapping[str, Tensor],
    noise: Mapping[str, Tensor] | None,
) -> dict[str, Tensor]:
    """The trajectories of the driven ``sites``: name -> ``(N, H, dim)``.

    Args:
        graph: the model's graph.
        mechanisms: name -> f_i of every non-root.
        parents: the model's parent concatenation.
        sites: :func:`driven_sites`'s result.
        known: name -> ``(N, H, dim)`` trajectories of the lag-0 roots and assigned sites.
        initial: name -> ``(N, dim)`` values of the lag-1 roots at the first step.
        noise: None for expected residuals, or name -> residuals ``(N, dim)`` (every step) or
            ``(N, H, dim)`` (one per step) of every driven site.
    """
    lagged = graph.lagged
    deps = nx.DiGraph()
    deps.add_nodes_from(sites)
    for name in sites:
        for p in graph.parents(name):
            if p in lagged and graph.is_root(p) and lagged[p] in sites:
                deps.add_edge(p, name)
                deps.add_edge(lagged[p], p)
            elif p in sites:
                deps.add_edge(p, name)
    run = _Pass(graph, mechanisms, parents, dict(known), initial, noise)
    order = {n: i for i, n in enumerate(graph.names)}
    condensed = nx.condensation(deps)
    for c in nx.topological_sort(condensed):
        members = sorted(condensed.nodes[c]["members"], key=order.__getitem__)
        if len(members) == 1 and not deps.has_edge(members[0], members[0]):
            run.whole(members[0])
        else:
            run.stepped(members)
    return {n: run.traj[n] for n in sites}


class _Pass:
    """The trajectories ``traj`` (name -> ``(N, H, dim)``) of one pre-pass, filled component by component."""

    def __init__(self, graph, mechanisms, parents, traj, initial, noise) -> None:
        self.graph, self.mechanisms, self.parents = graph, mechanisms, parents
        self.traj, self.initial, self.noise = traj, initial, noise
        self.n, self.h = next(iter(traj.values())).shape[:2]

    def trajectory(self, name: str) -> Tensor:
        """``name``'s trajectory; a lag-1 root's is its ``initial`` value, then its ``lag_of`` site's shifted by one step."""
        if name not in self.traj:
            site = self.traj[self.graph.lagged[name]]
            self.traj[name] = torch.cat([self.initial[name].unsqueeze(1), site[:, :-1]], 1)
        return self.traj[name]

    def residuals(self, name: str, tau: int | None = None) -> Tensor | None:
        """The site's residuals ``(N, H, dim)`` (``tau`` None) or ``(N, dim)`` at step ``tau``; None when expected."""
        if self.noise is None:
            return None
        eps = self.noise[name]
        if tau is not None:
            return eps[:, tau] if eps.ndim == 3 else eps
        return eps if eps.ndim == 3 else eps.unsqueeze(1).expand(self.n, self.h, eps.shape[-1])

    def whole(self, name: str) -> None:
        """An acyclic component: a lag-1 root shifted from its site, or one call over ``N * H`` rows."""
        if self.graph.is_root(name):
            self.trajectory(name)
            return
        flat = {p: self.trajectory(p).flatten(0, 1) for p in self.graph.parents(name)}
        eps = self.residuals(name)
        out = _value(
            self.mechanisms[name], self.parents(name, flat), None if eps is None else eps.flatten(0, 1)
        )
        self.traj[name] = out.reshape(self.n, self.h, out.shape[-1])

    def stepped(self, members: list[str]) -> None:
        """A cyclic component, stepped in time: its lag-1 roots read the step before (``initial`` at 0)."""
        graph, lagged = self.graph, self.graph.lagged
        roots = [m for m in members if graph.is_root(m)]
        sites = [m for m in members if not graph.is_root(m)]
        steps: dict[str, list[Tensor]] = {m: [] for m in members}
        for tau in range(self.h):
            now = {r: self.initial[r] if tau == 0 else steps[lagged[r]][tau - 1] for r in roots}
            for name in sites:
                pa = {p: now[p] if p in now else self.trajectory(p)[:, tau] for p in graph.parents(name)}
                now[name] = _value(self.mechanisms[name], self.parents(name, pa), self.residuals(name, tau))
            for m in members:
                steps[m].append(now[m])
        for m, values in steps.items():
            self.traj[m] = torch.stack(values, 1)


def _value(mech: Mechanism, pa: Tensor, eps: Tensor | None) -> Tensor:
    """``loc(pa)``, or ``loc(pa) + scale(pa) eps`` with residuals."""
    if eps is None:
        return mech(pa)
    loc, scale = mech.loc_scale(pa)
    return loc + scale * eps
