"""Pusher-v5: does the world model predict that a push moves the object, and that the object rests when the tip is far?

Situations with the fingertip on the object and a pushing action are taken from scripted
episodes (:class:`pal.baselines.scripted_pusher_v5.ScriptedPusherV5`, seeds apart from those
of the training data): the steps in which the simulator moved the object by more than the
moved rule's floor (``MOVED_SIGMAS * position_sigma``, :mod:`pal.agent.graph`), i.e. the arm
pushed it. Each gives the model's roots before the step (joints, velocities, fingertip, object
position and previous displacement) and the scripted torques. Its **far** twin keeps the arm and
the torques and puts the object, at rest (previous displacement 0), ``far`` m from the fingertip
in the table plane, along the fingertip -> object direction.

Per model and situation the predicted displacement ``dpos.object`` is measured twice:

- **expected**: the mixture mean over the contact switch where the model has one,
  ``E[dpos] = P(c = 1) f_1(pa) + P(c = 0) f_0(pa)`` with the arm's sites at their expected
  values (:meth:`models.WorldModel.probs`, :meth:`models.WorldModel.loc`), else the expected
  prediction ``f(pa)`` (:meth:`models.WorldModel.predict`);
- **predictive**: the mean of :func:`inference.predictive_interval` (every site not given
  drawn, the switch and the arm's residuals included, the ensemble members in equal shares).

The target: ``mean_i |E dpos_on,i| / mean_i |E dpos_far,i| >= ratio`` (the far mean floored at
1 nm), evaluated when the training data hold at least one episode in which the object moved and
at least :data:`MIN_SITUATIONS` situations were found. The simulator's own displacements (the
recorded push, and the far twin replayed) are reported beside the models'.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from inference import predictive_interval
from pal.baselines.scripted_pusher_v5 import scripted_episode
from pal.checks import check_float, check_int
from pal.lab.report import Precondition, Table, Target
from pal.language.sim_worlds import PusherWorld

__all__ = ["MIN_SITUATIONS", "MotionCheck", "contact_situations", "motion_targets", "predicted_motion"]

#: Fewest contact situations for the target to be evaluated.
MIN_SITUATIONS = 20
#: Floor of the far mean in the ratio, m (a nanometre).
TINY = 1e-9
_Q, _V, _TIP, _OBJ = slice(0, 7), slice(7, 14), slice(14, 17), slice(17, 20)


@dataclass(frozen=True)
class MotionCheck:
    """Settings of the contact-motion measurement (module docstring).

    Attributes:
        situations: contact situations used (the first found), at most.
        episodes: held-out scripted episodes searched for them (100 steps each).
        far: the far twin's fingertip-object distance in the table plane, m.
        ratio: the target's lowest accepted on / far ratio.
        num_samples: draws per situation of :func:`inference.predictive_interval`.
    """

    situations: int = 40
    episodes: int = 6
    far: float = 0.3
    ratio: float = 10.0
    num_samples: int = 200

    def __post_init__(self) -> None:
        check_int("situations", self.situations)
        check_int("episodes", self.episodes)
        check_float("far", self.far, 0.0, open_low=True)
        check_float("ratio", self.ratio, 0.0, open_low=True)
        check_int("num_samples", self.num_samples, 2)


def _far(values: dict[str, np.ndarray], far: float) -> dict[str, np.ndarray]:
    """The far twins: the object at rest ``far`` m from the fingertip along fingertip -> object (table plane)."""
    tip, pos = values["ee_prev"], values["pos_prev.object"]
    d = pos[:, :2] - tip[:, :2]
    u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    out = dict(values)
    out["pos_prev.object"] = np.concatenate([tip[:, :2] + far * u, pos[:, 2:]], 1)
    out["vel_prev.object"] = np.zeros_like(values["vel_prev.object"])
    return out


def contact_situations(env: Any, check: MotionCheck, seeds: list[int], floor: float) -> dict[str, Any]:
    """The pushing steps of scripted episodes and their far twins (module docstring).

    Args:
        env: ``gymnasium.make("Pusher-v5")`` (its state is changed).
        check: the settings.
        seeds: one reset seed per episode.
        floor: the moved rule's floor, m.

    Returns:
        ``{"on": values, "far": values, "sim_on": (n,), "sim_far": (n,)}``: values name ->
        ``(n, d)`` (``act``, ``q_prev``, ``v_prev``, ``ee_prev``, ``pos_prev.object``,
        ``vel_prev.object``), the simulator's |dpos| of each, m; n may be 0.
    """
    rows: list[dict[str, np.ndarray]] = []
    states: list[np.ndarray] = []
    for s in seeds:
        ep = scripted_episode(env, s)
        obs = ep["observations"]
        for t in range(1, len(ep["actions"])):
            moved = np.linalg.norm(obs[t + 1, _OBJ] - obs[t, _OBJ])
            if moved > floor and len(rows) < check.situations:
                rows.append(
                    {
                        "act": ep["actions"][t],
                        "q_prev": obs[t, _Q],
                        "v_prev": obs[t, _V],
                        "ee_prev": obs[t, _TIP],
                        "pos_prev.object": obs[t, _OBJ],
                        "vel_prev.object": obs[t, _OBJ] - obs[t - 1, _OBJ],
                        "moved": np.array([moved]),
                    }
                )
                states.append(ep["states"][t])
    if not rows:
        return {"on": {}, "far": {}, "sim_on": np.zeros(0), "sim_far": np.zeros(0)}
    on = {k: np.stack([r[k] for r in rows]) for k in rows[0] if k != "moved"}
    far = _far(on, check.far)
    return {
        "on": on,
        "far": far,
        "sim_on": np.array([float(r["moved"][0]) for r in rows]),
        "sim_far": _replay_far(env, np.stack(states), on, far),
    }


def _replay_far(
    env: Any, states: np.ndarray, on: dict[str, np.ndarray], far: dict[str, np.ndarray]
) -> np.ndarray:
    """The simulator's |dpos| of the far twins: the recorded state with the object moved there and at rest."""
    world = PusherWorld(env)
    m = env.unwrapped.model
    jnt = m.body_jntadr[m.body("object").id]
    slide = m.jnt_qposadr[jnt + np.arange(2)]
    dof = m.jnt_dofadr[jnt + np.arange(2)]
    axes = m.jnt_axis[jnt + np.arange(2), :2].T  # (2, 2) slide axes
    out = []
    for i, state in enumerate(states):
        s = state.copy()
        shift = np.linalg.solve(axes, far["pos_prev.object"][i, :2] - on["pos_prev.object"][i, :2])
        s[slide] += shift
        s[m.nq + dof] = 0.0
        start = world.restore(s)["pos.object"]
        after = world.advance(on["act"][i])["pos.object"]
        out.append(float(np.linalg.norm(after - start)))
    return np.array(out)


