"""The shared protocol of experiments B1-B3 (thesis §5.2.1): data, split, the graphs, fit.

Protocol: 100 000 uniform-babbling transitions split 80:20 at random; for each graph
variant (``"thesis"``: Fig. 5.5, ``"state"``: with q_prev -> dq, ``"dynamics"``: also with
dq_prev -> dq) a world model with MLP mechanisms (2 x 32, tanh) trained with MSE for 120
epochs, batch 2048, lr 0.01 (Eq. 4.33). Beyond the thesis, 10 % of the training rows are
held out to estimate each sigma_i (not from training residuals), and the mechanisms may be
heteroscedastic (``X ~ Normal(f(pa), sigma(pa))``, beta-NLL) and ensembles of K members.
:func:`prepare` runs it once and hands B1, B2 and B3 the same data and models.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np
import torch

from inference import ActionOptions, CuriositySampler, FitResult, FitSchedule, ReplayNoise, fit, infer_action
from models import WorldModel
from models.presets import ALL_VARIANTS, GRAPH_VARIANTS, joint_chain_graph
from models.variables import Role
from pal.checks import check_choice, check_float, check_int
from pal.experiments.world_model.data import DataConfig, JointData, Realizer, babble_or_load
from pal.io.dataset import TransitionDataset

__all__ = [
    "ActionConfig",
    "FitConfig",
    "Prepared",
    "ProtocolConfig",
    "abs_errors",
    "build_model",
    "fit_model",
    "infer_actions",
    "predict_q",
    "prepare",
    "setup_note",
    "state_of",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FitConfig:
    """The mechanisms and their fit by :func:`inference.fit` (Eq. 4.33).

    Attributes:
        hidden: MLP hidden widths (tanh).
        kind: ``"mlp"`` (homoscedastic, MSE: the thesis) or ``"hetero"`` (each mechanism
            predicts its own scale sigma(pa), trained with beta-NLL).
        members: ensemble size K per site (1: no ensemble); each member sees its own
            bootstrap of the training rows, and their disagreement is the epistemic variance.
        schedule: the :func:`inference.fit` schedule, passed as it is (thesis: 120 epochs,
            batch 2048, lr 0.01). Its ``validation`` share of the training rows is held out to
            estimate sigma_i and, with ``patience``, to stop early; 0 is the thesis protocol
            (sigma from training residuals).
    """

    hidden: tuple[int, ...] = (32, 32)
    kind: str = "mlp"
    members: int = 1
    schedule: FitSchedule = FitSchedule()

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden", tuple(check_int("hidden", h) for h in self.hidden))
        check_choice("kind", self.kind, ("mlp", "hetero"))
        check_int("members", self.members)
        if not isinstance(self.schedule, FitSchedule):
            raise ValueError(f"schedule must be a FitSchedule, got {type(self.schedule).__name__}")
        if self.schedule.patience is not None and self.schedule.validation == 0:
            raise ValueError(
                "schedule.patience needs validation rows; give schedule.validation > 0 or schedule.patience=None"
            )

    def describe(self) -> str:
        """A phrase for reports."""
        mech = "heteroscedastic MLPs (beta-NLL)" if self.kind == "hetero" else "MLPs (MSE)"
        ens = f", ensembles of {self.members}" if self.members > 1 else ""
        validation = self.schedule.validation
        sigma = (
            f"sigma from {validation:.0%} held-out rows" if validation else "sigma from training residuals"
        )
        return f"{'x'.join(map(str, self.hidden))} tanh {mech}{ens}, {self.schedule.epochs} epochs, {sigma}"


@dataclass(frozen=True)
class ActionConfig:
    """Action inference: Alg. 4.2 (thesis §5.2.3: 200 Adam steps, lr 0.05), optionally after a sampling stage.

    Attributes:
        num_steps: Adam iterations.
        starts: 1 starts at the midpoint of X_a (the thesis protocol); k > 1 restarts from
            k points across X_a and keeps the best under the model.
        options: the options of :func:`inference.infer_action`, passed as they are except for
            ``init``, which ``starts`` makes (leave it ``"midpoint"``): ``lr`` is Adam's
            learning rate; ``sampling`` None is pure gradient descent (the thesis protocol), a
            :class:`inference.SamplingConfig` runs a CEM stage over X_a before Adam (the
            thesis's midpoint is a member of its first population).
    """

    num_steps: int = 200
    starts: int = 1
    options: ActionOptions = ActionOptions(lr=0.05)

    def __post_init__(self) -> None:
        check_int("num_steps", self.num_steps)
        check_int("starts", self.starts)
        if not isinstance(self.options, ActionOptions):
            raise ValueError(f"options must be an ActionOptions, got {type(self.options).__name__}")
        check_float("options.lr", self.options.lr, 0.0, open_low=True)
        if not (isinstance(self.options.init, str) and self.options.init == "midpoint"):
            raise ValueError("options.init is made from `starts`; leave it 'midpoint' and set starts")

    def describe(self) -> str:
        """A phrase for reports."""
        start = "the midpoint of X_a" if self.starts == 1 else f"{self.starts} points across X_a"
        s = self.options.sampling
        search = f"CEM ({s.population} x {s.iterations}, {s.elites} elites) then " if s is not None else ""
        return f"{search}Adam {self.num_steps} steps, lr {self.options.lr}, from {start}, clipped to X_a"


@dataclass(frozen=True)
class CuriosityDensity:
    """The curiosity target density of B3 and online exploration (thesis Eq. 5.8-5.9).

    Attributes:
        bins: histogram bins over the joint's range X_q (also the coverage bins), >= 2.
        alpha: locality amplification of Eq. 5.8, >= 0.
        sigma_fraction: locality width sigma as a fraction of |X_q|, > 0.
    """

    bins: int = 20
    alpha: float = 0.5
    sigma_fraction: float = 0.1

    def __post_init__(self) -> None:
        check_int("bins", self.bins, minimum=2)
        check_float("alpha", self.alpha, 0.0)
        check_float("sigma_fraction", self.sigma_fraction, 0.0, open_low=True)

    def sampler(self, low: float, high: float) -> CuriositySampler:
        """An unfitted :class:`inference.CuriositySampler` over ``[low, high]`` (rad)."""
        return CuriositySampler(
            low, high, bins=self.bins, alpha=self.alpha, sigma=self.sigma_fraction * (high - low)
        )


@dataclass(frozen=True)
class ProtocolConfig:
    """Data and training protocol shared by B1-B3 (defaults: thesis §5.2.1).

    Attributes:
        data: the babbling dataset.
        graphs: graph variants to fit, from ``("thesis", "state", "dynamics", "velocity")``
            (default the first three; ``"velocity"`` needs the recorded joint velocities).
        split: training share of the random split.
        fit: the fitting schedule.
    """

    data: DataConfig = DataConfig()
    graphs: tuple[str, ...] = GRAPH_VARIANTS
    split: float = 0.8
    fit: FitConfig = FitConfig()

    def __post_init__(self) -> None:
        graphs = (self.graphs,) if isinstance(self.graphs, str) else tuple(self.graphs)
        unknown = [g for g in graphs if g not in ALL_VARIANTS]
        if unknown or not graphs or len(set(graphs)) != len(graphs):
            raise ValueError(
                f"graphs {list(graphs)!r} invalid; expected distinct names from {list(ALL_VARIANTS)}"
            )
        object.__setattr__(self, "graphs", graphs)
        check_float("split", self.split, 0.0, 1.0, open_low=True, open_high=True)


@dataclass
class Prepared:
    """Data and fitted models of one protocol run.

    Attributes:
        config: the protocol.
        dataset: all transitions; ``train`` and ``test`` are its random split.
        joint: the analysed joint and its actuator.
        q_range: observed range X_q of q.J in the training data, rad.
        models: graph variant -> fitted :class:`WorldModel`.
        fits: graph variant -> :class:`FitResult` (loss curves).
        seconds: wall time of ``data`` and ``fit_<graph>``.
    """

    config: ProtocolConfig
    seed: int
    dataset: TransitionDataset
    train: TransitionDataset
    test: TransitionDataset
    joint: JointData
    q_range: tuple[float, float]
    models: dict[str, WorldModel] = field(default_factory=dict)
    fits: dict[str, FitResult] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)

    @cached_property
    def test_columns(self) -> dict[str, np.ndarray]:
        """The analysed joint's test columns, name -> ``(N_test, 1)`` float32."""
        return self.joint.columns(self.test)

    @cached_property
    def realizer(self) -> Realizer:
        """Replays test transitions in the simulator (rows index :attr:`test`)."""
        return Realizer(self.test, self.joint, self.config.data.body.source)

    def info(self) -> dict[str, object]:
        """Facts for reports: body, joint, actuator, sizes, ranges, seconds."""
        return {
            "body": self.dataset.metadata.get("body"),
            "joint": self.joint.joint,
            "actuator": self.joint.actuator,
            "babbling_actuators": len(self.dataset.actuators),
            "n_train": len(self.train),
            "n_test": len(self.test),
            "action_range": list(self.joint.action_range),
            "q_range": list(self.q_range),
            "seconds": dict(self.seconds),
        }


def build_model(
    joint: JointData,
    variant: str,
    q_range: tuple[float, float],
    seed: int,
    fit: FitConfig = FitConfig(),
) -> WorldModel:
    """An unfitted world model over the analysed joint; tanh MLP weights drawn from ``seed``."""
    graph = joint_chain_graph(
        [joint.joint], {joint.joint: joint.action_range}, variant=variant, q_ranges={joint.joint: q_range}
    )
    return WorldModel(
        graph, kind=fit.kind, members=fit.members, hidden=fit.hidden, activation="tanh", seed=seed
    )


def fit_model(
    model: WorldModel,
    data: Mapping[str, np.ndarray],
    config: FitConfig,
    seed: int,
    progress_bar: bool = False,
) -> FitResult:
    """Fit ``model`` on the columns of its graph in ``data`` with the schedule of ``config``."""
    return fit(
        model,
        {k: v for k, v in data.items() if k in model.graph},
        loss="mse" if config.kind == "mlp" else "beta_nll",
        schedule=config.schedule,
        seed=seed,
        progress_bar=progress_bar,
    )


_LAST: dict[tuple[ProtocolConfig, int], Prepared] = {}


def prepare(config: ProtocolConfig, seed: int, progress_bar: bool = False) -> Prepared:
    """Babble (or load) the data, split it and fit one world model per graph variant.

    The last result is kept in memory, so that B1, B2 and B3 run one after another on the
    same protocol and seed (``pal demo``) share one dataset and one fit. B1-B3 only read
    the models (state and action inference hold their parameters fixed).
    """
    key = (config, seed)
    if key in _LAST:
        return _LAST[key]
    start = time.perf_counter()
    dataset = babble_or_load(config.data, seed, progress_bar=progress_bar)
    joint = JointData.select(dataset, config.data.body.joint)
    train, test = dataset.split(config.split, seed=seed)
    prep = Prepared(config, seed, dataset, train, test, joint, joint.q_range(train))
    prep.seconds["data"] = time.perf_counter() - start
    data = joint.columns(train)
    for variant in config.graphs:
        start = time.perf_counter()
        model = build_model(joint, variant, prep.q_range, seed, config.fit)
        prep.fits[variant] = fit_model(model, data, config.fit, seed, progress_bar)
        prep.models[variant] = model
        prep.seconds[f"fit_{variant}"] = time.perf_counter() - start
        log.info("fitted the %s graph in %.1f s", variant, prep.seconds[f"fit_{variant}"])
    _LAST.clear()
    _LAST[key] = prep
    return prep


def abs_errors(pred: np.ndarray | torch.Tensor, target: np.ndarray | torch.Tensor) -> np.ndarray:
    """``|pred - target|`` as a flat float64 array (inputs ``(n,)`` or ``(n, 1)``)."""
    p = pred.detach().numpy() if isinstance(pred, torch.Tensor) else np.asarray(pred)
    t = target.detach().numpy() if isinstance(target, torch.Tensor) else np.asarray(target)
    p, t = p.astype(np.float64).reshape(-1), t.astype(np.float64).reshape(-1)
    if p.shape != t.shape:
        raise ValueError(f"prediction has {p.size} entries, target {t.size}")
    return np.abs(p - t)


def state_of(
    model: WorldModel, columns: Mapping[str, np.ndarray], rows: Any = slice(None)
) -> dict[str, np.ndarray]:
    """The model's non-action roots (q_prev.J, and dq_prev.J in the dynamics graph) from ``columns``.

    Args:
        model: a fitted joint-chain world model.
        columns: name -> ``(N, 1)`` columns (:meth:`JointData.columns`).
        rows: the rows to take (indices, a mask or a slice).

    Returns:
        name -> ``(n, 1)`` float32, rad.
    """
    graph = model.graph
    names = [r for r in graph.roots if graph[r].role is not Role.ACTION]
    missing = [r for r in names if r not in columns]
    if missing:
        raise ValueError(
            f"the data have no column(s) {missing} for the roots of the {list(graph.roots)} graph"
        )
    return {r: np.asarray(columns[r][rows], np.float32).reshape(-1, 1) for r in names}


def _tensors(values: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(np.asarray(v, np.float32).reshape(-1, 1)) for k, v in values.items()}


def predict_q(
    model: WorldModel, joint: JointData, state: Mapping[str, np.ndarray], actions: np.ndarray
) -> np.ndarray:
    """Model-predicted post-action angle Phi(s, a) (Eq. 5.7) with expected residuals.

    Args:
        model: the fitted world model.
        joint: the joint whose variables are predicted.
        state: the model's non-action roots (:func:`state_of`), each ``(n,)`` or ``(n, 1)``, rad.
        actions: ``(n,)`` or ``(n, 1)`` commands, dimensionless.

    Returns:
        ``(n,)`` float64 predicted q.J, rad.
    """
    act, _, _, q = joint.names
    values = _tensors({**state, act: actions})
    return model.predict(values)[q].numpy().astype(np.float64).reshape(-1)


def infer_actions(
    model: WorldModel,
    joint: JointData,
    state: Mapping[str, np.ndarray],
    targets: np.ndarray,
    action: ActionConfig,
    rng: np.random.Generator | None = None,
    seed: int = 0,
    noise: Mapping[str, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, tuple[float, ...]]:
    """Alg. 4.2 for each (state, target) pair: the action whose predicted q.J is the target.

    The loss is ``0.5 (Phi(s, a) - target)^2`` per pair (the thesis's MSE objective),
    minimised by projected Adam clipped to X_a, after an optional CEM sampling stage
    (``action.options.sampling``). With ``action.starts = 1`` Adam starts from the midpoint of
    X_a (thesis §5.2.3). With ``starts = k > 1`` it starts from the k interior points of
    ``linspace(low, high, k + 2)`` (the midpoint among them when k is odd), all in one
    batch, and keeps per pair the action with the lowest final loss under the model. With
    ``rng`` the k starts of every pair are drawn uniformly from X_a instead, so that where
    the model predicts no effect of the action (a flat loss) the chosen action stays random
    rather than fixed.

    Args:
        model: the fitted world model.
        joint: the analysed joint.
        state: the model's non-action roots (:func:`state_of`), each ``(n,)`` or ``(n, 1)``, rad.
        targets: ``(n,)`` target angles q.J, rad.
        action: the inference settings.
        rng: draw the starts uniformly from X_a with this generator.
        seed: seeds the sampling stage.
        noise: optional site -> ``(n,)`` or ``(n, 1)`` standardised residuals replayed in the
            prediction (abducted ones: the two-step protocol of B2); needs ``options.sampling``.

    Returns:
        ``(actions (n,), predicted q (n,), mean loss per Adam step)``; the loss curve is
        averaged over all pairs and starts.
    """
    starts = action.starts
    act, _, _, q = joint.names
    given = _tensors(state)
    tg = torch.as_tensor(np.asarray(targets, np.float32).reshape(-1, 1))
    n = len(tg)
    low, high = joint.action_range
    if rng is not None:
        init: str | dict[str, np.ndarray] = {
            act: rng.uniform(low, high, size=(starts * n, 1)).astype(np.float32)
        }
    elif starts == 1:
        init = "midpoint"
    else:
        init = {act: np.repeat(np.linspace(low, high, starts + 2)[1:-1], n)[:, None].astype(np.float32)}
    program = model
    if noise:  # abducted residuals replayed in the prediction (ReplayNoise, through the torch twin)
        eps = {
            k: torch.as_tensor(np.asarray(v, np.float32).reshape(n, -1)).repeat(starts, 1)
            for k, v in noise.items()
        }
        program = ReplayNoise(eps, default="expected")(model)
    res = infer_action(
        program,
        {k: v.repeat(starts, 1) for k, v in given.items()},
        {q: tg.repeat(starts, 1)},
        actions=[act],
        num_steps=action.num_steps,
        options=replace(action.options, init=init),
        seed=seed,
    )
    best = res.final_loss.numpy().reshape(starts, n).argmin(0) * n + np.arange(n)
    return (
        res.actions[act].numpy().astype(np.float64).reshape(-1)[best],
        res.predicted[q].numpy().astype(np.float64).reshape(-1)[best],
        res.loss,
    )


def setup_note(info: dict[str, Any]) -> str:
    """One sentence describing the run from :meth:`Prepared.info`."""
    return (
        f"Body {info['body']}, joint {info['joint']} (action: actuator {info['actuator']}, "
        f"{info['babbling_actuators']} actuator(s) babbling), {info['n_train']} training / {info['n_test']} "
        f"test transitions, X_a = [{info['action_range'][0]:.3f}, {info['action_range'][1]:.3f}], "
        f"X_q = [{info['q_range'][0]:.3f}, {info['q_range'][1]:.3f}] rad."
    )
