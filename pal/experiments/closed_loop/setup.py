"""The protocol shared by experiments C1-C4: the pushing world, a babbling agent, one-step predictions.

Every experiment starts the same way: an :class:`pal.agent.Agent` over
:class:`pal.sim.pushing.PushingEnv` (its camera view in ``info``, spec :func:`pal.agent.pushing_spec`)
babbles for ``babble_steps`` steps while it perceives (Π on the self-filtered RGB-D frames), so its
history holds for every step the executed servo targets, the joint angles, the sensed hand and
touch, the perceived object positions and, copied from the environment's ``info`` for evaluation
only, the true ones and the simulator state. Objects are put back every ``agent.reset_every`` steps.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from inference import SamplingConfig
from models import WorldModel
from pal.agent import (
    Agent,
    AgentConfig,
    CuriosityConfig,
    EstimateConfig,
    ModelConfig,
    PlanConfig,
    build_graph,
    build_model,
    fit_model,
    pushing_spec,
)
from pal.agent.config import ESTIMATE_SVI, MODEL_SCHEDULE, PLAN_ACTION, PLAN_SAMPLING
from pal.agent.graph_frame import world_displacement
from pal.agent.history import History
from pal.checks import check_float, check_int
from pal.experiments.closed_loop.regimes import contact_coverage
from pal.sim.pushing import PushingEnv

__all__ = [
    "QUICK_SETUP",
    "TINY_AGENT",
    "TINY_SETUP",
    "SetupConfig",
    "babbled_agent",
    "contact_coverage",
    "fitted_model",
    "predict_displacements",
    "split_rows",
    "summary",
]

log = logging.getLogger(__name__)


def summary(values: Any) -> dict[str, float | int | None]:
    """Median, mean, 25th and 75th percentile and count of a 1-d array; None statistics when empty."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.size == 0:
        return {"median": None, "mean": None, "p25": None, "p75": None, "n": 0}
    return {
        "median": float(np.median(v)),
        "mean": float(v.mean()),
        "p25": float(np.percentile(v, 25)),
        "p75": float(np.percentile(v, 75)),
        "n": int(v.size),
    }


@dataclass(frozen=True)
class SetupConfig:
    """Settings every pushing experiment shares (the seed is the experiment's).

    Attributes:
        babble_steps: babbling steps that make the training history.
        camera_size: (width, height) of the RGB-D camera, pixels.
        agent: the agent's settings: its model and fits (Eq. 4.33), inference, episodes
            (objects are put back at seeded random places every ``agent.reset_every`` steps).
    """

    babble_steps: int = 3000
    camera_size: tuple[int, int] = (320, 240)
    agent: AgentConfig = AgentConfig()

    def __post_init__(self) -> None:
        check_int("babble_steps", self.babble_steps)
        if len(self.camera_size) != 2:
            raise ValueError(f"camera_size must be (width, height) in pixels, got {self.camera_size!r}")
        object.__setattr__(
            self, "camera_size", tuple(check_int("camera_size", v, 16) for v in self.camera_size)
        )


#: The agent of the tiny runs: small ensembles fitted for a few epochs, light inference, short episodes.
TINY_AGENT = AgentConfig(
    model=ModelConfig(members=2, hidden=(8,), schedule=replace(MODEL_SCHEDULE, epochs=3, patience=None)),
    estimate=EstimateConfig(num_steps=30, svi=replace(ESTIMATE_SVI, lr=0.05)),
    plan=PlanConfig(
        action=replace(
            PLAN_ACTION, sampling=replace(PLAN_SAMPLING, population=8, elites=2, iterations=1, refine_steps=3)
        )
    ),
    curiosity=CuriosityConfig(
        sampling=SamplingConfig(population=8, elites=2, iterations=1), influence_samples=4
    ),
    reset_every=12,
)
#: Babbling of the tiny runs (a few seconds) and of the quick ones (``--quick``).
TINY_SETUP = SetupConfig(babble_steps=24, agent=TINY_AGENT)
QUICK_SETUP = SetupConfig(
    babble_steps=240, agent=AgentConfig(model=ModelConfig(schedule=replace(MODEL_SCHEDULE, epochs=40)))
)


