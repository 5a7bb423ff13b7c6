"""The agent's world model: the pushing graph with its mechanisms, fitting from the history, sub-models.

- :func:`build_world_model`: :func:`models.pushing_graph` over the world's joints and object slots;
- :func:`fit_world_model`: local mechanism learning (Eq. 4.33) from the sensorimotor history;
- :func:`submodel`: the same model restricted to some objects, or to the object sites given the hand;
- :func:`candidate_actions`: servo targets to try around the current joint angles.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from inference import fit
from models import CausalGraph, LinearMechanism, Role, WorldModel, pushing_graph
from pal.agent.history import History
from pal.checks import check_float, check_int
from pal.sim.pushing import JOINTS, PushingEnv

__all__ = ["build_world_model", "candidate_actions", "fit_world_model", "submodel"]

log = logging.getLogger(__name__)


def candidate_actions(
    q: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    rng: np.random.Generator,
    n: int,
    scales: tuple[float, ...] = (0.1, 0.25, 0.5),
    wide: float = 0.25,
) -> np.ndarray:
    """(n, J) candidate servo targets, rad, around the joint angles q (J,) rad.

    A share ``wide`` is uniform over [low, high], the rest q + U(-s, s) for each scale s in
    turn (fine and coarse moves), clipped to the ranges.
    """
    check_int("n", n)
    check_float("wide", wide, 0.0, 1.0)
    k = round(wide * n)
    far = rng.uniform(low, high, size=(k, len(q)))
    s = np.resize(np.asarray(scales, float), n - k)[:, None]
    near = np.asarray(q, float) + rng.uniform(-1.0, 1.0, size=(n - k, len(q))) * s
    return np.clip(np.concatenate([far, near]), low, high)


def build_world_model(
    env: PushingEnv, objects: tuple[str, ...], hidden: tuple[int, ...], seed: int
) -> WorldModel:
    """The pushing world model over the env's joints (:func:`models.pushing_graph`, object_dim 2).

    ``pos.o = W [pos_prev.o, dpos.o] + b`` is a learned linear mechanism; ``meas.o = pos.o`` is
    fixed (its sigma is replaced per frame by perception's). The rest are MLPs (seeded init).
    """
    ranges = {short: env.actuator_ranges[short] for short in JOINTS}
    graph = pushing_graph(tuple(JOINTS), ranges, objects, q_ranges=ranges, object_dim=2)
    generator = torch.Generator().manual_seed(seed)
    mechs = {}
    for o in objects:
        mechs[f"meas.{o}"] = LinearMechanism.from_coefficients(torch.eye(2), sigma=0.01)
        mechs[f"pos.{o}"] = LinearMechanism(4, 2, seed=generator)
    return WorldModel(graph, mechs, hidden=hidden, seed=seed)


def submodel(
    model: WorldModel, objects: tuple[str, ...] | None = None, *, blanket: bool = False
) -> WorldModel:
    """A pushing world model restricted to some objects, as a warm-started copy (:meth:`WorldModel.with_graph`).

    Args:
        model: a model over :func:`models.pushing_graph`.
        objects: object slots to keep (default all); the sites of the others are dropped, which
            changes nothing for the kept ones (objects do not act on each other in this graph).
        blanket: also drop the joint sites and make ``hand_prev`` and ``hand`` observed roots.
            With the hand observed, the joint sites are d-separated from the object sites, so
            the posterior over ``dpos.o`` and ``pos.o`` is that of the full program, at half the sites.
    """
    g = model.graph
    prefixes = ("pos_prev.", "contact.", "dpos.", "pos.", "meas.")
    slots = {n.split(".", 1)[1] for n in g.names if n.startswith("pos.")}
    keep_objects = slots if objects is None else set(objects)
    unknown = sorted(keep_objects - slots)
    if unknown:
        raise ValueError(f"objects {unknown} are not in the model; it has {sorted(slots)}")

    def kept(n: str) -> bool:
        if n.startswith(prefixes):
            return n.split(".", 1)[1] in keep_objects
        return n in ("hand_prev", "hand") or not blanket

    names = [n for n in g.names if kept(n)]
    hands = ("hand_prev", "hand") if blanket else ()
    variables = [replace(g[n], role=Role.OBSERVED) if n in hands else g[n] for n in names]
    return model.with_graph(CausalGraph(variables, [(p, c) for p, c in g.edges if p in names and c in names]))


def fit_world_model(
    model: WorldModel,
    history: History,
    *,
    source: str = "perceived",
    rows: Any = None,
    epochs: int = 150,
    batch_size: int = 256,
    lr: float = 0.005,
    min_sigma: float = 0.003,
    seed: int = 0,
) -> dict[str, Any]:
    """Fit every learned mechanism on the history (Eq. 4.33); return name -> fitted sigma and the row counts.

    Object mechanisms are fitted on the rows where both positions of that object are known.
    """
    arm, objects = history.columns(source, rows)
    trained: dict[str, Any] = {}
    arm_vars = [v for v in model.graph.non_roots if v.startswith(("dq.", "q.", "hand"))]
    r = fit(model, arm, variables=arm_vars, epochs=epochs, batch_size=batch_size, lr=lr, seed=seed)
    trained.update(r.sigma)
    for o, cols in objects.items():
        if len(cols[f"pos.{o}"]) < 2:
            log.warning(
                "object %r has %d usable transitions; its mechanisms stay unfitted",
                o,
                len(cols[f"pos.{o}"]),
            )
            continue
        r = fit(
            model,
            cols,
            variables=[f"contact.{o}", f"dpos.{o}"],
            epochs=epochs,
            batch_size=batch_size,
            lr=lr,
            seed=seed,
        )
        trained.update(r.sigma)
        # the linear position update converges slowly at the MLPs' learning rate: its own schedule
        r = fit(
            model,
            cols,
            variables=[f"pos.{o}"],
            epochs=max(epochs, 200),
            batch_size=batch_size,
            lr=0.05,
            seed=seed,
        )
        trained.update(r.sigma)
    for name in trained:
        mech = model.mechanism(name)
        mech.set_sigma(mech.sigma.detach().clamp_min(min_sigma))
    trained["rows"] = {
        "arm": len(next(iter(arm.values()))),
        **{o: len(c[f"pos.{o}"]) for o, c in objects.items()},
    }
    return trained
