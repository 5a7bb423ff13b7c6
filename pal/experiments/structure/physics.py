"""The physics judge of ``discovery_body``: simulator interventions that justify edges into dq.

Physics is asked by intervening in the simulator on recorded test states: the standardised
effect of a parent on ``dq.j`` is

    E_{p -> dq.j} = mean_r |dq_j(p + h) - dq_j(p - h)| / (2h) * sd(p) / sd(dq_j),

with h = 0.05 rad for ``q_prev.k`` (joint k's angle moved before the step), h = 0.05 rad
for ``dq_prev.k`` (joint k's velocity at the start of the step changed by h / dt, as if
the previous step had moved it h further) and h = 0.05 x ctrl range for ``act.k``. An
edge into ``dq.j`` is *justified* when E >= :data:`JUSTIFIED`; the *physics graph* of
joint J has exactly the justified parents of dq.J (and q.J <- dq.J, q_prev.J).
"""

from __future__ import annotations

import mujoco
import numpy as np

from pal.experiments.world_model.data import Realizer

__all__ = ["JUSTIFIED", "physics_effects", "physics_graph"]

#: Smallest standardised simulator effect that justifies an edge into dq.
JUSTIFIED = 0.05


def physics_effects(
    realizer: Realizer,
    rows: np.ndarray,
    joints: list[str] | None = None,
    h_angle: float = 0.05,
    h_ctrl: float = 0.05,
) -> dict[str, float]:
    """Standardised simulator effects E_{p -> dq.j} for p in {act.k, q_prev.k, dq_prev.k}, for all j, k in ``joints``.

    Args:
        realizer: the recording (its states, commands and columns) and its simulator.
        rows: ``(R,)`` rows of the recording whose states are intervened on.
        joints: the joints j, k (default: every recorded joint).
        h_angle: angle step h of q_prev and of dq_prev (a velocity step h / dt), rad.
        h_ctrl: command step as a share of the ctrl range.

    Returns:
        ``"p->dq.j"`` -> E (dimensionless; see the module docstring).
    """
    env, dataset = realizer.env, realizer.dataset
    recorded = list(dataset.joints)
    chosen = [(i, j) for i, j in enumerate(recorded) if joints is None or j in joints]
    acts = {j: env.actuator_names.index(a) for j, a in env.joint_actuators.items() if a in env.actuator_names}
    cols = dataset.columns
    sd_dq = {j: float(cols[f"dq.{j}"].std()) for _, j in chosen}

    def dq_after(i: int, kind: str, k: int, delta: float) -> np.ndarray:
        env.set_state(dataset.states[i])
        ctrl = dataset.ctrl[i].astype(np.float64)
        if kind == "angle":
            env.data.qpos[env.qpos_indices[k]] += delta
            mujoco.mj_forward(env.model, env.data)
        elif kind == "velocity":
            env.data.qvel[env.qvel_indices[k]] += delta / env.dt
            mujoco.mj_forward(env.model, env.data)
        else:
            ctrl[k] = np.clip(ctrl[k] + delta, env.ctrl_low[k], env.ctrl_high[k])
        before = env.data.qpos[env.qpos_indices].copy()
        env.step(ctrl)
        return env.data.qpos[env.qpos_indices] - before

    out: dict[str, float] = {}
    for kj, k in chosen:
        parents = [
            (f"q_prev.{k}", "angle", kj, h_angle, float(cols[f"q_prev.{k}"].std())),
            (f"dq_prev.{k}", "velocity", kj, h_angle, float(cols[f"dq_prev.{k}"].std())),
        ]
        if k in acts:
            a = acts[k]
            h = h_ctrl * float(env.ctrl_high[a] - env.ctrl_low[a])
            parents.append((f"act.{k}", "ctrl", a, h, float(dataset.ctrl[:, a].std())))
        for name, kind, idx, h, sd_p in parents:
            diffs = np.array([dq_after(i, kind, idx, h) - dq_after(i, kind, idx, -h) for i in rows])  # (R, J)
            slope = np.abs(diffs).mean(0) / (2 * h)
            for jj, j in chosen:
                out[f"{name}->dq.{j}"] = float(slope[jj] * sd_p / sd_dq[j]) if sd_dq[j] > 0 else 0.0
    return out


def physics_graph(joint: str, effects: dict[str, float]) -> set[tuple[str, str]]:
    """The edges of joint ``joint``'s chain whose dq parents are exactly the simulator-justified ones."""
    parents = [f"{kind}.{joint}" for kind in ("act", "q_prev", "dq_prev")]
    justified = {(p, f"dq.{joint}") for p in parents if effects.get(f"{p}->dq.{joint}", 0.0) >= JUSTIFIED}
    return justified | {(f"dq.{joint}", f"q.{joint}"), (f"q_prev.{joint}", f"q.{joint}")}