def babbled_agent(config: SetupConfig, seed: int, *, progress_bar: bool = False) -> Agent:
    """A new agent in a new world that has babbled ``config.babble_steps`` steps (not fitted yet).

    Args:
        config: the protocol.
        seed: the agent's master seed.
        progress_bar: show a tqdm bar over the babbling steps.
    """
    env = PushingEnv(camera_size=config.camera_size, camera=True)
    agent = Agent(env, pushing_spec(), config.agent, seed=seed)
    start = time.perf_counter()
    agent.run(config.babble_steps, "babble", progress_bar=progress_bar)
    log.info("babbled %d steps in %.1f s", config.babble_steps, time.perf_counter() - start)
    return agent


def split_rows(n: int, test_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """``(train, test)`` row indices: the first ``1 - test_fraction`` of ``n`` rows, then the rest."""
    check_float("test_fraction", test_fraction, 0.0, 1.0, open_low=True, open_high=True)
    n_train = round((1 - test_fraction) * n)
    if not 0 < n_train < n:
        raise ValueError(f"{n} rows with test_fraction {test_fraction} leave no training or no test rows")
    return np.arange(n_train), np.arange(n_train, n)


def fitted_model(
    agent: Agent,
    config: SetupConfig,
    seed: int,
    source: str,
    rows: np.ndarray,
    *,
    displacement: str | None = None,
) -> tuple[WorldModel, dict[str, int]]:
    """A new world model of the agent's spec fitted on ``rows`` of its history (``config.agent.model``).

    Args:
        agent: the agent whose history, spec and graph are used.
        config: the protocol (its agent config gives the model and fit schedule).
        seed: seeds the model's initial weights and the fit.
        source: object positions from ``"perceived"`` (Π) or ``"truth"`` (the simulator).
        rows: indices of the history rows to fit on.
        displacement: the displacement form (``"gated"`` or ``"smooth"``,
            :attr:`pal.agent.config.ModelConfig.displacement`); None: the agent config's.

    Returns:
        ``(model, rows)``: ``rows`` counts the fitted transitions (``arm`` and per object).
    """
    m = config.agent.model
    graph = agent.graph
    if displacement is not None and displacement != m.displacement:
        m = replace(m, displacement=displacement)
        graph = build_graph(agent.spec, (agent.low, agent.high), displacement=displacement)
    model = build_model(agent.spec, graph, m, seed=seed)
    out = fit_model(model, agent.history, agent.spec, m, source=source, rows=rows, seed=seed)
    return model, out["rows"]


def predict_displacements(
    model: WorldModel, history: History, rows: np.ndarray, source: str
) -> dict[str, dict[str, np.ndarray]]:
    """One-step predictions of every object's displacement from the actions (Alg. 4.1, expected noise).

    The model gets the executed servo targets, the joint angles and the sensed hand before the
    step and the object positions before it: perceived ones (``source="perceived"``) or true
    ones (``"truth"``); the chain is actions -> joints -> hand -> contact -> displacement. Only
    rows where the object was perceived before the step are used, for both sources, so the two
    are compared on the same transitions.

    Returns:
        object -> ``{"predicted": (n, 2), "sd": (n, 2), "true": (n, 2), "rows": (n,), "touch": (n,)}``,
        with the predictive sd of the displacement and the true displacement, metres.
    """
    act, q_prev, hand_prev = (history.array(k)[rows] for k in ("act", "q_prev", "hand_prev"))
    meas_prev, truth_prev, truth = (history.array(k)[rows] for k in ("meas_prev", "truth_prev", "truth"))
    touch = history.array("touch")[rows]
    out = {}
    for k, o in enumerate(history.objects):
        ok = np.isfinite(meas_prev[:, k, 0])
        values = {"act": act[ok], "q_prev": q_prev[ok], "ee_prev": hand_prev[ok]}
        for kk, oo in enumerate(history.objects):
            prev = meas_prev[ok, kk] if source == "perceived" else truth_prev[ok, kk]
            # another object's unseen position does not enter o's mechanisms; any finite value will do
            values[f"pos_prev.{oo}"] = np.where(np.isfinite(prev), prev, truth_prev[ok, kk])
        tensors = {n: torch.as_tensor(v, dtype=model.dtype) for n, v in values.items()}
        pred = model.predict(tensors)
        scale = model.predict_scale(tensors)
        predicted, sd = world_displacement(model.graph, pred, scale, o)
        out[o] = {
            "predicted": predicted.numpy().astype(np.float64),
            "sd": sd.numpy().astype(np.float64),
            "true": truth[ok, k] - truth_prev[ok, k],
            "rows": np.asarray(rows)[ok],
            "touch": touch[ok, k],
        }
    return out
