"""Estimate: the belief over the object positions after each step (thesis Eq. 4.41-4.42).

A sensed object's estimate is its observation. A perceived one enters the world model through its
measurement site ``meas.o ~ Normal(pos.o, sigma_perception(t))``: :func:`inference.infer_state`
with ``measurement_scale`` returns the posterior over the true position ``pos.o`` given the last
transition, on the object sites of the model given the sensed effector
(:func:`pal.agent.graph.blanket`). The evidence is the previous estimate ``pos_prev.o``, the
effector relative to it before and after (``rel_prev.o``, ``rel.o``; in the push frame also the
body's points relative to it, ``prel_prev.o``, ``prel.o``, and all of them turned, ``local.o``),
touch ``contact.o`` and, for a visible object, ``meas.o`` with perception's sigma. A lost object's
``meas.o`` is left unobserved, so its posterior is the model's prediction; no NaN ever reaches the
model.
:func:`belief` assembles the state the planner starts from (the graph's lag-1 roots).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
import pyro
import torch

from inference import MeasurementScale, infer_state
from inference.diagnostics import PoorPosteriorWarning
from models import WorldModel
from pal.agent.config import DISPLACEMENTS, EstimateConfig
from pal.agent.graph import blanket
from pal.agent.graph_frame import frame_columns
from pal.agent.history import relative
from pal.agent.senses import Percept
from pal.agent.spec import EnvSpec
from pal.checks import check_choice

log = logging.getLogger(__name__)

__all__ = ["Estimator", "belief"]

Estimate = dict[str, np.ndarray | None]


def belief(
    spec: EnvSpec, percept: Percept, estimate: Mapping[str, np.ndarray | None], previous: Mapping[str, Any]
) -> dict[str, np.ndarray]:
    """The graph's lag-1 roots now: name -> (dim,) (``q_prev``, ``v_prev``, ``ee_prev``, ``pos_prev.o``, ``vel_prev.o``).

    Args:
        spec: the environment's spec.
        percept: the current percept.
        estimate: object -> current estimate or None (unknown objects are left out).
        previous: object -> the estimate one step earlier (for ``vel_prev.o``; missing: at rest).
    """
    out: dict[str, np.ndarray] = {"q_prev": percept.q}
    if percept.v is not None:
        out["v_prev"] = percept.v
    if percept.effector is not None:
        out["ee_prev"] = percept.effector
    for o in spec.object_names:
        e = estimate.get(o)
        if e is None:
            continue
        out[f"pos_prev.{o}"] = e
        if spec.object_momentum:
            p = previous.get(o)
            out[f"vel_prev.{o}"] = np.zeros_like(e) if p is None else e - p
    return out


def _frame_evidence(
    model: WorldModel, o: str, q_prev: np.ndarray, q: np.ndarray, obs: Mapping[str, Any]
) -> dict[str, np.ndarray]:
    """The push frame's evidence of object ``o``: ``prel_prev.o``, ``prel.o`` ``(1, 3 P)`` and ``local.o``.

    The body's points before and after the step follow from the sensed ``q_prev`` and ``q`` by the
    model's fixed kinematics, relative to the previous estimate ``pos_prev.o``; ``local.o`` turns
    them and the effector's relations in ``obs`` into the push frame. All are functions of the
    evidence, computed as :func:`pal.agent.graph_frame.frame_columns` computes them for training,
    and enter as observed (a latent copy with its fixed sigma would only stiffen the inference).
    A world-frame model: none.
    """
    if f"local.{o}" not in model.graph:
        return {}
    cols = {"q_prev": np.asarray(q_prev)[None], "q": np.asarray(q)[None], **obs}
    computed = frame_columns(model, cols)
    wanted = [k for k in (f"prel_prev.{o}", f"prel.{o}", f"local.{o}") if k in model.graph]
    return {k: computed[k] for k in wanted}


class Estimator:
    """The state estimate per object (module docstring).

    Args:
        spec: the environment's spec.
        config: SVI settings.
        displacement: the model's displacement form (:attr:`pal.agent.config.ModelConfig.displacement`):
            with ``"gated"`` the touch is observed as the 0/1 switch ``touch > 0``, and without
            touch sensing the switch stays latent and is enumerated.

    Attributes:
        poor_posteriors: steps whose posterior failed its diagnostics (Pareto-k, guide mass).
            The agent filters every step with a small SVI budget, so these are counted and
            logged at DEBUG instead of raising a ``PoorPosteriorWarning`` per step.
        updates: steps filtered through the world model.
    """

    def __init__(self, spec: EnvSpec, config: EstimateConfig, displacement: str = "gated") -> None:
        self.spec, self.config = spec, config
        self.gated = check_choice("displacement", displacement, DISPLACEMENTS) == "gated"
        self.poor_posteriors = 0
        self.updates = 0
        self._blankets: dict[tuple[int, tuple[str, ...]], WorldModel] = {}

    def forget(self) -> None:
        """Drop the cached sub-models (after a refit or a revision)."""
        self._blankets.clear()

    def blanket(self, model: WorldModel, objects: tuple[str, ...]) -> WorldModel:
        """The cached :func:`pal.agent.graph.blanket` of ``model`` over ``objects``."""
        key = (id(model), objects)
        if key not in self._blankets:
            observed = self.spec.touch is not None or not self.gated
            self._blankets[key] = blanket(model, objects, observed_contact=observed)
        return self._blankets[key]

    def initial(self, percept: Percept) -> Estimate:
        """The first estimate of an episode: the measurements."""
        return {o: (None if m is None else m.position.copy()) for o, m in percept.measurements.items()}

    def update(
        self,
        model: WorldModel | None,
        prev: Percept,
        est_prev: Mapping[str, np.ndarray | None],
        vel_prev: Mapping[str, np.ndarray | None],
        new: Percept,
        seed: int,
    ) -> Estimate:
        """The estimate after the step ``prev -> new``.

        Args:
            model: the fitted world model, or None before the first fit (then the estimate
                is the measurement, or the previous estimate for an unseen object).
            prev: the percept before the step.
            est_prev: the estimate before it.
            vel_prev: object -> its displacement over the step before (momentum only).
            new: the percept after the step.
            seed: seeds the SVI.
        """
        meas = new.measurements
        out: Estimate = {o: (None if m is None else m.position.copy()) for o, m in meas.items()}
        perceived = self.spec.perceived
        if model is None:
            return {o: (out[o] if out[o] is not None or o not in perceived else est_prev.get(o)) for o in out}
        known = tuple(o for o in perceived if est_prev.get(o) is not None)
        if not known:  # nothing seen yet in this episode: the first measurement starts the estimate
            return out
        obs: dict[str, Any] = {}
        scales = {}
        for o in known:
            k = self.spec.object_names.index(o)
            p = np.asarray(est_prev[o], dtype=np.float64)
            obs[f"pos_prev.{o}"] = p[None]
            obs[f"rel_prev.{o}"] = relative(prev.effector[None], p[None])
            obs[f"rel.{o}"] = relative(new.effector[None], p[None])
            if self.spec.touch is not None:
                touch = float(new.touch[k] > 0) if self.gated else new.touch[k]
                obs[f"contact.{o}"] = np.array([[touch]])
            if self.spec.object_momentum:
                v = vel_prev.get(o)
                obs[f"vel_prev.{o}"] = (np.zeros_like(p) if v is None else np.asarray(v))[None]
            obs.update(_frame_evidence(model, o, prev.q, new.q, obs))
            m = meas[o]
            if m is not None:
                obs[f"meas.{o}"] = m.position[None]
                scales[f"meas.{o}"] = torch.as_tensor(m.std[None], dtype=model.dtype)
        c = self.config
        with warnings.catch_warnings(), pyro.validation_enabled(False):  # evidence checked above
            warnings.simplefilter("ignore", PoorPosteriorWarning)  # counted below instead
            program = self.blanket(model, known)
            post = infer_state(
                MeasurementScale(scales)(program) if scales else program,
                obs,
                num_steps=c.num_steps,
                num_samples=64,
                options=c.svi,
                guide=c.guide,
                seed=seed,
            )
        self.updates += 1
        if not post.diagnostics.ok:
            self.poor_posteriors += 1
            log.debug("estimate: %s", post.diagnostics.message)
        for o in known:
            out[o] = post.mean[f"pos.{o}"][0].numpy().astype(np.float64)
        return out