def _tensors(model: Any, values: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(v, dtype=model.dtype) for k, v in values.items() if k in model.graph}


def _expected(model: Any, values: Mapping[str, np.ndarray], site: str, switch: str) -> torch.Tensor:
    """``(n, d)`` E[site]: the mixture mean over a Bernoulli ``switch`` parent, else the expected prediction."""
    given = _tensors(model, values)
    with torch.no_grad():
        known = {**given, **model.predict(given)}
        if switch not in model.graph.parents(site) or model.categories(switch) != 2:
            return known[site]
        p_on = model.probs(switch, {p: known[p] for p in model.graph.parents(switch)})[..., 1:2]
        parents = {p: known[p] for p in model.graph.parents(site) if p != switch}
        on = model.loc(site, {**parents, switch: torch.ones_like(p_on)})
        off = model.loc(site, {**parents, switch: torch.zeros_like(p_on)})
    return p_on * on + (1.0 - p_on) * off


def predicted_motion(
    model: Any, situations: dict[str, Any], check: MotionCheck, seed: int, obj: str = "object"
) -> dict[str, Any]:
    """Per situation |E dpos| on the object and far from it, expected and predictive, m (module docstring)."""
    site, switch = f"dpos.{obj}", f"contact.{obj}"
    out: dict[str, Any] = {}
    for where in ("on", "far"):
        values = situations[where]
        out[f"expected_{where}"] = _expected(model, values, site, switch).norm(dim=-1).numpy()
        pi = predictive_interval(model, _tensors(model, values), site, 0.9, check.num_samples, seed)
        out[f"predictive_{where}"] = pi.mean.norm(dim=-1).numpy()
    return out


def _ratio(on: np.ndarray, far: np.ndarray) -> float | None:
    return None if on.size == 0 else float(on.mean() / max(float(far.mean()), TINY))


def motion_targets(
    predicted: Mapping[str, Mapping[str, np.ndarray]],
    situations: Mapping[str, Any],
    check: MotionCheck,
    moved_episodes: int,
) -> tuple[dict[str, Any], Table, list[Target]]:
    """Metrics, table and targets ``contact_motion.<model>.<expected|predictive>`` (module docstring).

    Args:
        predicted: model name -> :func:`predicted_motion`.
        situations: :func:`contact_situations`.
        check: the settings.
        moved_episodes: training episodes in which the object moved by more than the floor.
    """
    n = int(situations["sim_on"].size)
    holds = moved_episodes >= 1 and n >= MIN_SITUATIONS
    pre = Precondition(
        holds,
        f"the training data hold >= 1 episode in which the object moved (had {moved_episodes}) and "
        f">= {MIN_SITUATIONS} contact situations were found (found {n})",
    )
    mean = lambda a: float(a.mean()) if a.size else None  # noqa: E731
    metrics: dict[str, Any] = {
        "situations": n,
        "moved_episodes": moved_episodes,
        "far": check.far,
        "simulator": {"on": mean(situations["sim_on"]), "far": mean(situations["sim_far"])},
    }
    rows = [["simulator", mean(situations["sim_on"]), mean(situations["sim_far"]), None, None, None, None]]
    targets = []
    for name, p in predicted.items():
        block = {}
        for kind in ("expected", "predictive"):
            on, far = p[f"{kind}_on"], p[f"{kind}_far"]
            block[kind] = {"on": mean(on), "far": mean(far), "ratio": _ratio(on, far)}
            targets.append(
                Target(
                    f"contact_motion.{name}.{kind}",
                    block[kind]["ratio"],
                    check.ratio,
                    ">=",
                    f"Pusher-v5, {name} model: mean predicted |dpos.object| ({kind}) with the fingertip on the "
                    f"object pushing / with the object {check.far} m away, over the contact situations",
                    pre,
                )
            )
        metrics[name] = block
        e, q = block["expected"], block["predictive"]
        rows.append([name, e["on"], e["far"], e["ratio"], q["on"], q["far"], q["ratio"]])
    table = Table(
        "Pusher-v5: predicted object motion with the fingertip on the object (pushing) and far from it [m per step]",
        ["world", "expected on", "expected far", "ratio", "predictive on", "predictive far", "ratio"],
        [[r[0], *(None if v is None else float(v) for v in r[1:])] for r in rows],
        caption=f"{n} situations from held-out scripted pushes (the steps in which the simulator moved the "
        f"object); far: the object at rest {check.far} m from the fingertip; the simulator's row: the "
        "recorded push and the far twin replayed.",
    )
    return metrics, table, targets
