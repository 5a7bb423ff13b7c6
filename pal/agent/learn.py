"""Learn: refit the world model on the history (Eq. 4.33), and revise it when its residuals persist (Eq. 4.50).

:func:`fit_model` trains the learned sites of :mod:`pal.agent.graph`: the arm's on every row,
each object's on the rows where both of its positions are known (NaN never reaches the fit), with
a validation split and early stopping; homoscedastic sigmas are floored at ``min_sigma``.

:class:`Learner` does that on a schedule and watches the model: after each refit an
:class:`inference.ResidualMonitor` takes the standardised residuals of the newest rows (the
reference scale of a site is its mean predictive sd on the training rows), and when it flags a
mechanism :func:`inference.revise` proposes and tests structural revisions on the recent rows
(a new parent, a regime split ...), keeping one only when it wins on held-out likelihood.
A gated displacement (``ModelConfig.displacement="gated"``) trains its on branch on the contact
rows only (:func:`inference.fit`); before the first contact row it stays unfitted, and while an
object has fewer than :data:`MIN_HELD_OUT_CONTACTS` contact rows its sites train on all of its
rows (no held-out share, no early stopping): a random hold-out could take every contact row.
:func:`inference.revise` scores homoscedastic single mechanisms; flagged heteroscedastic,
ensemble or discrete sites (a gated form's contact switch) are reported (``flagged``) but not revised.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from inference import ResidualMonitor, fit, revise
from models import DiscreteMechanism, GatedMechanism, WorldModel
from pal.agent.config import LearnConfig, ModelConfig
from pal.agent.graph import contact_rule, learned_sites
from pal.agent.graph_frame import frame_columns
from pal.agent.history import History
from pal.agent.rollout_fit import refine_objects
from pal.agent.spec import EnvSpec

__all__ = ["MIN_HELD_OUT_CONTACTS", "Learner", "fit_model", "site_data"]

log = logging.getLogger(__name__)

#: Contact rows an object needs before its gated sites hold out validation rows (module docstring).
MIN_HELD_OUT_CONTACTS = 10


def wrap_angle(x: np.ndarray) -> np.ndarray:
    """``x`` wrapped into [-pi, pi), rad (the step of an angle read from cos/sin)."""
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


def site_data(
    history: History,
    spec: EnvSpec,
    source: str = "perceived",
    rows: Any = None,
    config: ModelConfig | None = None,
    model: WorldModel | None = None,
) -> dict[str, np.ndarray]:
    """Every variable of the graph on the rows where every object is known (``meas.o = pos.o``).

    ``contact.o`` follows :func:`pal.agent.graph.contact_rule` of ``config`` (default: smooth).
    With ``model`` in the push frame, its columns follow :func:`pal.agent.graph_frame.frame_columns`.
    """
    rule, floor = contact_rule(spec, config or ModelConfig())
    idx = np.arange(len(history))[rows if rows is not None else slice(None)]
    prev_key, key = ("meas_prev", "meas") if source == "perceived" else ("truth_prev", "truth")
    prev, now = history.array(prev_key)[idx], history.array(key)[idx]
    ok = np.isfinite(prev).all((1, 2)) & np.isfinite(now).all((1, 2))
    if history.momentum:
        ok &= np.isfinite(history.array("vel_prev")[idx]).all((1, 2))
    arm, objects = history.columns(source, idx[ok], contact=rule, floor=floor)
    out = dict(arm)
    if spec.periodic:
        out["dq"] = wrap_angle(out["dq"])
    for o, cols in objects.items():
        out.update({k: v for k, v in cols.items() if k not in out})
        if o in spec.perceived:
            out[f"meas.{o}"] = cols[f"pos.{o}"]
        if rule == "strength" and spec.touch is None:
            out.pop(f"contact.{o}", None)
    return out if model is None else frame_columns(model, out)


def _on_rows(model: WorldModel, site: str, cols: dict[str, np.ndarray]) -> int | None:
    """The rows where a gated site's switch is on (None for other sites); 0 leaves its on branch as it is."""
    mech = model.mechanism(site)
    if not isinstance(mech, GatedMechanism):
        return None
    n = int((cols[mech.switch] == 1).sum())
    if n == 0:
        log.info("gated site %r: no row with %s = 1 yet; its on branch stays unfitted", site, mech.switch)
    return n


