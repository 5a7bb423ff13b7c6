"""The protocol shared by experiments C1-C4: the pushing world, a babbling agent, one-step predictions.

Every experiment starts the same way: an :class:`pal.agent.Agent` in the pushing world
(:class:`pal.sim.pushing.PushingEnv`) babbles for ``babble_steps`` steps while it perceives (Π on
the self-filtered RGB-D frames), so its history holds for every step the executed servo targets,
the joint angles, the sensed hand and touch, the perceived object positions and, for evaluation
only, the true ones and the simulator state. Objects are put back every ``reset_every`` steps.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from models import WorldModel
from pal.agent import Agent, AgentConfig
from pal.agent.history import History
from pal.sim.pushing import PushingEnv

__all__ = ["SetupConfig", "babbled_agent", "predict_displacements", "summary"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SetupConfig:
    """Settings every pushing experiment shares.

    Attributes:
        seed: master seed (world resets, babbling, fits, inference).
        babble_steps: babbling steps that make the training history.
        epochs: fitting epochs (Eq. 4.33), batch 256, lr 0.005.
        hidden: MLP widths of the learned mechanisms.
        reset_every: steps per episode (objects put back at seeded random places).
        camera_size: (width, height) of the RGB-D camera, pixels.
    """

    seed: int = 0
    babble_steps: int = 3000
    epochs: int = 150
    hidden: tuple[int, ...] = (64, 64)
    reset_every: int = 40
    camera_size: tuple[int, int] = (320, 240)

    def __post_init__(self) -> None:
        for name in ("babble_steps", "epochs", "reset_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")

    def agent(self, **overrides: Any) -> AgentConfig:
        """The agent's settings for this protocol (``overrides`` replace fields)."""
        base = AgentConfig(
            seed=self.seed, epochs=self.epochs, hidden=tuple(self.hidden), reset_every=self.reset_every
        )
        return replace(base, **overrides)


def babbled_agent(config: SetupConfig, *, progress_bar: bool = False, **overrides: Any) -> Agent:
    """A new agent in a new world that has babbled ``config.babble_steps`` steps (not fitted yet)."""
    torch.set_num_threads(1)
    env = PushingEnv(camera_size=tuple(config.camera_size))
    agent = Agent(env, config.agent(**overrides))
    start = time.perf_counter()
    agent.run(config.babble_steps, "babble", progress_bar=progress_bar)
    log.info("babbled %d steps in %.1f s", config.babble_steps, time.perf_counter() - start)
    return agent


def predict_displacements(
    model: WorldModel, history: History, rows: np.ndarray, source: str
) -> dict[str, dict[str, np.ndarray]]:
    """One-step predictions of every object's displacement from the actions (Alg. 4.1, expected noise).

    The model gets the executed servo targets, the joint angles before the step and the object
    positions before it: perceived ones (``source="perceived"``) or true ones (``"truth"``).
    Only rows where the object was perceived before the step are used, for both sources, so the
    two are compared on the same transitions.

    Returns:
        object -> ``{"predicted": (n, 2), "true": (n, 2), "rows": (n,), "touch": (n,)}``, with the
        true displacement from the simulator, metres.
    """
    act, q_prev = history.array("act")[rows], history.array("q_prev")[rows]
    meas_prev, truth_prev, truth = (history.array(k)[rows] for k in ("meas_prev", "truth_prev", "truth"))
    touch = history.array("touch")[rows]
    joints, objects = history.joints, history.objects
    out = {}
    for k, o in enumerate(objects):
        ok = np.isfinite(meas_prev[:, k, 0])
        values = {f"act.{j}": act[ok, c : c + 1] for c, j in enumerate(joints)}
        values.update({f"q_prev.{j}": q_prev[ok, c : c + 1] for c, j in enumerate(joints)})
        for kk, oo in enumerate(objects):
            prev = meas_prev[ok, kk] if source == "perceived" else truth_prev[ok, kk]
            # another object's unseen position does not enter o's mechanisms; any finite value will do
            values[f"pos_prev.{oo}"] = np.where(np.isfinite(prev), prev, truth_prev[ok, kk])
        pred = model.predict(
            {n: torch.as_tensor(v, dtype=torch.get_default_dtype()) for n, v in values.items()}
        )
        out[o] = {
            "predicted": pred[f"dpos.{o}"].numpy().astype(np.float64),
            "true": truth[ok, k] - truth_prev[ok, k],
            "rows": np.asarray(rows)[ok],
            "touch": touch[ok, k],
        }
    return out


def summary(values: np.ndarray) -> dict[str, float]:
    """Median, mean, 25th and 75th percentile of a 1-d array (NaN-free), as floats."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return {
            "median": float("nan"),
            "mean": float("nan"),
            "p25": float("nan"),
            "p75": float("nan"),
            "n": 0,
        }
    return {
        "median": float(np.median(v)),
        "mean": float(v.mean()),
        "p25": float(np.percentile(v, 25)),
        "p75": float(np.percentile(v, 75)),
        "n": int(v.size),
    }
