"""Bad input to the public API of ``inference`` raises a specific error naming the value.

Every entry of :data:`CASES` is one bad call (:class:`tests.bad_input.BadInput`): the exact
exception type it must raise and a substring of the message that names the offending value or
parameter. The shared builders and checks are in ``tests/bad_input.py``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch

from inference import (
    ActionOptions,
    CalibrationOptions,
    CuriositySampler,
    DiscoveryOptions,
    DiscoveryResult,
    Ensemble,
    FitSchedule,
    GridOptions,
    ImportanceOptions,
    Intervene,
    MeasurementScale,
    Program,
    ReplayNoise,
    ResidualMonitor,
    SVIOptions,
    abduct,
    active_subgraph,
    admissible_parents,
    counterfactual,
    discover,
    do,
    fit,
    gaussian_log_preference,
    infer_action,
    infer_state,
    normalized_entropy,
    occupancy,
    predictive_check,
    revise,
    rewire,
    shd,
    simulate,
    subgraph_model,
)
from inference.context import target_relevance
from inference.design import choose_interventions, structure_uncertainty
from inference.metalearn import SplitMechanism
from models import (
    CausalGraph,
    FunctionMechanism,
    LinearMechanism,
    Role,
    Variable,
    WorldModel,
    chain_graph,
    finger_graph,
)
from tests.bad_input import (
    FACTUAL,
    FIN,
    FSTATE,
    HALF,
    INF,
    NAN,
    BadInput,
    bad,
    bin_data,
    binary,
    chain,
    check,
    duplicate_ids,
    finger,
    raw_errors,
    scalars,
    xy_graph,
)


def plant() -> WorldModel:
    """q = q_prev + tanh(2 a), a in [-1, 1]."""
    g = CausalGraph(
        [
            Variable("a", "action", bounds=(-1.0, 1.0)),
            Variable("q_prev", "observed", lag=1, lag_of="q"),
            Variable("q", "latent"),
        ],
        [("a", "q"), ("q_prev", "q")],
    )
    mech = FunctionMechanism(lambda z: z[..., 1:2] + torch.tanh(2 * z[..., 0:1]), 2, 1, sigma=0.1)
    return WorldModel(g, {"q": mech})


def member(slope: float = 1.0) -> WorldModel:
    g = CausalGraph([Variable("a", Role.ACTION, bounds=(-1, 1)), Variable("y", Role.LATENT)], [("a", "y")])
    return WorldModel(g, {"y": LinearMechanism.from_coefficients([[slope]], sigma=0.5)})


def ensemble() -> Ensemble:
    return Ensemble([member(1.0), member(2.0)])


def finger_data(n: int = 16) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    a = -1.0 + 1.33 * torch.rand(n, 1, generator=gen)
    q_prev = torch.rand(n, 1, generator=gen) - 1.0
    dq = 0.5 * a - 0.2 * q_prev
    return {"act.finger": a, "q_prev.finger": q_prev, "dq.finger": dq, "q.finger": q_prev + dq}


def xy(n: int = 10, **cols: Any) -> dict[str, Any]:
    return {"x": np.zeros((n, 1)), "y": np.zeros((n, 1)), **cols}


def xy_model() -> WorldModel:
    return WorldModel(xy_graph(), seed=0, hidden=(4,))


def discovery_data(n: int = 40, **cols: Any) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    return {"x": rng.normal(size=(n, 1)), "y": rng.normal(size=(n, 1)), **cols}


def posterior():
    return infer_state(chain(), {"z": torch.tensor([[-3.0]])}, num_steps=2, num_samples=4)


def exact_cf():
    return counterfactual(chain(), FACTUAL, {"x": 0.0})


def fake_discovery() -> DiscoveryResult:
    g = chain_graph()
    return DiscoveryResult(g, {}, g.names, (), 0.0, 0, 0.0)


def finger_samples() -> tuple[WorldModel, dict[str, torch.Tensor]]:
    model = finger()
    return model, model.sample(8, torch.Generator().manual_seed(0))


def cut(mask: Any) -> dict[str, Any]:
    return {"dq.finger": mask}


Z = {"z": torch.tensor([[-3.0]])}
Q0 = {"q_prev": torch.zeros(2, 1)}
QT = {"q": torch.zeros(2, 1)}
THREE = np.full((4, 1), 3.0)


CASES: list[BadInput] = [
    # handlers
    bad(
        "inference.handlers",
        "Intervene list",
        lambda: Intervene([("x", 1.0)]),
        "interventions must be a mapping",
    ),
    bad(
        "inference.handlers", "ReplayNoise str", lambda: ReplayNoise({"y": "a"}), "noise['y'] is not numeric"
    ),
    bad(
        "inference.handlers",
        "ReplayNoise nan",
        lambda: ReplayNoise({"y": torch.tensor([[NAN]])}),
        "noise['y'] contains 1 NaN",
    ),
    bad(
        "inference.handlers",
        "ReplayNoise default",
        lambda: ReplayNoise(default="mean"),
        "default 'mean' unknown",
    ),
    bad(
        "inference.handlers",
        "ReplayNoise shape",
        lambda: ReplayNoise({"y": torch.zeros(2, 1)}, default="expected")(chain())(None, 3),
        "replayed noise for 'y' has shape (2, 1)",
    ),
    bad(
        "inference.handlers",
        "MeasurementScale zero",
        lambda: MeasurementScale({"z": np.array([0.0])}),
        "finite and > 0",
    ),
    bad(
        "inference.handlers",
        "MeasurementScale 3-d",
        lambda: MeasurementScale({"z": torch.ones(1, 1, 1)}),
        "has shape (1, 1, 1), expected (dim,) or (N, dim)",
    ),
    bad(
        "inference.handlers",
        "MeasurementScale list",
        lambda: MeasurementScale([1]),
        "scales must be a mapping",
    ),
    # do, simulate
    bad(
        "inference.do",
        "unknown target",
        lambda: do(chain(), {"nope": 1.0}),
        "unknown intervention target 'nope'",
    ),
    bad(
        "inference.do",
        "inf value",
        lambda: do(chain(), {"x": INF}),
        "intervention on 'x' contains NaN or inf",
    ),
    bad(
        "inference.do",
        "wrong dim",
        lambda: do(chain(), {"x": [1.0, 2.0]}),
        "intervention on 'x' has shape (2,)",
    ),
    bad("inference.do", "str value", lambda: do(chain(), {"x": "abc"}), "intervention on 'x' is not numeric"),
    bad(
        "inference.do", "bool value", lambda: do(chain(), {"x": True}), "intervention on 'x' is the bool True"
    ),
    bad(
        "inference.do",
        "int array",
        lambda: do(chain(), {"x": np.array([1])}),
        "intervention on 'x' has dtype int64",
    ),
    bad(
        "inference.do",
        "interventions a list",
        lambda: do(chain(), [("x", 1.0)]),
        "interventions must be a mapping",
    ),
    bad("inference.do", "model a str", lambda: do("model", {}), "model must be callable"),
    bad(
        "inference.do",
        "action out of bounds",
        lambda: do(finger(), {"act.finger": 2.0}),
        "interventions['act.finger'] has 1 entries outside the action bounds [-1, 0.33] (first: 2",
    ),
    bad(
        "inference.do",
        "shift leaves the bounds",
        lambda: do(finger(), {"act.finger": lambda a: a + 5.0})(None, 2),
        "shift intervention on 'act.finger' produced values outside its bounds",
    ),
    bad(
        "inference.do",
        "shift gives nan",
        lambda: do(chain(), {"x": lambda v: v * NAN})(None, 2),
        "shift intervention on 'x' produced NaN or inf",
    ),
    bad(
        "inference.do",
        "rows at run time",
        lambda: do(chain(), {"x": torch.zeros(2, 1)})(None, 3),
        "has shape (2, 1)",
    ),
    bad("inference.simulate", "n 0", lambda: simulate(chain(), 0), "n must be a positive int, got 0"),
    bad("inference.simulate", "n str", lambda: simulate(chain(), "5"), "n must be a positive int, got '5'"),
    bad(
        "inference.simulate",
        "seed negative",
        lambda: simulate(chain(), 5, seed=-1),
        "seed must be a non-negative int",
    ),
    bad(
        "inference.simulate",
        "seed float",
        lambda: simulate(chain(), 5, seed=1.5),
        "seed must be a non-negative int, got 1.5",
    ),
    bad(
        "inference.simulate",
        "interventions a list",
        lambda: simulate(chain(), 5, [1]),
        "interventions must be a mapping",
    ),
    # fit
    bad(
        "inference.fit", "model a str", lambda: fit("model", xy()), "model must be a WorldModel, got 'model'"
    ),
    bad("inference.fit", "data a list", lambda: fit(xy_model(), [1, 2]), "data must be a mapping"),
    bad("inference.fit", "data empty", lambda: fit(xy_model(), {}), "data is empty"),
    bad("inference.fit", "one row", lambda: fit(xy_model(), xy(1)), "at least 2 rows of data, got 1"),
    bad(
        "inference.fit",
        "unknown column",
        lambda: fit(xy_model(), xy(w=np.zeros((10, 1)))),
        "unknown variable in data 'w'",
    ),
    bad(
        "inference.fit",
        "int column",
        lambda: fit(xy_model(), xy(x=np.zeros((10, 1), int))),
        "data['x'] has dtype int64",
    ),
    bad(
        "inference.fit",
        "bool column",
        lambda: fit(xy_model(), xy(y=np.zeros((10, 1), bool))),
        "data['y'] has dtype bool",
    ),
    bad(
        "inference.fit", "str column", lambda: fit(xy_model(), xy(x=[["a"]] * 10)), "data['x'] is not numeric"
    ),
    bad(
        "inference.fit",
        "1-d column",
        lambda: fit(xy_model(), xy(x=np.zeros(10))),
        "data['x'] has shape (10,)",
    ),
    bad(
        "inference.fit",
        "rows differ",
        lambda: fit(xy_model(), xy(y=np.zeros((9, 1)))),
        "data['y'] has 9 rows, expected 10",
    ),
    bad(
        "inference.fit",
        "nan",
        lambda: fit(xy_model(), xy(y=np.full((10, 1), NAN))),
        "data['y'] contains 10 NaN",
    ),
    bad("inference.fit", "unknown loss", lambda: fit(xy_model(), xy(), loss="l1"), "loss 'l1' unknown"),
    bad(
        "inference.fit",
        "epochs str",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(epochs="10")),
        "epochs must be a positive int, got '10'",
    ),
    bad(
        "inference.fit",
        "epochs 0",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(epochs=0)),
        "epochs must be a positive int, got 0",
    ),
    bad(
        "inference.fit",
        "epochs float",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(epochs=2.0)),
        "epochs must be a positive int, got 2.0",
    ),
    bad(
        "inference.fit",
        "batch_size bool",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(batch_size=True)),
        "batch_size must be a positive int",
    ),
    bad(
        "inference.fit",
        "lr bool",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(lr=True)),
        "lr must be > 0 (a finite number), got True",
    ),
    bad(
        "inference.fit",
        "lr 0",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(lr=0)),
        "lr must be > 0 (a finite number), got 0",
    ),
    bad(
        "inference.fit",
        "lr inf",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(lr=INF)),
        "lr must be > 0 (a finite number), got inf",
    ),
    bad(
        "inference.fit",
        "lr str",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(lr="0.1")),
        "lr must be > 0 (a finite number), got '0.1'",
    ),
    bad(
        "inference.fit",
        "validation 1",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(validation=1.0)),
        "validation must be >= 0 and < 1 (a finite number), got 1",
    ),
    bad(
        "inference.fit",
        "validation negative",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(validation=-0.2)),
        "validation must be >= 0 and < 1 (a finite number), got -0.2",
    ),
    bad(
        "inference.fit",
        "validation nan",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(validation=NAN)),
        "validation must be",
    ),
    bad(
        "inference.fit",
        "validation leaves no rows",
        lambda: fit(xy_model(), xy(2), schedule=FitSchedule(validation=0.9)),
        "validation=0.9 of 2 rows leaves no training rows",
    ),
    bad(
        "inference.fit",
        "beta above 1",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(beta=1.5)),
        "beta must be >= 0 and <= 1",
    ),
    bad(
        "inference.fit",
        "beta negative",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(beta=-0.5)),
        "got -0.5",
    ),
    bad(
        "inference.fit",
        "beta str",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(beta="0.5")),
        "beta must be >= 0 and <= 1",
    ),
    bad(
        "inference.fit",
        "patience 0",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(patience=0)),
        "patience must be a positive int, got 0",
    ),
    bad(
        "inference.fit",
        "patience float",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(patience=2.0)),
        "patience must be a positive int",
    ),
    bad(
        "inference.fit",
        "patience without validation",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(patience=2, validation=0.0)),
        "patience=2 needs validation rows",
    ),
    bad(
        "inference.fit",
        "bootstrap str",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(bootstrap="yes")),
        "bootstrap must be True or False",
    ),
    bad(
        "inference.fit",
        "calibration not options",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(calibration="conformal")),
        "calibration must be a CalibrationOptions, got 'conformal' (str)",
    ),
    bad(
        "inference.fit",
        "calibration rule",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(calibration=CalibrationOptions(rule="quantile"))),
        "calibration rule 'quantile' unknown; expected one of ['variance', 'conformal']",
    ),
    bad(
        "inference.fit",
        "calibration level 1",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(calibration=CalibrationOptions(level=1.0))),
        "calibration level must be > 0 and < 1 (a finite number), got 1",
    ),
    bad(
        "inference.fit",
        "calibration level 0",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(calibration=CalibrationOptions(level=0))),
        "calibration level must be > 0 and < 1 (a finite number), got 0",
    ),
    bad(
        "inference.fit",
        "calibration level nan",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(calibration=CalibrationOptions(level=NAN))),
        "calibration level must be > 0 and < 1 (a finite number), got nan",
    ),
    bad(
        "inference.fit",
        "calibration folds 1",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(calibration=CalibrationOptions(folds=1))),
        "calibration folds must be an int >= 2, got 1",
    ),
    bad(
        "inference.fit",
        "calibration folds float",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(calibration=CalibrationOptions(folds=5.0))),
        "calibration folds must be an int >= 2, got 5.0 (float)",
    ),
    bad(
        "inference.fit",
        "loss beta-nll",
        lambda: fit(xy_model(), xy(), loss="beta-nll"),
        "loss 'beta-nll' unknown",
    ),
    bad(
        "inference.fit",
        "mse for a heteroscedastic mechanism",
        lambda: fit(WorldModel(xy_graph(), seed=0, kind="hetero", hidden=(2,)), xy(), loss="mse"),
        "loss='mse' cannot train the scale of the heteroscedastic mechanisms of ['y']",
    ),
    bad(
        "inference.fit",
        "only fixed functions",
        lambda: fit(WorldModel(xy_graph(), {"y": FunctionMechanism(torch.sin, 1)}), xy()),
        "the mechanisms of ['y'] are fixed functions, which fit does not train",
    ),
    bad(
        "inference.fit",
        "a fixed function requested",
        lambda: fit(WorldModel(xy_graph(), {"y": FunctionMechanism(torch.sin, 1)}), xy(), variables=["y"]),
        "cannot fit 'y': its mechanism is a fixed FunctionMechanism",
    ),
    bad(
        "inference.fit",
        "seed str",
        lambda: fit(xy_model(), xy(), seed="1"),
        "seed must be a non-negative int, got '1'",
    ),
    bad(
        "inference.fit",
        "progress_bar str",
        lambda: fit(xy_model(), xy(), progress_bar="no"),
        "progress_bar must be True or False",
    ),
    bad(
        "inference.fit",
        "variables a str",
        lambda: fit(xy_model(), xy(), variables="y"),
        "variables must be a sequence of names",
    ),
    bad("inference.fit", "variables a root", lambda: fit(xy_model(), xy(), variables=["x"]), "'x' is a root"),
    bad(
        "inference.fit",
        "variables unknown",
        lambda: fit(xy_model(), xy(), variables=["w"]),
        "unknown variable to fit 'w'",
    ),
    bad(
        "inference.fit",
        "variables repeated",
        lambda: fit(xy_model(), xy(), variables=["y", "y"]),
        "names ['y'] more than once",
    ),
    bad(
        "inference.fit", "variables empty", lambda: fit(xy_model(), xy(), variables=[]), "variables is empty"
    ),
    bad(
        "inference.fit",
        "nothing trainable",
        lambda: fit(xy_model(), {"x": np.zeros((10, 1))}),
        "no mechanism can be trained",
    ),
    # predictive_check
    bad(
        "inference.calibration",
        "model a str",
        lambda: predictive_check("m", xy()),
        "model must be a WorldModel",
    ),
    bad(
        "inference.calibration",
        "level 1",
        lambda: predictive_check(xy_model(), xy(), level=1.0),
        "level must be > 0 and < 1",
    ),
    bad(
        "inference.calibration",
        "level str",
        lambda: predictive_check(xy_model(), xy(), level="0.9"),
        "got '0.9'",
    ),
    bad(
        "inference.calibration",
        "levels with 0",
        lambda: predictive_check(xy_model(), xy(), levels=[0.5, 0.0]),
        "levels[1] must be > 0 and < 1",
    ),
    bad(
        "inference.calibration",
        "levels empty",
        lambda: predictive_check(xy_model(), xy(), levels=()),
        "levels must be a non-empty",
    ),
    bad(
        "inference.calibration",
        "site a root",
        lambda: predictive_check(xy_model(), xy(), sites=["x"]),
        "site 'x' is a root",
    ),
    bad(
        "inference.calibration",
        "site without parents' column",
        lambda: predictive_check(xy_model(), {"y": np.zeros((3, 1))}, sites=["y"]),
        "cannot check site 'y': data has no column for ['x']",
    ),
    bad("inference.calibration", "no columns", lambda: predictive_check(xy_model(), {}), "data is empty"),
    # infer_state
    bad(
        "inference.infer_state",
        "model a str",
        lambda: infer_state("m", Z),
        "model must be a WorldModel or a program",
    ),
    bad(
        "inference.infer_state",
        "model without graph",
        lambda: infer_state(print, Z),
        "model must be a WorldModel",
    ),
    bad("inference.infer_state", "observed empty", lambda: infer_state(chain(), {}), "observed is empty"),
    bad(
        "inference.infer_state",
        "observed int",
        lambda: infer_state(chain(), {"z": np.array([[1]])}),
        "observed['z'] has dtype int64",
    ),
    bad(
        "inference.infer_state",
        "unknown guide",
        lambda: infer_state(chain(), Z, guide="flows"),
        "guide 'flows' unknown",
    ),
    bad(
        "inference.infer_state",
        "num_steps 0",
        lambda: infer_state(chain(), Z, num_steps=0),
        "num_steps must be a positive int",
    ),
    bad(
        "inference.infer_state",
        "num_steps float",
        lambda: infer_state(chain(), Z, num_steps=10.0),
        "num_steps must be a positive int",
    ),
    bad(
        "inference.infer_state",
        "num_particles bool",
        lambda: infer_state(chain(), Z, options=SVIOptions(num_particles=True)),
        "num_particles must be",
    ),
    bad(
        "inference.infer_state",
        "num_samples str",
        lambda: infer_state(chain(), Z, num_samples="9"),
        "num_samples must be",
    ),
    bad(
        "inference.infer_state",
        "lr negative",
        lambda: infer_state(chain(), Z, options=SVIOptions(lr=-1.0)),
        "lr must be > 0",
    ),
    bad(
        "inference.infer_state",
        "lr_final 0",
        lambda: infer_state(chain(), Z, options=SVIOptions(lr_final=0)),
        "lr_final must be > 0",
    ),
    bad(
        "inference.infer_state",
        "init_scale nan",
        lambda: infer_state(chain(), Z, options=SVIOptions(init_scale=NAN)),
        "init_scale must be > 0",
    ),
    bad(
        "inference.infer_state",
        "seed negative",
        lambda: infer_state(chain(), Z, seed=-1),
        "seed must be a non-negative int",
    ),
    bad(
        "inference.infer_state",
        "progress_bar int",
        lambda: infer_state(chain(), Z, progress_bar=1),
        "progress_bar must be True",
    ),
    bad(
        "inference.infer_state",
        "observed and intervened",
        lambda: infer_state(do(chain(), {"z": 1.0}), Z),
        "variables ['z'] are both observed and intervened on",
    ),
    bad(
        "inference.infer_state",
        "action out of bounds",
        lambda: infer_state(finger(), {"act.finger": torch.full((1, 1), 0.5), "q.finger": torch.zeros(1, 1)}),
        "observed['act.finger'] has 1 entries outside the action bounds",
    ),
    bad(
        "inference.infer_state",
        "nothing latent",
        lambda: infer_state(chain(), FACTUAL),
        "there is no latent site",
    ),
    bad(
        "inference.infer_state",
        "interval unknown",
        lambda: posterior().interval("w"),
        "'w' is not a latent site",
    ),
    bad(
        "inference.infer_state",
        "interval level",
        lambda: posterior().interval("y", level=1.5),
        "level must be > 0 and < 1",
    ),
    # counterfactual, abduct
    bad(
        "inference.counterfactual",
        "model a str",
        lambda: counterfactual("m", FACTUAL, {}),
        "model must be a WorldModel",
    ),
    bad(
        "inference.counterfactual",
        "interventions a str",
        lambda: counterfactual(chain(), FACTUAL, "x"),
        "interventions must be a mapping (one scenario) or a list of mappings, got 'x'",
    ),
    bad(
        "inference.counterfactual",
        "no scenario",
        lambda: counterfactual(chain(), FACTUAL, []),
        "empty sequence",
    ),
    bad(
        "inference.counterfactual",
        "scenario an int",
        lambda: counterfactual(chain(), FACTUAL, [{"x": 0.0}, 5]),
        "scenario 1 must be a mapping",
    ),
    bad(
        "inference.counterfactual",
        "unknown target",
        lambda: counterfactual(chain(), FACTUAL, {"w": 0.0}),
        "unknown intervention target 'w'",
    ),
    bad(
        "inference.counterfactual",
        "nan scenario",
        lambda: counterfactual(chain(), FACTUAL, {"x": NAN}),
        "intervention on 'x' contains NaN",
    ),
    bad(
        "inference.counterfactual",
        "factual empty",
        lambda: counterfactual(chain(), {}, {"x": 0.0}),
        "factual evidence is empty",
    ),
    bad(
        "inference.counterfactual",
        "factual shape",
        lambda: counterfactual(chain(), {"x": torch.ones(1)}, {"x": 0.0}),
        "factual['x'] has shape (1,)",
    ),
    bad(
        "inference.counterfactual",
        "scenario rows",
        lambda: counterfactual(chain(), FACTUAL, {"x": torch.zeros(2, 1)}),
        "intervention on 'x' has 2 rows, expected 1",
    ),
    bad(
        "inference.counterfactual",
        "num_samples 0",
        lambda: counterfactual(chain(), FACTUAL, {}, num_samples=0),
        "num_samples must be",
    ),
    bad(
        "inference.counterfactual",
        "seed str",
        lambda: counterfactual(chain(), FACTUAL, {}, seed="0"),
        "seed must be a non-negative int",
    ),
    bad(
        "inference.counterfactual",
        "shift gives nan",
        lambda: counterfactual(chain(), FACTUAL, [{"x": lambda v: v * NAN}]),
        "shift intervention on 'x' produced NaN or inf",
    ),
    bad(
        "inference.counterfactual",
        "action scenario out of bounds",
        lambda: counterfactual(finger(), finger_data(2), {"act.finger": 1.0}),
        "interventions['act.finger'] has 1 entries outside the action bounds",
    ),
    bad(
        "inference.counterfactual",
        "factual action out of bounds",
        lambda: counterfactual(finger(), {**finger_data(2), "act.finger": torch.full((2, 1), 4.0)}, {}),
        "factual['act.finger'] has 2 entries outside the action bounds",
    ),
    bad(
        "inference.counterfactual",
        "interval unknown",
        lambda: exact_cf().interval("w"),
        "unknown variable 'w'",
    ),
    bad(
        "inference.counterfactual",
        "interval level",
        lambda: exact_cf().interval("y", level=0),
        "level must be > 0 and < 1",
    ),
    bad("inference.abduct", "n 0", lambda: abduct(chain(), FACTUAL, 0), "n must be a positive int, got 0"),
    bad(
        "inference.abduct",
        "rows differ from n",
        lambda: abduct(chain(), FACTUAL, 2),
        "values['x'] has 1 rows, expected 2",
    ),
    # infer_action
    bad(
        "inference.infer_action",
        "model a str",
        lambda: infer_action("m", Q0, QT),
        "model must be a WorldModel",
    ),
    bad(
        "inference.infer_action",
        "unknown target",
        lambda: infer_action(plant(), Q0, {"w": torch.zeros(2, 1)}),
        "unknown variable in targets 'w'",
    ),
    bad(
        "inference.infer_action",
        "target rows",
        lambda: infer_action(plant(), Q0, {"q": torch.zeros(3, 1)}),
        "targets['q'] has 3 rows, expected 2",
    ),
    bad(
        "inference.infer_action",
        "target nan",
        lambda: infer_action(plant(), Q0, {"q": torch.full((2, 1), NAN)}),
        "targets['q'] contains 2 NaN",
    ),
    bad(
        "inference.infer_action",
        "target an action",
        lambda: infer_action(plant(), Q0, {"a": torch.zeros(2, 1)}),
        "target 'a' is an optimised action",
    ),
    bad(
        "inference.infer_action",
        "no targets",
        lambda: infer_action(plant(), Q0, None),
        "give targets or a log_preference",
    ),
    bad(
        "inference.infer_action",
        "actions not actions",
        lambda: infer_action(plant(), Q0, QT, actions=["q"]),
        "only actions can be optimised",
    ),
    bad(
        "inference.infer_action",
        "actions a str",
        lambda: infer_action(plant(), Q0, QT, actions="a"),
        "actions must be a sequence of names",
    ),
    bad(
        "inference.infer_action",
        "actions unknown",
        lambda: infer_action(plant(), Q0, QT, actions=["w"]),
        "unknown action 'w'",
    ),
    bad(
        "inference.infer_action",
        "unknown init",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(init="zero")),
        "init 'zero' unknown",
    ),
    bad(
        "inference.infer_action",
        "init an int",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(init=5)),
        "init must be 'midpoint', 'random' or a mapping",
    ),
    bad(
        "inference.infer_action",
        "init out of bounds",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(init={"a": torch.full((2, 1), 3.0)})),
        "init['a'] lies outside the bounds",
    ),
    bad(
        "inference.infer_action",
        "init unknown name",
        lambda: infer_action(
            plant(), Q0, QT, options=ActionOptions(init={"a": torch.zeros(2, 1), "b": torch.zeros(2, 1)})
        ),
        "init names ['b']",
    ),
    bad(
        "inference.infer_action",
        "steps 0",
        lambda: infer_action(plant(), Q0, QT, num_steps=0),
        "steps must be a positive int, got 0",
    ),
    bad(
        "inference.infer_action",
        "steps str",
        lambda: infer_action(plant(), Q0, QT, num_steps="200"),
        "steps must be a positive int, got '200'",
    ),
    bad(
        "inference.infer_action",
        "lr 0",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(lr=0.0)),
        "lr must be > 0",
    ),
    bad(
        "inference.infer_action",
        "scale 0",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(scale=0.0)),
        "scale must be > 0",
    ),
    bad(
        "inference.infer_action",
        "scale str",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(scale="1")),
        "scale must be > 0 (a finite number), got '1'",
    ),
    bad(
        "inference.infer_action",
        "scale unknown name",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(scale={"w": 1.0})),
        "unknown names ['w'], missing ['q']",
    ),
    bad(
        "inference.infer_action",
        "scale nan",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(scale={"q": NAN})),
        "scale['q'] must be > 0",
    ),
    bad(
        "inference.infer_action",
        "log_preference an int",
        lambda: infer_action(plant(), Q0, options=ActionOptions(log_preference=5)),
        "log_preference must be callable",
    ),
    bad(
        "inference.infer_action",
        "log_preference returns a float",
        lambda: infer_action(plant(), Q0, options=ActionOptions(log_preference=lambda p: 1.0), num_steps=1),
        "log_preference returned 1.0 (float)",
    ),
    bad(
        "inference.infer_action",
        "log_preference wrong shape",
        lambda: infer_action(
            plant(), Q0, options=ActionOptions(log_preference=lambda p: p["q"]), num_steps=1
        ),
        "log_preference returned (2, 1), expected a tensor of shape (2,)",
    ),
    bad(
        "inference.infer_action",
        "fixed action out of bounds",
        lambda: infer_action(
            finger(), {**FSTATE, "act.finger": torch.full((2, 1), 5.0)}, {"q.finger": torch.zeros(2, 1)}
        ),
        "state['act.finger'] has 2 entries outside the action bounds",
    ),
    bad(
        "inference.infer_action",
        "seed negative",
        lambda: infer_action(plant(), Q0, QT, seed=-2),
        "seed must be a non-negative int",
    ),
    bad(
        "inference.infer_action",
        "state int",
        lambda: infer_action(plant(), {"q_prev": np.zeros((2, 1), int)}, QT),
        "state['q_prev'] has dtype int64",
    ),
    bad(
        "inference.infer_action",
        "state and targets empty",
        lambda: infer_action(plant(), {}, {}),
        "state and targets are empty",
    ),
    bad(
        "inference.infer_action",
        "preference targets empty",
        lambda: gaussian_log_preference({}),
        "targets is empty",
    ),
    bad(
        "inference.infer_action",
        "preference scale negative",
        lambda: gaussian_log_preference(QT, -1.0),
        "scale must be > 0",
    ),
    bad(
        "inference.infer_action",
        "preference targets a str",
        lambda: gaussian_log_preference("q"),
        "targets must be a mapping",
    ),
    # curiosity
    bad("inference.curiosity", "low >= high", lambda: CuriositySampler(1.0, 0.0), "need finite low < high"),
    bad(
        "inference.curiosity",
        "low str",
        lambda: CuriositySampler("0", 1.0),
        "low must be a finite number, got '0'",
    ),
    bad(
        "inference.curiosity",
        "high inf",
        lambda: CuriositySampler(0.0, INF),
        "high must be a finite number, got inf",
    ),
    bad(
        "inference.curiosity",
        "bins 1",
        lambda: CuriositySampler(0.0, 1.0, bins=1),
        "bins must be an int >= 2, got 1",
    ),
    bad(
        "inference.curiosity",
        "bins float",
        lambda: CuriositySampler(0.0, 1.0, bins=2.5),
        "bins must be an int >= 2, got 2.5",
    ),
    bad(
        "inference.curiosity",
        "bins bool",
        lambda: CuriositySampler(0.0, 1.0, bins=True),
        "bins must be an int >= 2, got True",
    ),
    bad(
        "inference.curiosity",
        "alpha inf",
        lambda: CuriositySampler(0.0, 1.0, alpha=INF),
        "alpha must be >= 0 (a finite number), got inf",
    ),
    bad(
        "inference.curiosity",
        "alpha nan",
        lambda: CuriositySampler(0.0, 1.0, alpha=NAN),
        "alpha must be >= 0 (a finite number), got nan",
    ),
    bad(
        "inference.curiosity",
        "alpha negative",
        lambda: CuriositySampler(0.0, 1.0, alpha=-1.0),
        "alpha must be >= 0",
    ),
    bad("inference.curiosity", "sigma 0", lambda: CuriositySampler(0.0, 1.0, sigma=0.0), "sigma must be > 0"),
    bad(
        "inference.curiosity",
        "sigma inf",
        lambda: CuriositySampler(0.0, 1.0, sigma=INF),
        "sigma must be > 0 (a finite number), got inf",
    ),
    bad(
        "inference.curiosity",
        "unknown form",
        lambda: CuriositySampler(0.0, 1.0, form="log"),
        "form 'log' unknown",
    ),
    bad("inference.curiosity", "eps 0", lambda: CuriositySampler(0.0, 1.0, eps=0.0), "eps must be > 0"),
    bad(
        "inference.curiosity",
        "eps str",
        lambda: CuriositySampler(0.0, 1.0, eps="1"),
        "eps must be > 0 (a finite number), got '1'",
    ),
    bad(
        "inference.curiosity",
        "fit nan",
        lambda: CuriositySampler(0.0, 1.0).fit([0.1, NAN]),
        "values contains 1 NaN",
    ),
    bad(
        "inference.curiosity",
        "fit 2 columns",
        lambda: CuriositySampler(0.0, 1.0).fit(np.zeros((3, 2))),
        "expected (N,) or (N, 1)",
    ),
    bad(
        "inference.curiosity",
        "fit strings",
        lambda: CuriositySampler(0.0, 1.0).fit(["a"]),
        "values is not numeric",
    ),
    bad(
        "inference.curiosity",
        "fit bools",
        lambda: CuriositySampler(0.0, 1.0).fit(np.array([True])),
        "values has dtype bool",
    ),
    bad(
        "inference.curiosity",
        "sample no rng",
        lambda: CuriositySampler(0.0, 1.0).sample(None, [0.5]),
        "rng must be a numpy.random.Generator",
    ),
    bad(
        "inference.curiosity",
        "sample no size",
        lambda: CuriositySampler(0.0, 1.0).sample(np.random.default_rng(0)),
        "give current values or a positive size",
    ),
    bad(
        "inference.curiosity",
        "sample size float",
        lambda: CuriositySampler(0.0, 1.0).sample(np.random.default_rng(0), size=2.5),
        "size must be a positive int, got 2.5",
    ),
    bad(
        "inference.curiosity",
        "sample size and current",
        lambda: CuriositySampler(0.0, 1.0).sample(np.random.default_rng(0), [0.5], size=3),
        "size is only used without current",
    ),
    bad(
        "inference.curiosity",
        "density strings",
        lambda: CuriositySampler(0.0, 1.0).density(["x"]),
        "current is not numeric",
    ),
    bad(
        "inference.curiosity",
        "occupancy bins 0",
        lambda: occupancy([0.1], 0.0, 1.0, bins=0),
        "bins must be an int >= 2, got 0",
    ),
    bad(
        "inference.curiosity",
        "occupancy low >= high",
        lambda: occupancy([0.1], 1.0, 0.0),
        "need finite low < high",
    ),
    bad(
        "inference.curiosity",
        "entropy of nothing",
        lambda: normalized_entropy([], 0.0, 1.0),
        "no values to compute an entropy",
    ),
    # discover, admissible_parents, shd
    bad(
        "inference.discover",
        "variables a str",
        lambda: discover("xy", discovery_data()),
        "expected a CausalGraph or a sequence of Variable",
    ),
    bad(
        "inference.discover",
        "data a list",
        lambda: discover(scalars("x", "y"), [1]),
        "data must be a mapping",
    ),
    bad(
        "inference.discover",
        "missing column",
        lambda: discover(scalars("x", "y", "z"), discovery_data()),
        "missing ['z']",
    ),
    bad(
        "inference.discover",
        "str column",
        lambda: discover(scalars("x", "y"), discovery_data(x=[["a"]] * 40)),
        "data['x'] is not numeric",
    ),
    bad(
        "inference.discover",
        "int column",
        lambda: discover(scalars("x", "y"), discovery_data(x=np.zeros((40, 1), int))),
        "data['x'] has dtype int64",
    ),
    bad(
        "inference.discover",
        "nan column",
        lambda: discover(scalars("x", "y"), discovery_data(x=np.full((40, 1), NAN))),
        "data['x'] contains NaN",
    ),
    bad(
        "inference.discover",
        "5 rows",
        lambda: discover(scalars("x", "y"), discovery_data(5)),
        "at least 8 rows, got 5",
    ),
    bad(
        "inference.discover",
        "1-d column",
        lambda: discover(scalars("x", "y"), discovery_data(x=np.zeros(40))),
        "data['x'] has shape (40,)",
    ),
    bad(
        "inference.discover",
        "float mask",
        lambda: discover(scalars("x", "y"), discovery_data(), intervened={"x": np.zeros(40)}),
        "intervened['x'] has shape (40,) and dtype float64, expected (40,) bool",
    ),
    bad(
        "inference.discover",
        "mask unknown name",
        lambda: discover(scalars("x", "y"), discovery_data(), intervened={"w": np.zeros(40, bool)}),
        "intervened names unknown variable 'w'",
    ),
    bad(
        "inference.discover",
        "intervened a list",
        lambda: discover(scalars("x", "y"), discovery_data(), intervened=[1]),
        "intervened must be a mapping",
    ),
    bad(
        "inference.discover",
        "unknown sparsify",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(sparsify="lasso")),
        "sparsify 'lasso' unknown",
    ),
    bad(
        "inference.discover",
        "min_gain str",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(min_gain="10")),
        "min_gain must be a finite number, got '10'",
    ),
    bad(
        "inference.discover",
        "prune above gain",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(prune_nats=20.0)),
        "prune_nats (20.0) must be <= min_gain",
    ),
    bad(
        "inference.discover",
        "max_parents 0",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(max_parents=0)),
        "max_parents must be a positive int, got 0",
    ),
    bad(
        "inference.discover",
        "max_moves float",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(max_moves=1.5)),
        "max_moves must be a positive int, got 1.5",
    ),
    bad(
        "inference.discover",
        "features negative",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(features=-1)),
        "features must be a non-negative int, got -1",
    ),
    bad(
        "inference.discover",
        "folds 1",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(folds=1)),
        "folds must be an int >= 2, got 1",
    ),
    bad(
        "inference.discover",
        "ridge str",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(ridge="1")),
        "ridge must be a number > 0",
    ),
    bad(
        "inference.discover",
        "ridge empty",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(ridge=[])),
        "ridge is an empty sequence",
    ),
    bad(
        "inference.discover",
        "ridge negative",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(ridge=(0.1, -1.0))),
        "ridge[1] must be > 0",
    ),
    bad(
        "inference.discover",
        "length 0",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(length=0.0)),
        "length must be > 0",
    ),
    bad(
        "inference.discover",
        "floor 0",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(floor=0.0)),
        "floor must be > 0",
    ),
    bad(
        "inference.discover",
        "repeats 0",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(repeats=0)),
        "repeats must be a positive int, got 0",
    ),
    bad(
        "inference.discover",
        "gated unknown key",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(gated={"depth": 2})),
        "gated has unknown keys ['depth']",
    ),
    bad(
        "inference.discover",
        "gated steps 0",
        lambda: discover(
            scalars("x", "y"),
            discovery_data(),
            options=DiscoveryOptions(features=4, sparsify="gated", gated={"steps": 0}),
        ),
        "steps must be a positive int, got 0",
    ),
    bad(
        "inference.discover",
        "seed negative",
        lambda: discover(scalars("x", "y"), discovery_data(), seed=-1),
        "seed must be a non-negative int",
    ),
    bad(
        "inference.discover",
        "required a str",
        lambda: discover(scalars("x", "y"), discovery_data(), required="xy"),
        "required must be a sequence of (parent, child) pairs",
    ),
    bad(
        "inference.discover",
        "required unknown",
        lambda: discover(scalars("x", "y"), discovery_data(), required=[("x", "w")]),
        "required edge ('x', 'w') is not a (parent, child) pair of known variables",
    ),
    bad(
        "inference.admissible",
        "tiers a str",
        lambda: admissible_parents(scalars("x", "y"), tiers="xy"),
        "tiers must be a sequence",
    ),
    bad(
        "inference.admissible",
        "tier an int",
        lambda: admissible_parents(scalars("x", "y"), tiers=[["x"], 5]),
        "tier 1 is 5 (int)",
    ),
    bad(
        "inference.admissible",
        "name in two tiers",
        lambda: admissible_parents(scalars("x", "y"), tiers=[["x"], ["x"]]),
        "'x' is in tiers 0 and 1",
    ),
    bad(
        "inference.admissible",
        "forbidden of one",
        lambda: admissible_parents(scalars("x", "y"), forbidden=[("x",)]),
        "edge ('x',) is not a (parent, child) pair",
    ),
    bad(
        "inference.admissible",
        "variables an int",
        lambda: admissible_parents(5),
        "expected a CausalGraph or a sequence of Variable, got 5",
    ),
    bad(
        "inference.shd",
        "learnt an int",
        lambda: shd(5, []),
        "learnt must be a sequence of (parent, child) pairs",
    ),
    bad(
        "inference.shd",
        "triple",
        lambda: shd([("a", "b", "c")], []),
        "edge ('a', 'b', 'c') is not a (parent, child) pair",
    ),
    # design
    bad(
        "inference.design",
        "result a str",
        lambda: choose_interventions("r", {}, 1),
        "result must be a DiscoveryResult",
    ),
    bad(
        "inference.design",
        "budget negative",
        lambda: choose_interventions(fake_discovery(), {}, -1),
        "budget must be a non-negative int, got -1",
    ),
    bad(
        "inference.design",
        "budget float",
        lambda: choose_interventions(fake_discovery(), {}, 2.5),
        "budget must be a non-negative int, got 2.5",
    ),
    bad(
        "inference.design",
        "margin of a non-edge",
        lambda: structure_uncertainty(fake_discovery(), {("a", "b"): 1.0}),
        "margins names ('a', 'b'), which is not an edge",
    ),
    # context
    bad(
        "inference.context",
        "model a str",
        lambda: active_subgraph("m", {}, ["q"]),
        "model must be a WorldModel",
    ),
    bad(
        "inference.context",
        "targets a str",
        lambda: active_subgraph(*finger_samples(), "q.finger"),
        "targets must be a sequence of names",
    ),
    bad(
        "inference.context",
        "targets empty",
        lambda: active_subgraph(*finger_samples(), []),
        "targets is empty",
    ),
    bad(
        "inference.context",
        "unknown target",
        lambda: active_subgraph(*finger_samples(), ["w"]),
        "unknown target 'w'",
    ),
    bad(
        "inference.context",
        "threshold negative",
        lambda: active_subgraph(*finger_samples(), ["q.finger"], -1.0),
        "threshold must be >= 0",
    ),
    bad(
        "inference.context",
        "threshold nan",
        lambda: active_subgraph(*finger_samples(), ["q.finger"], NAN),
        "threshold must be >= 0 (a finite number), got nan",
    ),
    bad(
        "inference.context",
        "samples incomplete",
        lambda: active_subgraph(finger(), FIN, ["q.finger"]),
        "context needs a value for every variable; missing",
    ),
    bad(
        "inference.context",
        "sub a str",
        lambda: subgraph_model(finger(), "sub"),
        "sub must be an ActiveSubgraph",
    ),
    bad(
        "inference.context",
        "relevance targets a str",
        lambda: target_relevance(finger(), FIN, "q.finger"),
        "targets must be a sequence of names",
    ),
    # ensemble
    bad("inference.ensemble", "one member", lambda: Ensemble([member()]), "at least 2 members, got 1"),
    bad(
        "inference.ensemble",
        "members a str",
        lambda: Ensemble("ab"),
        "members must be a sequence of WorldModel",
    ),
    bad(
        "inference.ensemble",
        "member a str",
        lambda: Ensemble([member(), "x"]),
        "ensemble member 1 must be a WorldModel",
    ),
    bad(
        "inference.ensemble",
        "different graphs",
        lambda: Ensemble([member(), chain()]),
        "must share one graph",
    ),
    bad("inference.ensemble", "make not callable", lambda: Ensemble.create(5), "make must be callable"),
    bad(
        "inference.ensemble",
        "k 1",
        lambda: Ensemble.create(lambda s: member(), k=1),
        "k must be an int >= 2, got 1",
    ),
    bad(
        "inference.ensemble",
        "k float",
        lambda: Ensemble.create(lambda s: member(), k=2.0),
        "k must be an int >= 2, got 2.0",
    ),
    bad(
        "inference.ensemble",
        "fit unknown kwarg",
        lambda: ensemble().fit({"a": torch.zeros(4, 1), "y": torch.zeros(4, 1)}, epoch=3),
        "fit_kwargs has unknown keys ['epoch']",
    ),
    bad(
        "inference.ensemble",
        "fit one row",
        lambda: ensemble().fit({"a": torch.zeros(1, 1), "y": torch.zeros(1, 1)}),
        "at least 2 rows, got 1",
    ),
    bad(
        "inference.ensemble",
        "target a root",
        lambda: ensemble().information({"a": torch.zeros(1, 1)}, ["a"]),
        "target 'a' is a root",
    ),
    bad(
        "inference.ensemble",
        "targets a str",
        lambda: ensemble().information({"a": torch.zeros(1, 1)}, "y"),
        "targets must be a sequence of names",
    ),
    bad(
        "inference.ensemble", "no candidates", lambda: ensemble().choose({}, {}, ["y"]), "candidates is empty"
    ),
    bad(
        "inference.ensemble",
        "spread 0",
        lambda: ensemble().choose({}, {"a": torch.zeros(2, 3, 1)}, ["y"], spread=0.0),
        "spread must be > 0",
    ),
    bad(
        "inference.ensemble",
        "candidate out of bounds",
        lambda: ensemble().choose({}, {"a": torch.full((2, 3, 1), 2.0)}, ["y"]),
        "values['a'] has 6 entries outside the action bounds",
    ),
    # metalearn
    bad(
        "inference.metalearn",
        "monitor model a str",
        lambda: ResidualMonitor("m"),
        "model must be a WorldModel",
    ),
    bad(
        "inference.metalearn",
        "window 0",
        lambda: ResidualMonitor(finger(), window=0),
        "window must be a positive int, got 0",
    ),
    bad(
        "inference.metalearn",
        "window float",
        lambda: ResidualMonitor(finger(), window=1.5),
        "window must be a positive int, got 1.5",
    ),
    bad(
        "inference.metalearn",
        "threshold 0",
        lambda: ResidualMonitor(finger(), threshold=0),
        "threshold must be > 0",
    ),
    bad(
        "inference.metalearn",
        "patience bool",
        lambda: ResidualMonitor(finger(), patience=True),
        "patience must be a positive int, got True",
    ),
    bad(
        "inference.metalearn",
        "tolerance of a root",
        lambda: ResidualMonitor(finger(), tolerance={"act.finger": 0.1}),
        "'act.finger', a root",
    ),
    bad(
        "inference.metalearn",
        "tolerance 0",
        lambda: ResidualMonitor(finger(), tolerance={"dq.finger": 0.0}),
        "tolerance['dq.finger'] must be",
    ),
    bad(
        "inference.metalearn",
        "tolerance str",
        lambda: ResidualMonitor(finger(), tolerance={"dq.finger": "a"}),
        "tolerance['dq.finger'] is not numeric",
    ),
    bad(
        "inference.metalearn",
        "tolerance unknown",
        lambda: ResidualMonitor(finger(), tolerance={"w": 1.0}),
        "unknown tolerance variable 'w'",
    ),
    bad(
        "inference.metalearn",
        "update incomplete",
        lambda: ResidualMonitor(finger()).update(finger(), FIN),
        "values needs rows of every variable; missing",
    ),
    bad(
        "inference.metalearn",
        "revise variables a str",
        lambda: revise(finger(), finger_data(), "dq.finger"),
        "variables must be a sequence of names",
    ),
    bad(
        "inference.metalearn",
        "revise unknown kind",
        lambda: revise(finger(), finger_data(), ["dq.finger"], kinds=("grow",)),
        "unknown revision kinds ['grow']",
    ),
    bad(
        "inference.metalearn",
        "revise a root",
        lambda: revise(finger(), finger_data(), ["act.finger"]),
        "'act.finger' is a root",
    ),
    bad(
        "inference.metalearn",
        "revise val_fraction 1",
        lambda: revise(finger(), finger_data(), ["dq.finger"], val_fraction=1.0),
        "val_fraction must be > 0 and < 1",
    ),
    bad(
        "inference.metalearn",
        "revise unknown fit kwarg",
        lambda: revise(finger(), finger_data(), ["dq.finger"], fit_kwargs={"epoch": 1}),
        "fit_kwargs has unknown keys ['epoch']",
    ),
    bad(
        "inference.metalearn",
        "revise hidden 0",
        lambda: revise(finger(), finger_data(), ["dq.finger"], hidden=(0,)),
        "hidden[0] must be a positive int",
    ),
    bad(
        "inference.metalearn",
        "revise data incomplete",
        lambda: revise(finger(), FIN, ["dq.finger"]),
        "revise needs rows of every variable; missing",
    ),
    bad(
        "inference.metalearn",
        "split component out of range",
        lambda: SplitMechanism(LinearMechanism(1, seed=0), LinearMechanism(1, seed=1), 5, 0.0),
        "split component 5 out of range",
    ),
    bad(
        "inference.metalearn",
        "split regime a str",
        lambda: SplitMechanism("a", LinearMechanism(1, seed=1), 0, 0.0),
        "low regime must be a Mechanism",
    ),
    bad(
        "inference.metalearn",
        "split cut nan",
        lambda: SplitMechanism(LinearMechanism(1, seed=0), LinearMechanism(1, seed=1), 0, NAN),
        "cut must be a finite number, got nan",
    ),
    # rewire
    bad("inference.rewire", "model a str", lambda: rewire("m", finger_graph()), "model must be a WorldModel"),
    bad(
        "inference.rewire",
        "graph a str",
        lambda: rewire(finger(), "g", refit="none"),
        "graph must be a CausalGraph",
    ),
    bad(
        "inference.rewire",
        "unknown refit",
        lambda: rewire(finger(), finger_graph(), finger_data(), refit="some"),
        "refit 'some' unknown",
    ),
    bad("inference.rewire", "no data", lambda: rewire(finger(), finger_graph()), "data is needed to refit"),
    bad(
        "inference.rewire",
        "epochs str",
        lambda: rewire(finger(), finger_graph(), finger_data(), schedule=FitSchedule(epochs="3")),
        "epochs must be a positive int, got '3'",
    ),
    bad(
        "inference.rewire",
        "unknown fit kwarg",
        lambda: rewire(finger(), finger_graph(), finger_data(), epoch=3),
        "fit_kwargs has unknown keys ['epoch']",
    ),
    bad(
        "inference.rewire",
        "mask shape",
        lambda: rewire(finger(), finger_graph(), finger_data(), intervened=cut(np.zeros(3, bool))),
        "intervened['dq.finger'] has shape (3,)",
    ),
    bad(
        "inference.rewire",
        "mask unknown name",
        lambda: rewire(finger(), finger_graph(), finger_data(), intervened={"w": np.zeros(16, bool)}),
        "intervened names ['w']",
    ),
    bad(
        "inference.rewire",
        "seed negative",
        lambda: rewire(finger(), finger_graph(), refit="none", seed=-1),
        "seed must be a non-negative int",
    ),
    bad("inference.rewire", "data empty", lambda: rewire(finger(), finger_graph(), {}), "data is empty"),
    bad(
        "inference.fit",
        "Bernoulli observed with 0.5",
        lambda: fit(binary(), bin_data(t=HALF)),
        "data['t'] has 1 values that are not 0 or 1",
    ),
    bad(
        "inference.infer_state",
        "Bernoulli observed with 0.5",
        lambda: infer_state(binary(), {"x": HALF, "t": HALF}),
        "observed['t'] has 1 values that are not 0 or 1",
    ),
    bad(
        "inference.counterfactual",
        "Bernoulli observed with 0.5",
        lambda: counterfactual(binary(), bin_data(t=HALF), {"x": 0.0}),
        "factual['t'] has 1 values that are not 0 or 1",
    ),
    bad(
        "inference.counterfactual",
        "categorical value outside range",
        lambda: counterfactual(binary(), bin_data(c=THREE), {"x": 0.0}),
        "factual['c'] has 4 values that are not an integer code 0 .. 2 (first: 3 at index (0, 0))",
    ),
    bad(
        "inference.fit",
        "categorical value outside range",
        lambda: fit(binary(), bin_data(c=-THREE)),
        "data['c'] has 4 values that are not an integer code 0 .. 2 (first: -3",
    ),
    bad(
        "inference.do",
        "categorical intervention outside range",
        lambda: do(binary(), {"c": 3.0}),
        "intervention on 'c' has 1 values that are not an integer code 0 .. 2",
    ),
    bad(
        "inference.do",
        "Bernoulli intervention of 0.5",
        lambda: do(binary(), {"t": 0.5}),
        "intervention on 't' has 1 values that are not 0 or 1",
    ),
    bad(
        "inference.do",
        "shift intervention leaves the categories",
        lambda: simulate(binary(), 3, {"c": lambda c: c + 5}),
        "intervention on 'c' has 3 values that are not an integer code 0 .. 2",
    ),
    # posteriors and composition
    bad(
        "inference.infer_state",
        "guide unknown",
        lambda: infer_state(chain(), Z, guide="laplace"),
        "guide 'laplace' unknown; expected one of",
    ),
    bad(
        "inference.infer_state",
        "options of another guide",
        lambda: infer_state(chain(), Z, guide="grid", options=SVIOptions()),
        "guide='grid' takes options=GridOptions(...), got",
    ),
    bad(
        "inference.infer_state",
        "SVI options for importance sampling",
        lambda: infer_state(chain(), Z, guide="importance", options=SVIOptions(lr=0.1)),
        "guide='importance' takes options=ImportanceOptions(...), got SVIOptions(",
    ),
    bad("inference.SVIOptions", "lr zero", lambda: SVIOptions(lr=0.0), "lr must be > 0"),
    bad(
        "inference.GridOptions",
        "max_dims 3",
        lambda: GridOptions(max_dims=3),
        "max_dims must be 1 or 2, got 3",
    ),
    bad(
        "inference.ImportanceOptions",
        "too few particles",
        lambda: ImportanceOptions(num_particles=2),
        "num_particles must be an int >= 10, got 2",
    ),
    bad(
        "inference.counterfactual",
        "posterior of a program with a different graph",
        lambda: counterfactual(
            chain(),
            {"x": torch.ones(1, 1), "z": Z["z"]},
            {"x": 0.0},
            posterior=infer_state(binary(), {"x": np.zeros((1, 1)), "y": np.zeros((1, 1))}, guide="grid"),
        ),
        "posterior was made for another graph",
    ),
    bad(
        "inference.counterfactual",
        "posterior not a StateResult",
        lambda: counterfactual(chain(), {"x": torch.ones(1, 1), "z": Z["z"]}, {"x": 0.0}, posterior={"y": 1}),
        "posterior must be a StateResult from infer_state",
    ),
    bad(
        "inference.counterfactual",
        "guide unknown",
        lambda: counterfactual(chain(), Z, {"x": 0.0}, guide="exact"),
        "guide 'exact' unknown",
    ),
    bad(
        "inference.handlers",
        "handler naming a site of another graph",
        lambda: MeasurementScale({"q": torch.ones(1)})(chain()),
        "MeasurementScale names ['q'], which are not sites of the program",
    ),
    bad(
        "inference.Program",
        "a Program of something else",
        lambda: Program(lambda d, n: None),
        "a Program wraps a WorldModel",
    ),
    bad(
        "inference.fit",
        "schedule a dict",
        lambda: fit(xy_model(), xy(), schedule={"epochs": 1}),
        "schedule must be a FitSchedule or None",
    ),
    bad(
        "inference.FitSchedule",
        "validation 1",
        lambda: FitSchedule(validation=1.0),
        "validation must be >= 0 and < 1",
    ),
    bad(
        "inference.infer_action",
        "options a dict",
        lambda: infer_action(finger(), FSTATE, {"q.finger": np.zeros((2, 1))}, options={"lr": 0.1}),
        "options must be an ActionOptions or None",
    ),
]


def test_case_ids_are_unique_and_there_are_enough():
    assert duplicate_ids(CASES) == []
    assert len(CASES) >= 70, len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[f"{c.area}: {c.id}" for c in CASES])
def test_bad_input_raises_a_specific_error_naming_the_value(case):
    check(case)


def test_no_bad_input_gets_a_raw_library_error():
    raw = raw_errors(CASES)
    assert raw == [], "\n".join(raw)