def fit_model(
    model: WorldModel,
    history: History,
    spec: EnvSpec,
    config: ModelConfig,
    *,
    source: str = "perceived",
    rows: Any = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Fit every learned site on the history (module docstring).

    With ``config.rollout.window`` > 0 the objects whose displacement was fitted are then
    refined through their own rollouts (:func:`pal.agent.rollout_fit.refine_objects`).

    Returns:
        ``{"rows": {"arm": n, <object>: n ...}, "sites": [...]}`` and, when refined,
        ``"rollout"``: the refinement's summary.
    """
    rule, floor = contact_rule(spec, config)
    arm, objects = history.columns(source, rows, contact=rule, floor=floor)
    if spec.periodic:  # angles from cos/sin: a step across +-pi is a small dq, not 2 pi
        for cols in (arm, *objects.values()):
            cols["dq"] = wrap_angle(cols["dq"])
    known = lambda cols: {k: v for k, v in cols.items() if k in model.graph}  # noqa: E731
    arm, objects = known(arm), {o: known(frame_columns(model, c)) for o, c in objects.items()}
    learned = [
        s
        for s in learned_sites(spec, config.displacement)
        if s in model.graph and model.mechanism(s).trainable
    ]
    base = config.schedule

    def schedule(n: int, contacts: int | None = None) -> dict[str, Any]:
        # too few rows (or contact rows) to hold any out: train on all of them, every epoch
        held_out = round(base.validation * n) >= 1 and (contacts is None or contacts >= MIN_HELD_OUT_CONTACTS)
        return {"schedule": base if held_out else replace(base, validation=0.0, patience=None), "seed": seed}

    arm_sites = [s for s in learned if s in ("dq", "v", "dee")]
    if arm_sites:  # none when the body's laws are all given (kinematics and dynamics from the MJCF)
        fit(model, arm, variables=arm_sites, **schedule(len(arm["act"])))
    fitted = list(arm_sites)
    for o, cols in objects.items():
        sites = [s for s in learned if s.endswith(f".{o}")]
        if len(cols[f"pos.{o}"]) < 4:
            log.warning(
                "object %r has %d usable transitions; its mechanisms stay unfitted", o, len(cols[f"pos.{o}"])
            )
            continue
        on_rows = {s: _on_rows(model, s, cols) for s in sites}
        sites = [s for s in sites if on_rows[s] != 0]
        contacts = min((n for n in on_rows.values() if n is not None), default=None)
        fit(model, cols, variables=sites, **schedule(len(cols[f"pos.{o}"]), contacts))
        fitted += sites
    for name in fitted:
        mech = model.mechanism(name)
        if not mech.heteroscedastic and not isinstance(mech, DiscreteMechanism):
            mech.set_sigma(mech.sigma.detach().clamp_min(config.min_sigma))
    out: dict[str, Any] = {
        "rows": {"arm": len(arm["act"]), **{o: len(c[f"pos.{o}"]) for o, c in objects.items()}},
        "sites": fitted,
    }
    if config.rollout.window:
        refined = [o for o in objects if f"dpos.{o}" in fitted]
        out["rollout"] = refine_objects(
            model,
            history,
            refined,
            config.rollout,
            contact=rule,
            floor=floor,
            source=source,
            rows=rows,
            seed=seed,
        )
    return out


def _revisable(mech: Any) -> bool:
    """True for the mechanisms :func:`inference.revise` scores: homoscedastic, single and continuous."""
    return not (mech.heteroscedastic or mech.size > 1 or isinstance(mech, DiscreteMechanism))


def _tolerance(model: WorldModel, data: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """Mean predictive sd of every non-root on ``data``: the monitor's reference scales."""
    values = {k: torch.as_tensor(v, dtype=model.dtype) for k, v in data.items()}
    with torch.no_grad():
        sd = model.predict_scale({r: values[r] for r in model.graph.roots})
    return {n: s.mean(0).clamp_min(1e-6) for n, s in sd.items()}


class Learner:
    """Scheduled refits and structural revisions (module docstring).

    Args:
        spec: the environment's spec.
        model: its settings (fit schedule).
        config: the refit period and the monitor.
    """

    def __init__(self, spec: EnvSpec, model: ModelConfig, config: LearnConfig) -> None:
        self.spec, self.model_config, self.config = spec, model, config
        self.monitor: ResidualMonitor | None = None
        self.revisions: list[dict[str, Any]] = []
        self._seen = 0

    def refit(self, model: WorldModel, history: History, seed: int) -> tuple[WorldModel, dict[str, Any]]:
        """Refit on the whole history, then let the monitor judge the newest rows; returns the (revised) model."""
        out = fit_model(model, history, self.spec, self.model_config, seed=seed)
        if not self.config.monitor or len(history) < 8:
            return model, out
        data = site_data(history, self.spec, config=self.model_config, model=model)
        if not data or len(next(iter(data.values()))) < 8:
            return model, out
        fresh = {k: v[-min(len(v), self.config.window) :] for k, v in data.items()}
        if self.monitor is None:
            self.monitor = ResidualMonitor(
                model,
                self.config.window,
                tolerance=_tolerance(model, data),
                threshold=self.config.threshold,
                patience=self.config.patience,
            )
        levels = self.monitor.update(model, fresh)
        out["residual_levels"] = levels
        learned = learned_sites(self.spec, self.model_config.displacement)
        flagged = [v for v in self.monitor.flagged() if v in learned and model.mechanism(v).trainable]
        out["flagged"] = flagged
        # inference.revise scores candidates with one sigma per site: homoscedastic, single, continuous ones
        flagged = [v for v in flagged if _revisable(model.mechanism(v))]
        if flagged and self.config.revisions:
            revised, log_ = revise(model, fresh, flagged, kinds=self.config.revisions, seed=seed)
            accepted = [r.to_dict() for r in log_ if r.accepted]
            self.revisions += accepted
            out["revisions"] = [r.to_dict() for r in log_]
            if accepted:
                log.info("revised %s: %s", flagged, accepted)
                model = revised
                self.monitor = None
        return model, out
