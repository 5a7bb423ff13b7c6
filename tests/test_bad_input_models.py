"""Bad input to the public API of ``models`` and ``inference`` raises a specific error.

Every entry of :data:`CASES` is one bad call: the exact exception type it must raise and a
substring of the message that names the offending value or parameter. A report can count
the cases with ``from tests.test_bad_input_models import CASES`` (``len(CASES)``, or by
``case.area``).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import pytest
import torch

from inference import (
    ActionOptions,
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
    BernoulliMechanism,
    CategoricalMechanism,
    CausalGraph,
    EnsembleMechanism,
    FunctionMechanism,
    HeteroscedasticMechanism,
    LinearMechanism,
    MLPMechanism,
    Role,
    Variable,
    WorldModel,
    chain_graph,
    finger_graph,
    joint_chain_graph,
    pushing_graph,
    random_graph,
)
from models.mechanisms import make_mechanism

NAN, INF = float("nan"), float("inf")


class BadInput(NamedTuple):
    """One bad call: ``call()`` must raise exactly ``error`` with ``match`` in its message."""

    area: str
    id: str
    call: Callable[[], Any]
    error: type[Exception]
    match: str


# ---------------------------------------------------------------------------- builders
def chain() -> WorldModel:
    """Y = 2X + U_y, Z = -1.5Y + U_z."""
    return WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients([[2.0]]), "z": LinearMechanism.from_coefficients([[-1.5]])},
    )


def finger() -> WorldModel:
    return WorldModel(finger_graph("state"), seed=0, hidden=(4,))


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


def xy_graph() -> CausalGraph:
    return CausalGraph([Variable("x", "observed"), Variable("y", "latent")], [("x", "y")])


def xy_model() -> WorldModel:
    return WorldModel(xy_graph(), seed=0, hidden=(4,))


def scalars(*names: str) -> list[Variable]:
    return [Variable(n, Role.OBSERVED) for n in names]


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


FACTUAL = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-3.0]])}
Z = {"z": torch.tensor([[-3.0]])}
Q0 = {"q_prev": torch.zeros(2, 1)}
QT = {"q": torch.zeros(2, 1)}
FSTATE = {"q_prev.finger": torch.zeros(2, 1)}
FIN = {"act.finger": torch.zeros(2, 1), "q_prev.finger": torch.zeros(2, 1)}
RANGES = {"j": (-1.0, 1.0)}
MECH2 = LinearMechanism.from_coefficients([[1.0], [2.0]])  # 1 -> 2


def _c(
    area: str, id_: str, call: Callable[[], Any], match: str, error: type[Exception] = ValueError
) -> BadInput:
    return BadInput(area, id_, call, error, match)


# ---------------------------------------------------------------------------- models
CASES: list[BadInput] = [
    # Variable
    _c("models.Variable", "name not a str", lambda: Variable(5, "latent"), "variable name 5"),
    _c("models.Variable", "unknown role", lambda: Variable("x", "bogus"), "role 'bogus'"),
    _c("models.Variable", "role a list", lambda: Variable("x", ["latent"]), "role ['latent']"),
    _c(
        "models.Variable",
        "dim float",
        lambda: Variable("x", "latent", dim=2.0),
        "dim must be a positive int, got 2.0",
    ),
    _c(
        "models.Variable",
        "dim bool",
        lambda: Variable("x", "latent", dim=True),
        "dim must be a positive int, got True",
    ),
    _c(
        "models.Variable",
        "dim str",
        lambda: Variable("x", "latent", dim="2"),
        "dim must be a positive int, got '2'",
    ),
    _c(
        "models.Variable",
        "lag bool",
        lambda: Variable("x", "latent", lag=True),
        "lag must be 0 or 1, got True",
    ),
    _c("models.Variable", "lag 2", lambda: Variable("x", "latent", lag=2), "lag must be 0 or 1, got 2"),
    _c(
        "models.Variable",
        "bounds strings",
        lambda: Variable("a", "action", bounds=("0", "1")),
        "bounds side '0'",
    ),
    _c(
        "models.Variable",
        "bounds bool",
        lambda: Variable("a", "action", bounds=(True, 2)),
        "bounds side True",
    ),
    _c(
        "models.Variable",
        "bounds inf",
        lambda: Variable("a", "action", bounds=(0, INF)),
        "bounds must be finite",
    ),
    _c(
        "models.Variable",
        "bounds nan",
        lambda: Variable("a", "action", bounds=(NAN, 1)),
        "bounds must be finite",
    ),
    _c("models.Variable", "bounds reversed", lambda: Variable("a", "action", bounds=(1, 0)), "low >= high"),
    _c(
        "models.Variable", "bounds scalar", lambda: Variable("a", "action", bounds=5), "bounds must be a pair"
    ),
    _c(
        "models.Variable",
        "bounds wrong dim",
        lambda: Variable("a", "action", dim=2, bounds=([0], [1])),
        "expected 2",
    ),
    _c(
        "models.Variable",
        "action without bounds",
        lambda: Variable("a", "action"),
        "action 'a' has no bounds",
    ),
    _c(
        "models.Variable",
        "unit not str",
        lambda: Variable("x", "latent", unit=3),
        "unit must be a str, got 3",
    ),
    _c(
        "models.Variable",
        "lag_of at lag 0",
        lambda: Variable("x", "latent", lag_of="q"),
        "lag_of is only meaningful",
    ),
    _c(
        "models.Variable",
        "lag_of not str",
        lambda: Variable("x", "latent", lag=1, lag_of=3),
        "lag_of must be",
    ),
    _c(
        "models.Variable",
        "from_dict not mapping",
        lambda: Variable.from_dict("x"),
        "variable entry must be a mapping",
    ),
    _c(
        "models.Variable",
        "from_dict unknown field",
        lambda: Variable.from_dict({"name": "x", "role": "latent", "colour": 1}),
        "unknown variable fields ['colour']",
    ),
    _c(
        "models.Variable",
        "from_dict no role",
        lambda: Variable.from_dict({"name": "x"}),
        "needs 'name' and 'role'",
    ),
    # CausalGraph
    _c(
        "models.CausalGraph",
        "variables a str",
        lambda: CausalGraph("ab"),
        "variables must be a sequence of Variable",
    ),
    _c(
        "models.CausalGraph",
        "variables an int",
        lambda: CausalGraph(5),
        "variables must be a sequence of Variable",
    ),
    _c(
        "models.CausalGraph",
        "variable a str",
        lambda: CausalGraph(["x"]),
        "expected Variable instances, got str",
    ),
    _c(
        "models.CausalGraph",
        "duplicate names",
        lambda: CausalGraph(scalars("x", "x")),
        "duplicate variable name 'x'",
    ),
    _c(
        "models.CausalGraph",
        "cycle",
        lambda: CausalGraph(scalars("x", "y"), [("x", "y"), ("y", "x")]),
        "graph has a cycle",
    ),
    _c(
        "models.CausalGraph",
        "edges a str",
        lambda: CausalGraph(scalars("x", "y"), "xy"),
        "edges must be a sequence",
    ),
    _c(
        "models.CausalGraph",
        "edge of one",
        lambda: CausalGraph(scalars("x"), [("x",)]),
        "edge ('x',) is not a",
    ),
    _c(
        "models.CausalGraph",
        "edge an int",
        lambda: CausalGraph(scalars("x"), [5]),
        "edge 5 is not a (parent, child)",
    ),
    _c(
        "models.CausalGraph",
        "edge end a list",
        lambda: CausalGraph(scalars("x", "y"), [(["x"], "y")]),
        "expected variable names",
    ),
    _c(
        "models.CausalGraph",
        "edge unknown name",
        lambda: CausalGraph(scalars("x"), [("x", "w")]),
        "names unknown variable 'w'",
    ),
    _c(
        "models.CausalGraph", "self-loop", lambda: CausalGraph(scalars("x"), [("x", "x")]), "self-loop on 'x'"
    ),
    _c(
        "models.CausalGraph",
        "action with a parent",
        lambda: CausalGraph([*scalars("x"), Variable("a", "action", bounds=(0, 1))], [("x", "a")]),
        "action 'a' has parent 'x'",
    ),
    _c(
        "models.CausalGraph",
        "confidence a str",
        lambda: chain_graph().with_confidence({("x", "y"): "0.5"}),
        "confidence of edge 'x' -> 'y' must be a finite number, got '0.5'",
    ),
    _c(
        "models.CausalGraph",
        "confidence above 1",
        lambda: chain_graph().with_confidence({("x", "y"): 1.5}),
        "is 1.5, expected [0, 1]",
    ),
    _c(
        "models.CausalGraph",
        "confidence nan",
        lambda: chain_graph().with_confidence({("x", "y"): NAN}),
        "confidence of edge 'x' -> 'y' must be a finite number, got nan",
    ),
    _c(
        "models.CausalGraph",
        "confidence of a non-edge",
        lambda: chain_graph().with_confidence({("x", "z"): 0.5}),
        "confidence given for ('x', 'z')",
    ),
    _c(
        "models.CausalGraph",
        "confidence not a mapping",
        lambda: CausalGraph(scalars("x"), [], [("x", "y")]),
        "confidence must be a mapping",
    ),
    _c("models.CausalGraph", "getitem unknown", lambda: chain_graph()["w"], "unknown variable 'w'"),
    _c("models.CausalGraph", "getitem int", lambda: chain_graph()[5], "variable name must be a str, got 5"),
    _c("models.CausalGraph", "parents of a list", lambda: chain_graph().parents(["x"]), "name must be a str"),
    _c(
        "models.CausalGraph",
        "by_role unknown",
        lambda: chain_graph().by_role("bogus"),
        "role 'bogus' unknown",
    ),
    _c(
        "models.CausalGraph",
        "with_edges a str",
        lambda: chain_graph().with_edges(add=["xz"]),
        "edge 'xz' is not a",
    ),
    _c(
        "models.CausalGraph",
        "with_edges remove missing",
        lambda: chain_graph().with_edges(remove=[("x", "z")]),
        "cannot remove edges [('x', 'z')]",
    ),
    _c(
        "models.CausalGraph",
        "edge_confidence non-edge",
        lambda: chain_graph().edge_confidence("x", "z"),
        "'x' -> 'z'",
    ),
    _c("models.CausalGraph", "from_json not str", lambda: CausalGraph.from_json(5), "must be a str, got 5"),
    _c("models.CausalGraph", "from_json malformed", lambda: CausalGraph.from_json("{"), "malformed"),
    _c(
        "models.CausalGraph",
        "from_dict no variables",
        lambda: CausalGraph.from_dict({"format": "pal.causal_graph/1"}),
        "no 'variables' entry",
    ),
    _c(
        "models.CausalGraph",
        "from_dict variables a str",
        lambda: CausalGraph.from_dict({"format": "pal.causal_graph/1", "variables": "x", "edges": []}),
        "'variables' must be a list",
    ),
    _c(
        "models.CausalGraph", "from_dict format", lambda: CausalGraph.from_dict({"format": "x"}), "format 'x'"
    ),
    _c(
        "models.CausalGraph",
        "from_dict variable entry",
        lambda: CausalGraph.from_dict({"format": "pal.causal_graph/1", "variables": [5], "edges": []}),
        "variable entry 5 is not a mapping",
    ),
    # presets
    _c(
        "models.presets",
        "joints a str",
        lambda: joint_chain_graph("ab", {"a": (0, 1)}),
        "joints must be a sequence",
    ),
    _c("models.presets", "joints empty", lambda: joint_chain_graph([], {}), "joints is empty"),
    _c(
        "models.presets",
        "joints repeated",
        lambda: joint_chain_graph(["j", "j"], RANGES),
        "names ['j'] more than once",
    ),
    _c(
        "models.presets",
        "action_ranges a list",
        lambda: joint_chain_graph(["j"], [(-1, 1)]),
        "action_ranges must be a mapping",
    ),
    _c(
        "models.presets",
        "missing action range",
        lambda: joint_chain_graph(["a"], RANGES),
        "no action range for joints ['a']",
    ),
    _c(
        "models.presets",
        "unknown variant",
        lambda: joint_chain_graph(["j"], RANGES, "x"),
        "graph variant 'x' unknown",
    ),
    _c(
        "models.presets",
        "q_ranges unknown joint",
        lambda: joint_chain_graph(["j"], RANGES, q_ranges={"k": (0, 1)}),
        "q_ranges names unknown joints ['k']",
    ),
    _c("models.presets", "finger joint an int", lambda: finger_graph(joint=5), "joint must be a joint name"),
    _c("models.presets", "random_graph d float", lambda: random_graph(2.5), "d must be an int >= 2, got 2.5"),
    _c("models.presets", "random_graph d 1", lambda: random_graph(1), "d must be an int >= 2, got 1"),
    _c(
        "models.presets",
        "random_graph expected_parents nan",
        lambda: random_graph(4, expected_parents=NAN),
        "expected_parents must be",
    ),
    _c(
        "models.presets",
        "random_graph seed -1",
        lambda: random_graph(4, seed=-1),
        "seed must be a non-negative int",
    ),
    _c(
        "models.presets",
        "random_graph seed str",
        lambda: random_graph(4, seed="0"),
        "seed must be a non-negative int",
    ),
    _c(
        "models.presets",
        "pushing objects a str",
        lambda: pushing_graph(["j"], RANGES, objects="box"),
        "objects must be",
    ),
    _c(
        "models.presets",
        "pushing object_dim float",
        lambda: pushing_graph(["j"], RANGES, object_dim=2.0),
        "object_dim must be 2 or 3, got 2.0",
    ),
    _c(
        "models.presets",
        "pushing clash",
        lambda: pushing_graph(["j"], RANGES, objects=("hand",)),
        "clash with the hand",
    ),
    # mechanisms
    _c("models.mechanisms", "in_dim 0", lambda: MLPMechanism(0), "in_dim must be a positive int, got 0"),
    _c(
        "models.mechanisms",
        "in_dim float",
        lambda: MLPMechanism(2.5),
        "in_dim must be a positive int, got 2.5",
    ),
    _c(
        "models.mechanisms",
        "in_dim bool",
        lambda: MLPMechanism(True),
        "in_dim must be a positive int, got True",
    ),
    _c(
        "models.mechanisms",
        "out_dim str",
        lambda: LinearMechanism(1, "1"),
        "out_dim must be a positive int, got '1'",
    ),
    _c("models.mechanisms", "hidden an int", lambda: MLPMechanism(1, hidden=5), "hidden must be a sequence"),
    _c(
        "models.mechanisms",
        "hidden float",
        lambda: MLPMechanism(1, hidden=(2.5,)),
        "hidden[0] must be a positive int",
    ),
    _c(
        "models.mechanisms",
        "hidden 0",
        lambda: MLPMechanism(1, hidden=(0,)),
        "hidden[0] must be a positive int, got 0",
    ),
    _c(
        "models.mechanisms",
        "unknown activation",
        lambda: MLPMechanism(1, activation="nope"),
        "activation 'nope' unknown",
    ),
    _c(
        "models.mechanisms",
        "activation a list",
        lambda: MLPMechanism(1, activation=["tanh"]),
        "activation ['tanh']",
    ),
    _c("models.mechanisms", "sigma 0", lambda: MLPMechanism(1, sigma=0), "sigma must be > 0"),
    _c(
        "models.mechanisms",
        "sigma inf",
        lambda: LinearMechanism(1, sigma=INF),
        "sigma must be > 0 (a finite number), got inf",
    ),
    _c(
        "models.mechanisms",
        "sigma str",
        lambda: LinearMechanism(1, sigma="1"),
        "sigma must be > 0 (a finite number), got '1'",
    ),
    _c(
        "models.mechanisms",
        "seed negative",
        lambda: MLPMechanism(1, seed=-3),
        "seed must be a non-negative int, got -3",
    ),
    _c(
        "models.mechanisms",
        "seed float",
        lambda: LinearMechanism(1, seed=1.5),
        "seed must be a non-negative int, got 1.5",
    ),
    _c(
        "models.mechanisms",
        "weight nan",
        lambda: LinearMechanism.from_coefficients([[NAN]]),
        "weight contains 1 NaN or inf",
    ),
    _c(
        "models.mechanisms",
        "weight str",
        lambda: LinearMechanism.from_coefficients("abc"),
        "weight is not numeric",
    ),
    _c(
        "models.mechanisms",
        "weight 3-d",
        lambda: LinearMechanism.from_coefficients(np.ones((2, 2, 2))),
        "weight has shape (2, 2, 2)",
    ),
    _c(
        "models.mechanisms",
        "weight empty",
        lambda: LinearMechanism.from_coefficients([]),
        "weight has shape (1, 0)",
    ),
    _c(
        "models.mechanisms",
        "weight int array",
        lambda: LinearMechanism.from_coefficients(np.array([[1, 2]])),
        "weight has dtype int64",
    ),
    _c(
        "models.mechanisms",
        "bias nan",
        lambda: LinearMechanism.from_coefficients([[1.0]], bias=NAN),
        "bias contains 1 NaN or inf",
    ),
    _c(
        "models.mechanisms",
        "bias too long",
        lambda: LinearMechanism.from_coefficients([[1.0]], bias=[1.0, 2.0]),
        "bias has 2 entries, expected 1",
    ),
    _c(
        "models.mechanisms",
        "coefficient sigma negative",
        lambda: LinearMechanism.from_coefficients([[1.0]], sigma=-1.0),
        "sigma must be > 0",
    ),
    _c(
        "models.mechanisms",
        "coefficient sigma inf",
        lambda: LinearMechanism.from_coefficients([[1.0]], sigma=INF),
        "sigma contains 1 NaN or inf",
    ),
    _c(
        "models.mechanisms",
        "fn not callable",
        lambda: FunctionMechanism(5, 1),
        "fn must be callable, got int",
    ),
    _c(
        "models.mechanisms",
        "fn returns a float",
        lambda: FunctionMechanism(lambda z: 1.0, 1)(torch.zeros(2, 1)),
        "function mechanism returned float",
    ),
    _c(
        "models.mechanisms",
        "fn returns nan",
        lambda: FunctionMechanism(lambda z: z * NAN, 1)(torch.zeros(2, 1)),
        "function mechanism returned NaN or inf",
    ),
    _c(
        "models.mechanisms",
        "input wrong dim",
        lambda: LinearMechanism(1, seed=0)(torch.ones(4, 3)),
        "last dim 3, expected 1",
    ),
    _c(
        "models.mechanisms",
        "input int tensor",
        lambda: LinearMechanism(1, seed=0)(torch.ones(2, 1, dtype=torch.int64)),
        "mechanism input has dtype torch.int64",
    ),
    _c(
        "models.mechanisms",
        "input str",
        lambda: LinearMechanism(1, seed=0)("abc"),
        "mechanism input is not numeric",
    ),
    _c("models.mechanisms", "set_sigma negative", lambda: MECH2.set_sigma([1.0, -1.0]), "sigma must be > 0"),
    _c("models.mechanisms", "set_sigma str", lambda: MECH2.set_sigma("a"), "sigma is not numeric"),
    _c(
        "models.mechanisms",
        "set_normalization scale 0",
        lambda: LinearMechanism(1, seed=0).set_normalization(0.0, 0.0, 0.0, 1.0),
        "in_scale must be > 0",
    ),
    _c(
        "models.mechanisms",
        "set_normalization nan",
        lambda: LinearMechanism(1, seed=0).set_normalization(NAN, 1.0, 0.0, 1.0),
        "in_loc contains 1 NaN or inf",
    ),
    _c(
        "models.mechanisms",
        "make config a str",
        lambda: make_mechanism("mlp"),
        "mechanism config must be a mapping",
    ),
    _c(
        "models.mechanisms",
        "make unknown kind",
        lambda: make_mechanism({"kind": "gp"}),
        "mechanism kind 'gp'",
    ),
    _c(
        "models.mechanisms",
        "make unknown key",
        lambda: make_mechanism({"kind": "mlp", "in_dim": 1, "depth": 3}),
        "unknown keys ['depth']",
    ),
    _c("models.mechanisms", "make no in_dim", lambda: make_mechanism({"kind": "linear"}), "needs 'in_dim'"),
    # WorldModel constructor
    _c("models.WorldModel", "graph a str", lambda: WorldModel("g"), "graph must be a CausalGraph, got str"),
    _c(
        "models.WorldModel",
        "mechanisms a list",
        lambda: WorldModel(chain_graph(), [MECH2]),
        "mechanisms must be a mapping",
    ),
    _c(
        "models.WorldModel",
        "mechanism for unknown",
        lambda: WorldModel(chain_graph(), {"w": LinearMechanism(1, seed=0)}),
        "unknown mechanism target 'w'",
    ),
    _c(
        "models.WorldModel",
        "mechanism for a root",
        lambda: WorldModel(chain_graph(), {"x": LinearMechanism(1, seed=0)}),
        "'x' is a root",
    ),
    _c(
        "models.WorldModel",
        "mechanism a str",
        lambda: WorldModel(chain_graph(), {"y": "linear"}),
        "mechanism for 'y' must be a Mechanism, got str",
    ),
    _c(
        "models.WorldModel",
        "mechanism wrong dims",
        lambda: WorldModel(chain_graph(), {"y": LinearMechanism(2, 1, seed=0)}),
        "maps 2 -> 1, expected 1",
    ),
    _c(
        "models.WorldModel", "unknown kind", lambda: WorldModel(chain_graph(), kind="gp"), "kind 'gp' unknown"
    ),
    _c(
        "models.WorldModel",
        "hidden an int",
        lambda: WorldModel(chain_graph(), hidden=32),
        "hidden must be a sequence",
    ),
    _c(
        "models.WorldModel",
        "hidden float",
        lambda: WorldModel(chain_graph(), hidden=(32.0,)),
        "hidden[0] must be",
    ),
    _c(
        "models.WorldModel",
        "unknown activation",
        lambda: WorldModel(chain_graph(), activation="sigmoid"),
        "activation 'sigmoid' unknown",
    ),
    _c(
        "models.WorldModel",
        "seed str",
        lambda: WorldModel(chain_graph(), seed="0"),
        "seed must be a non-negative int",
    ),
    _c(
        "models.WorldModel",
        "seed negative",
        lambda: WorldModel(chain_graph(), seed=-1),
        "seed must be a non-negative int",
    ),
    # WorldModel.predict
    _c(
        "models.predict",
        "int array",
        lambda: chain().predict({"x": np.array([[1]])}),
        "values['x'] has dtype int64",
    ),
    _c(
        "models.predict",
        "bool tensor",
        lambda: chain().predict({"x": torch.tensor([[True]])}),
        "values['x'] has dtype torch.bool",
    ),
    _c("models.predict", "str value", lambda: chain().predict({"x": "abc"}), "values['x'] is not numeric"),
    _c(
        "models.predict",
        "ragged list",
        lambda: chain().predict({"x": [[1.0], [2.0, 3.0]]}),
        "not a rectangular array",
    ),
    _c(
        "models.predict",
        "1-d column",
        lambda: chain().predict({"x": torch.ones(3)}),
        "values['x'] has shape (3,)",
    ),
    _c(
        "models.predict",
        "no rows",
        lambda: chain().predict({"x": torch.ones(0, 1)}),
        "values['x'] has shape (0, 1): no rows",
    ),
    _c(
        "models.predict",
        "nan value",
        lambda: chain().predict({"x": torch.tensor([[NAN]])}),
        "values['x'] contains 1 NaN",
    ),
    _c(
        "models.predict",
        "unknown name",
        lambda: chain().predict({"w": torch.ones(3, 1)}),
        "unknown variable in values 'w'",
    ),
    _c(
        "models.predict",
        "name an int",
        lambda: chain().predict({5: torch.ones(3, 1)}),
        "name must be a str, got 5",
    ),
    _c("models.predict", "values a list", lambda: chain().predict([1.0]), "values must be a mapping"),
    _c(
        "models.predict",
        "rows differ",
        lambda: chain().predict({"x": torch.ones(3, 1), "y": torch.ones(2, 1)}),
        "values['y'] has 2 rows, expected 3",
    ),
    _c("models.predict", "missing root", lambda: chain().predict({"y": torch.ones(2, 1)}), "missing ['x']"),
    _c(
        "models.predict",
        "unknown noise mode",
        lambda: chain().predict(FACTUAL, noise="bogus"),
        "noise 'bogus' unknown",
    ),
    _c(
        "models.predict",
        "noise an int",
        lambda: chain().predict(FACTUAL, noise=5),
        "noise must be 'expected', 'sampled'",
    ),
    _c(
        "models.predict",
        "noise nan",
        lambda: chain().predict(
            {"x": torch.ones(1, 1)}, noise={"y": torch.tensor([[NAN]]), "z": torch.zeros(1, 1)}
        ),
        "noise['y'] contains 1 NaN",
    ),
    _c(
        "models.predict",
        "noise for a root",
        lambda: chain().predict({"x": torch.ones(1, 1)}, noise={"x": torch.zeros(1, 1)}),
        "noise names ['x'] are not non-root",
    ),
    _c(
        "models.predict",
        "noise rows",
        lambda: chain().predict(
            {"x": torch.ones(1, 1)}, noise={"y": torch.zeros(3, 1), "z": torch.zeros(1, 1)}
        ),
        "noise['y'] has shape (3, 1)",
    ),
    _c(
        "models.predict",
        "noise incomplete",
        lambda: chain().predict({"x": torch.ones(1, 1)}, noise={"y": torch.zeros(1, 1)}),
        "no residual for 'z'",
    ),
    _c(
        "models.predict",
        "generator an int",
        lambda: chain().predict(FACTUAL, "sampled", 0),
        "generator must be a torch.Generator or None, got 0",
    ),
    _c(
        "models.predict",
        "grad a str",
        lambda: chain().predict(FACTUAL, grad="yes"),
        "grad must be True or False, got 'yes'",
    ),
    _c(
        "models.predict",
        "action above bounds",
        lambda: finger().predict({**FSTATE, "act.finger": torch.full((2, 1), 5.0)}),
        "values['act.finger'] has 2 entries outside the action bounds [-1, 0.33] (first: 5",
    ),
    _c(
        "models.predict",
        "action below bounds",
        lambda: finger().predict({**FSTATE, "act.finger": torch.full((2, 1), -1.001)}),
        "outside the action bounds [-1, 0.33] (first: -1.001",
    ),
    # WorldModel: other methods
    _c("models.WorldModel", "sample n 0", lambda: chain().sample(0), "n must be a positive int, got 0"),
    _c(
        "models.WorldModel",
        "sample n float",
        lambda: chain().sample(2.5),
        "n must be a positive int, got 2.5",
    ),
    _c(
        "models.WorldModel",
        "sample n bool",
        lambda: chain().sample(True),
        "n must be a positive int, got True",
    ),
    _c(
        "models.WorldModel",
        "sample numpy generator",
        lambda: chain().sample(3, np.random.default_rng(0)),
        "generator must be a torch.Generator",
    ),
    _c(
        "models.rollout",
        "action out of bounds",
        lambda: finger().rollout(FSTATE, {"act.finger": torch.full((2, 3, 1), 2.0)}),
        "inputs['act.finger'] has 6 entries outside the action bounds",
    ),
    _c(
        "models.rollout",
        "inputs without T",
        lambda: finger().rollout(FSTATE, {"act.finger": torch.zeros(2, 1)}),
        "expected (N, T, 1)",
    ),
    _c(
        "models.rollout",
        "missing initial",
        lambda: finger().rollout({}, {"act.finger": torch.zeros(2, 3, 1)}),
        "missing ['q_prev.finger']",
    ),
    _c(
        "models.rollout",
        "noise steps",
        lambda: finger().rollout(
            FSTATE,
            {"act.finger": torch.zeros(2, 3, 1)},
            noise={"dq.finger": torch.zeros(2, 2, 1), "q.finger": torch.zeros(2, 1)},
        ),
        "noise['dq.finger'] has 2 steps, expected 3",
    ),
    _c(
        "models.rollout",
        "action in initial",
        lambda: finger().rollout(
            {**FSTATE, "act.finger": torch.zeros(2, 1)}, {"act.finger": torch.zeros(2, 3, 1)}
        ),
        "rollout got values for ['act.finger']",
    ),
    _c(
        "models.WorldModel",
        "residuals incomplete",
        lambda: chain().residuals({"x": torch.ones(1, 1)}),
        "missing ['y', 'z']",
    ),
    _c(
        "models.WorldModel",
        "root prior of a non-root",
        lambda: chain().set_root_prior("y", 0, 1),
        "'y' is not a non-action root",
    ),
    _c(
        "models.WorldModel",
        "root prior scale negative",
        lambda: chain().set_root_prior("x", 0, -1),
        "positive finite scale",
    ),
    _c(
        "models.WorldModel",
        "root prior loc str",
        lambda: chain().set_root_prior("x", "a", 1),
        "root prior loc of 'x' is not numeric",
    ),
    _c(
        "models.WorldModel",
        "root prior too long",
        lambda: chain().set_root_prior("x", [0, 0], 1),
        "needs 1 loc and scale entries",
    ),
    _c("models.WorldModel", "root prior nan", lambda: chain().set_root_prior("x", NAN, 1), "finite loc"),
    _c("models.WorldModel", "mechanism of a root", lambda: chain().mechanism("x"), "'x' is a root"),
    # heteroscedastic and ensemble mechanisms, the member axis, predictive scales
    _c(
        "models.WorldModel",
        "members 0",
        lambda: WorldModel(xy_graph(), members=0),
        "members must be a positive int, got 0",
    ),
    _c(
        "models.WorldModel",
        "members float",
        lambda: WorldModel(xy_graph(), members=2.0),
        "members must be a positive int",
    ),
    _c("models.WorldModel", "kind gp", lambda: WorldModel(xy_graph(), kind="gp"), "kind 'gp' unknown"),
    _c(
        "models.WorldModel",
        "sigma of a heteroscedastic site",
        lambda: WorldModel(xy_graph(), seed=0, kind="hetero", hidden=(2,)).sigma("y"),
        "is heteroscedastic: its scale depends on the parents",
    ),
    _c(
        "models.WorldModel",
        "predict members a str",
        lambda: finger().predict(FIN, members="yes"),
        "members must be True or False",
    ),
    _c(
        "models.WorldModel",
        "rollout members a str",
        lambda: finger().rollout(FSTATE, {"act.finger": torch.zeros(2, 3, 1)}, members=1),
        "members must be True or False",
    ),
    _c(
        "models.WorldModel",
        "members of different sizes",
        lambda: WorldModel(
            chain_graph(),
            {
                "y": EnsembleMechanism([LinearMechanism(1, seed=0)] * 2),
                "z": EnsembleMechanism([LinearMechanism(1, seed=0)] * 3),
            },
        ).predict({"x": torch.zeros(1, 1)}, members=True),
        "ensembles have different sizes {'y': 2, 'z': 3}",
    ),
    _c(
        "models.WorldModel",
        "predict_scale component",
        lambda: finger().predict_scale(FIN, "all"),
        "component 'all' unknown",
    ),
    _c(
        "models.WorldModel",
        "predict_scale missing root",
        lambda: finger().predict_scale({"act.finger": torch.zeros(2, 1)}),
        "predict_scale needs a value for every root; missing ['q_prev.finger']",
    ),
    _c(
        "models.WorldModel",
        "predict_scale action out of bounds",
        lambda: finger().predict_scale({**FIN, "act.finger": torch.full((2, 1), 5.0)}),
        "outside the action bounds",
    ),
    _c("models.ensemble", "no members", lambda: EnsembleMechanism([]), "ensemble size must be >= 1), got 0"),
    _c(
        "models.ensemble",
        "replicate 0",
        lambda: EnsembleMechanism.replicate(MLPMechanism, 0),
        "members must be a positive int, got 0",
    ),
    _c(
        "models.ensemble",
        "members a mechanism",
        lambda: EnsembleMechanism(MECH2),
        "members must be a list of Mechanism",
    ),
    _c(
        "models.ensemble",
        "member a str",
        lambda: EnsembleMechanism([MECH2, "m"]),
        "ensemble member 1 must be a Mechanism",
    ),
    _c(
        "models.ensemble",
        "mixed kinds",
        lambda: EnsembleMechanism([MECH2, MLPMechanism(1, 2, seed=0)]),
        "ensemble members must be of one kind, got ['LinearMechanism', 'MLPMechanism']",
    ),
    _c(
        "models.ensemble",
        "mixed dims",
        lambda: EnsembleMechanism([MECH2, LinearMechanism(1, 1, seed=0)]),
        "ensemble members must share in_dim and out_dim, got (in, out) [(1, 1), (1, 2)]",
    ),
    _c(
        "models.ensemble",
        "nested",
        lambda: EnsembleMechanism([EnsembleMechanism([MECH2])]),
        "ensemble member 0 is itself an ensemble",
    ),
    _c(
        "models.ensemble",
        "paired parents of the wrong size",
        lambda: EnsembleMechanism([MECH2, MECH2]).member_loc_scale(torch.zeros(3, 4, 1), paired=True),
        "paired parents have shape (3, 4, 1), expected (2, ..., 1)",
    ),
    _c(
        "models.ensemble",
        "sigma of two members",
        lambda: EnsembleMechanism([MECH2, MECH2]).sigma,
        "an ensemble of 2 members has a scale that depends on the parents",
    ),
    _c(
        "models.ensemble",
        "config without members",
        lambda: make_mechanism({"kind": "ensemble"}),
        "ensemble config needs 'members', a non-empty list of configs",
    ),
    _c(
        "models.ensemble",
        "config nested",
        lambda: make_mechanism({"kind": "ensemble", "members": [{"kind": "ensemble", "members": []}]}),
        "ensemble member 0 is itself an ensemble",
    ),
    _c(
        "models.heteroscedastic",
        "bounds reversed",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=(2.0, -2.0)),
        "log_scale_bounds must have low < high, got (2, -2)",
    ),
    _c(
        "models.heteroscedastic",
        "bounds equal",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=(0.0, 0.0)),
        "log_scale_bounds must have low < high, got (0, 0)",
    ),
    _c(
        "models.heteroscedastic",
        "bound nan",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=(NAN, 1.0)),
        "log_scale_bounds[0] must be a finite number, got nan",
    ),
    _c(
        "models.heteroscedastic",
        "bound inf",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=(-1.0, INF)),
        "log_scale_bounds[1] must be a finite number, got inf",
    ),
    _c(
        "models.heteroscedastic",
        "bounds a number",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=1.0),
        "log_scale_bounds must be a pair (low, high)",
    ),
    _c(
        "models.heteroscedastic",
        "bounds a str",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds="ab"),
        "log_scale_bounds must be a pair (low, high)",
    ),
    _c(
        "models.heteroscedastic",
        "learn_bounds a str",
        lambda: HeteroscedasticMechanism(1, learn_bounds="no"),
        "learn_bounds must be True or False",
    ),
    _c(
        "models.heteroscedastic",
        "in_dim 0",
        lambda: HeteroscedasticMechanism(0),
        "in_dim must be a positive int, got 0",
    ),
    _c(
        "models.heteroscedastic",
        "activation unknown",
        lambda: HeteroscedasticMechanism(1, activation="gelu"),
        "activation 'gelu' unknown",
    ),
    _c(
        "models.heteroscedastic",
        "coefficients of the wrong shape",
        lambda: HeteroscedasticMechanism.from_coefficients([[1.0, 2.0]], log_scale_weight=[[1.0]]),
        "log_scale_weight has shape (1, 1), expected (1, 2)",
    ),
    _c(
        "models.heteroscedastic",
        "set_sigma",
        lambda: HeteroscedasticMechanism(1, seed=0).set_sigma(1.0),
        "it predicts its scale, which cannot be set",
    ),
    _c(
        "models.heteroscedastic",
        "config unknown key",
        lambda: make_mechanism({"kind": "hetero", "in_dim": 1, "sigma": 1.0}),
        "hetero mechanism config has unknown keys ['sigma']",
    ),
    _c("models.WorldModel", "mechanism name a list", lambda: chain().mechanism(["y"]), "name must be a str"),
    _c("models.WorldModel", "loc missing parent", lambda: chain().loc("y", {}), "missing ['x']"),
    _c("models.WorldModel", "bounds of unbounded", lambda: chain().bounds("x"), "variable 'x' has no bounds"),
    _c("models.WorldModel", "program without n", lambda: chain()(None), "needs data or n"),
    _c(
        "models.WorldModel",
        "program n float",
        lambda: chain()(None, 2.5),
        "n must be a positive int, got 2.5",
    ),
    _c(
        "models.WorldModel",
        "program action out of bounds",
        lambda: finger()({"act.finger": torch.full((2, 1), 3.0)}),
        "data['act.finger'] has 2 entries outside the action bounds",
    ),
    _c(
        "models.WorldModel",
        "with_graph a str",
        lambda: chain().with_graph("g"),
        "graph must be a CausalGraph",
    ),
    _c(
        "models.WorldModel",
        "with_graph dim change",
        lambda: chain().with_graph(CausalGraph([Variable("x", "observed", dim=2)])),
        "'x' has dim 2 in the new graph, expected 1",
    ),
    _c(
        "models.WorldModel",
        "copy priors from a str",
        lambda: chain().copy_root_priors_from("m"),
        "other must be a WorldModel",
    ),
    _c(
        "models.WorldModel",
        "copy priors of a non-root",
        lambda: chain().copy_root_priors_from(chain(), names=["y"]),
        "cannot copy root priors of ['y']",
    ),
    _c(
        "models.WorldModel",
        "copy priors names a str",
        lambda: chain().copy_root_priors_from(chain(), names="x"),
        "names must be a sequence of names",
    ),
]

# ---------------------------------------------------------------------------- inference
CASES += [
    # handlers
    _c(
        "inference.handlers",
        "Intervene list",
        lambda: Intervene([("x", 1.0)]),
        "interventions must be a mapping",
    ),
    _c("inference.handlers", "ReplayNoise str", lambda: ReplayNoise({"y": "a"}), "noise['y'] is not numeric"),
    _c(
        "inference.handlers",
        "ReplayNoise nan",
        lambda: ReplayNoise({"y": torch.tensor([[NAN]])}),
        "noise['y'] contains 1 NaN",
    ),
    _c(
        "inference.handlers",
        "ReplayNoise default",
        lambda: ReplayNoise(default="mean"),
        "default 'mean' unknown",
    ),
    _c(
        "inference.handlers",
        "ReplayNoise shape",
        lambda: ReplayNoise({"y": torch.zeros(2, 1)}, default="expected")(chain())(None, 3),
        "replayed noise for 'y' has shape (2, 1)",
    ),
    _c(
        "inference.handlers",
        "MeasurementScale zero",
        lambda: MeasurementScale({"z": np.array([0.0])}),
        "finite and > 0",
    ),
    _c(
        "inference.handlers",
        "MeasurementScale 3-d",
        lambda: MeasurementScale({"z": torch.ones(1, 1, 1)}),
        "has shape (1, 1, 1), expected (dim,) or (N, dim)",
    ),
    _c(
        "inference.handlers",
        "MeasurementScale list",
        lambda: MeasurementScale([1]),
        "scales must be a mapping",
    ),
    # do, simulate
    _c(
        "inference.do",
        "unknown target",
        lambda: do(chain(), {"nope": 1.0}),
        "unknown intervention target 'nope'",
    ),
    _c(
        "inference.do",
        "inf value",
        lambda: do(chain(), {"x": INF}),
        "intervention on 'x' contains NaN or inf",
    ),
    _c(
        "inference.do",
        "wrong dim",
        lambda: do(chain(), {"x": [1.0, 2.0]}),
        "intervention on 'x' has shape (2,)",
    ),
    _c("inference.do", "str value", lambda: do(chain(), {"x": "abc"}), "intervention on 'x' is not numeric"),
    _c(
        "inference.do", "bool value", lambda: do(chain(), {"x": True}), "intervention on 'x' is the bool True"
    ),
    _c(
        "inference.do",
        "int array",
        lambda: do(chain(), {"x": np.array([1])}),
        "intervention on 'x' has dtype int64",
    ),
    _c(
        "inference.do",
        "interventions a list",
        lambda: do(chain(), [("x", 1.0)]),
        "interventions must be a mapping",
    ),
    _c("inference.do", "model a str", lambda: do("model", {}), "model must be callable"),
    _c(
        "inference.do",
        "action out of bounds",
        lambda: do(finger(), {"act.finger": 2.0}),
        "interventions['act.finger'] has 1 entries outside the action bounds [-1, 0.33] (first: 2",
    ),
    _c(
        "inference.do",
        "shift leaves the bounds",
        lambda: do(finger(), {"act.finger": lambda a: a + 5.0})(None, 2),
        "shift intervention on 'act.finger' produced values outside its bounds",
    ),
    _c(
        "inference.do",
        "shift gives nan",
        lambda: do(chain(), {"x": lambda v: v * NAN})(None, 2),
        "shift intervention on 'x' produced NaN or inf",
    ),
    _c(
        "inference.do",
        "rows at run time",
        lambda: do(chain(), {"x": torch.zeros(2, 1)})(None, 3),
        "has shape (2, 1)",
    ),
    _c("inference.simulate", "n 0", lambda: simulate(chain(), 0), "n must be a positive int, got 0"),
    _c("inference.simulate", "n str", lambda: simulate(chain(), "5"), "n must be a positive int, got '5'"),
    _c(
        "inference.simulate",
        "seed negative",
        lambda: simulate(chain(), 5, seed=-1),
        "seed must be a non-negative int",
    ),
    _c(
        "inference.simulate",
        "seed float",
        lambda: simulate(chain(), 5, seed=1.5),
        "seed must be a non-negative int, got 1.5",
    ),
    _c(
        "inference.simulate",
        "interventions a list",
        lambda: simulate(chain(), 5, [1]),
        "interventions must be a mapping",
    ),
    # fit
    _c("inference.fit", "model a str", lambda: fit("model", xy()), "model must be a WorldModel, got 'model'"),
    _c("inference.fit", "data a list", lambda: fit(xy_model(), [1, 2]), "data must be a mapping"),
    _c("inference.fit", "data empty", lambda: fit(xy_model(), {}), "data is empty"),
    _c("inference.fit", "one row", lambda: fit(xy_model(), xy(1)), "at least 2 rows of data, got 1"),
    _c(
        "inference.fit",
        "unknown column",
        lambda: fit(xy_model(), xy(w=np.zeros((10, 1)))),
        "unknown variable in data 'w'",
    ),
    _c(
        "inference.fit",
        "int column",
        lambda: fit(xy_model(), xy(x=np.zeros((10, 1), int))),
        "data['x'] has dtype int64",
    ),
    _c(
        "inference.fit",
        "bool column",
        lambda: fit(xy_model(), xy(y=np.zeros((10, 1), bool))),
        "data['y'] has dtype bool",
    ),
    _c(
        "inference.fit", "str column", lambda: fit(xy_model(), xy(x=[["a"]] * 10)), "data['x'] is not numeric"
    ),
    _c(
        "inference.fit",
        "1-d column",
        lambda: fit(xy_model(), xy(x=np.zeros(10))),
        "data['x'] has shape (10,)",
    ),
    _c(
        "inference.fit",
        "rows differ",
        lambda: fit(xy_model(), xy(y=np.zeros((9, 1)))),
        "data['y'] has 9 rows, expected 10",
    ),
    _c(
        "inference.fit",
        "nan",
        lambda: fit(xy_model(), xy(y=np.full((10, 1), NAN))),
        "data['y'] contains 10 NaN",
    ),
    _c("inference.fit", "unknown loss", lambda: fit(xy_model(), xy(), loss="l1"), "loss 'l1' unknown"),
    _c(
        "inference.fit",
        "epochs str",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(epochs="10")),
        "epochs must be a positive int, got '10'",
    ),
    _c(
        "inference.fit",
        "epochs 0",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(epochs=0)),
        "epochs must be a positive int, got 0",
    ),
    _c(
        "inference.fit",
        "epochs float",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(epochs=2.0)),
        "epochs must be a positive int, got 2.0",
    ),
    _c(
        "inference.fit",
        "batch_size bool",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(batch_size=True)),
        "batch_size must be a positive int",
    ),
    _c(
        "inference.fit",
        "lr bool",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(lr=True)),
        "lr must be > 0 (a finite number), got True",
    ),
    _c(
        "inference.fit",
        "lr 0",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(lr=0)),
        "lr must be > 0 (a finite number), got 0",
    ),
    _c(
        "inference.fit",
        "lr inf",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(lr=INF)),
        "lr must be > 0 (a finite number), got inf",
    ),
    _c(
        "inference.fit",
        "lr str",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(lr="0.1")),
        "lr must be > 0 (a finite number), got '0.1'",
    ),
    _c(
        "inference.fit",
        "validation 1",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(validation=1.0)),
        "validation must be >= 0 and < 1 (a finite number), got 1",
    ),
    _c(
        "inference.fit",
        "validation negative",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(validation=-0.2)),
        "validation must be >= 0 and < 1 (a finite number), got -0.2",
    ),
    _c(
        "inference.fit",
        "validation nan",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(validation=NAN)),
        "validation must be",
    ),
    _c(
        "inference.fit",
        "validation leaves no rows",
        lambda: fit(xy_model(), xy(2), schedule=FitSchedule(validation=0.9)),
        "validation=0.9 of 2 rows leaves no training rows",
    ),
    _c(
        "inference.fit",
        "beta above 1",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(beta=1.5)),
        "beta must be >= 0 and <= 1",
    ),
    _c(
        "inference.fit",
        "beta negative",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(beta=-0.5)),
        "got -0.5",
    ),
    _c(
        "inference.fit",
        "beta str",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(beta="0.5")),
        "beta must be >= 0 and <= 1",
    ),
    _c(
        "inference.fit",
        "patience 0",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(patience=0)),
        "patience must be a positive int, got 0",
    ),
    _c(
        "inference.fit",
        "patience float",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(patience=2.0)),
        "patience must be a positive int",
    ),
    _c(
        "inference.fit",
        "patience without validation",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(patience=2, validation=0.0)),
        "patience=2 needs validation rows",
    ),
    _c(
        "inference.fit",
        "bootstrap str",
        lambda: fit(xy_model(), xy(), schedule=FitSchedule(bootstrap="yes")),
        "bootstrap must be True or False",
    ),
    _c(
        "inference.fit",
        "loss beta-nll",
        lambda: fit(xy_model(), xy(), loss="beta-nll"),
        "loss 'beta-nll' unknown",
    ),
    _c(
        "inference.fit",
        "mse for a heteroscedastic mechanism",
        lambda: fit(WorldModel(xy_graph(), seed=0, kind="hetero", hidden=(2,)), xy(), loss="mse"),
        "loss='mse' cannot train the scale of the heteroscedastic mechanisms of ['y']",
    ),
    _c(
        "inference.fit",
        "only fixed functions",
        lambda: fit(WorldModel(xy_graph(), {"y": FunctionMechanism(torch.sin, 1)}), xy()),
        "the mechanisms of ['y'] are fixed functions, which fit does not train",
    ),
    _c(
        "inference.fit",
        "a fixed function requested",
        lambda: fit(WorldModel(xy_graph(), {"y": FunctionMechanism(torch.sin, 1)}), xy(), variables=["y"]),
        "cannot fit 'y': its mechanism is a fixed FunctionMechanism",
    ),
    _c(
        "inference.fit",
        "seed str",
        lambda: fit(xy_model(), xy(), seed="1"),
        "seed must be a non-negative int, got '1'",
    ),
    _c(
        "inference.fit",
        "progress_bar str",
        lambda: fit(xy_model(), xy(), progress_bar="no"),
        "progress_bar must be True or False",
    ),
    _c(
        "inference.fit",
        "variables a str",
        lambda: fit(xy_model(), xy(), variables="y"),
        "variables must be a sequence of names",
    ),
    _c("inference.fit", "variables a root", lambda: fit(xy_model(), xy(), variables=["x"]), "'x' is a root"),
    _c(
        "inference.fit",
        "variables unknown",
        lambda: fit(xy_model(), xy(), variables=["w"]),
        "unknown variable to fit 'w'",
    ),
    _c(
        "inference.fit",
        "variables repeated",
        lambda: fit(xy_model(), xy(), variables=["y", "y"]),
        "names ['y'] more than once",
    ),
    _c("inference.fit", "variables empty", lambda: fit(xy_model(), xy(), variables=[]), "variables is empty"),
    _c(
        "inference.fit",
        "nothing trainable",
        lambda: fit(xy_model(), {"x": np.zeros((10, 1))}),
        "no mechanism can be trained",
    ),
    # predictive_check
    _c(
        "inference.calibration",
        "model a str",
        lambda: predictive_check("m", xy()),
        "model must be a WorldModel",
    ),
    _c(
        "inference.calibration",
        "level 1",
        lambda: predictive_check(xy_model(), xy(), level=1.0),
        "level must be > 0 and < 1",
    ),
    _c(
        "inference.calibration",
        "level str",
        lambda: predictive_check(xy_model(), xy(), level="0.9"),
        "got '0.9'",
    ),
    _c(
        "inference.calibration",
        "levels with 0",
        lambda: predictive_check(xy_model(), xy(), levels=[0.5, 0.0]),
        "levels[1] must be > 0 and < 1",
    ),
    _c(
        "inference.calibration",
        "levels empty",
        lambda: predictive_check(xy_model(), xy(), levels=()),
        "levels must be a non-empty",
    ),
    _c(
        "inference.calibration",
        "site a root",
        lambda: predictive_check(xy_model(), xy(), sites=["x"]),
        "site 'x' is a root",
    ),
    _c(
        "inference.calibration",
        "site without parents' column",
        lambda: predictive_check(xy_model(), {"y": np.zeros((3, 1))}, sites=["y"]),
        "cannot check site 'y': data has no column for ['x']",
    ),
    _c("inference.calibration", "no columns", lambda: predictive_check(xy_model(), {}), "data is empty"),
    # infer_state
    _c(
        "inference.infer_state",
        "model a str",
        lambda: infer_state("m", Z),
        "model must be a WorldModel or a program",
    ),
    _c(
        "inference.infer_state",
        "model without graph",
        lambda: infer_state(print, Z),
        "model must be a WorldModel",
    ),
    _c("inference.infer_state", "observed empty", lambda: infer_state(chain(), {}), "observed is empty"),
    _c(
        "inference.infer_state",
        "observed int",
        lambda: infer_state(chain(), {"z": np.array([[1]])}),
        "observed['z'] has dtype int64",
    ),
    _c(
        "inference.infer_state",
        "unknown guide",
        lambda: infer_state(chain(), Z, guide="flows"),
        "guide 'flows' unknown",
    ),
    _c(
        "inference.infer_state",
        "num_steps 0",
        lambda: infer_state(chain(), Z, num_steps=0),
        "num_steps must be a positive int",
    ),
    _c(
        "inference.infer_state",
        "num_steps float",
        lambda: infer_state(chain(), Z, num_steps=10.0),
        "num_steps must be a positive int",
    ),
    _c(
        "inference.infer_state",
        "num_particles bool",
        lambda: infer_state(chain(), Z, options=SVIOptions(num_particles=True)),
        "num_particles must be",
    ),
    _c(
        "inference.infer_state",
        "num_samples str",
        lambda: infer_state(chain(), Z, num_samples="9"),
        "num_samples must be",
    ),
    _c(
        "inference.infer_state",
        "lr negative",
        lambda: infer_state(chain(), Z, options=SVIOptions(lr=-1.0)),
        "lr must be > 0",
    ),
    _c(
        "inference.infer_state",
        "lr_final 0",
        lambda: infer_state(chain(), Z, options=SVIOptions(lr_final=0)),
        "lr_final must be > 0",
    ),
    _c(
        "inference.infer_state",
        "init_scale nan",
        lambda: infer_state(chain(), Z, options=SVIOptions(init_scale=NAN)),
        "init_scale must be > 0",
    ),
    _c(
        "inference.infer_state",
        "seed negative",
        lambda: infer_state(chain(), Z, seed=-1),
        "seed must be a non-negative int",
    ),
    _c(
        "inference.infer_state",
        "progress_bar int",
        lambda: infer_state(chain(), Z, progress_bar=1),
        "progress_bar must be True",
    ),
    _c(
        "inference.infer_state",
        "observed and intervened",
        lambda: infer_state(do(chain(), {"z": 1.0}), Z),
        "variables ['z'] are both observed and intervened on",
    ),
    _c(
        "inference.infer_state",
        "action out of bounds",
        lambda: infer_state(finger(), {"act.finger": torch.full((1, 1), 0.5), "q.finger": torch.zeros(1, 1)}),
        "observed['act.finger'] has 1 entries outside the action bounds",
    ),
    _c(
        "inference.infer_state",
        "nothing latent",
        lambda: infer_state(chain(), FACTUAL),
        "there is no latent site",
    ),
    _c(
        "inference.infer_state",
        "interval unknown",
        lambda: posterior().interval("w"),
        "'w' is not a latent site",
    ),
    _c(
        "inference.infer_state",
        "interval level",
        lambda: posterior().interval("y", level=1.5),
        "level must be > 0 and < 1",
    ),
    # counterfactual, abduct
    _c(
        "inference.counterfactual",
        "model a str",
        lambda: counterfactual("m", FACTUAL, {}),
        "model must be a WorldModel",
    ),
    _c(
        "inference.counterfactual",
        "interventions a str",
        lambda: counterfactual(chain(), FACTUAL, "x"),
        "interventions must be a mapping (one scenario) or a list of mappings, got 'x'",
    ),
    _c(
        "inference.counterfactual",
        "no scenario",
        lambda: counterfactual(chain(), FACTUAL, []),
        "empty sequence",
    ),
    _c(
        "inference.counterfactual",
        "scenario an int",
        lambda: counterfactual(chain(), FACTUAL, [{"x": 0.0}, 5]),
        "scenario 1 must be a mapping",
    ),
    _c(
        "inference.counterfactual",
        "unknown target",
        lambda: counterfactual(chain(), FACTUAL, {"w": 0.0}),
        "unknown intervention target 'w'",
    ),
    _c(
        "inference.counterfactual",
        "nan scenario",
        lambda: counterfactual(chain(), FACTUAL, {"x": NAN}),
        "intervention on 'x' contains NaN",
    ),
    _c(
        "inference.counterfactual",
        "factual empty",
        lambda: counterfactual(chain(), {}, {"x": 0.0}),
        "factual evidence is empty",
    ),
    _c(
        "inference.counterfactual",
        "factual shape",
        lambda: counterfactual(chain(), {"x": torch.ones(1)}, {"x": 0.0}),
        "factual['x'] has shape (1,)",
    ),
    _c(
        "inference.counterfactual",
        "scenario rows",
        lambda: counterfactual(chain(), FACTUAL, {"x": torch.zeros(2, 1)}),
        "intervention on 'x' has 2 rows, expected 1",
    ),
    _c(
        "inference.counterfactual",
        "num_samples 0",
        lambda: counterfactual(chain(), FACTUAL, {}, num_samples=0),
        "num_samples must be",
    ),
    _c(
        "inference.counterfactual",
        "seed str",
        lambda: counterfactual(chain(), FACTUAL, {}, seed="0"),
        "seed must be a non-negative int",
    ),
    _c(
        "inference.counterfactual",
        "shift gives nan",
        lambda: counterfactual(chain(), FACTUAL, [{"x": lambda v: v * NAN}]),
        "shift intervention on 'x' produced NaN or inf",
    ),
    _c(
        "inference.counterfactual",
        "action scenario out of bounds",
        lambda: counterfactual(finger(), finger_data(2), {"act.finger": 1.0}),
        "interventions['act.finger'] has 1 entries outside the action bounds",
    ),
    _c(
        "inference.counterfactual",
        "factual action out of bounds",
        lambda: counterfactual(finger(), {**finger_data(2), "act.finger": torch.full((2, 1), 4.0)}, {}),
        "factual['act.finger'] has 2 entries outside the action bounds",
    ),
    _c(
        "inference.counterfactual",
        "interval unknown",
        lambda: exact_cf().interval("w"),
        "unknown variable 'w'",
    ),
    _c(
        "inference.counterfactual",
        "interval level",
        lambda: exact_cf().interval("y", level=0),
        "level must be > 0 and < 1",
    ),
    _c("inference.abduct", "n 0", lambda: abduct(chain(), FACTUAL, 0), "n must be a positive int, got 0"),
    _c(
        "inference.abduct",
        "rows differ from n",
        lambda: abduct(chain(), FACTUAL, 2),
        "values['x'] has 1 rows, expected 2",
    ),
    # infer_action
    _c(
        "inference.infer_action",
        "model a str",
        lambda: infer_action("m", Q0, QT),
        "model must be a WorldModel",
    ),
    _c(
        "inference.infer_action",
        "unknown target",
        lambda: infer_action(plant(), Q0, {"w": torch.zeros(2, 1)}),
        "unknown variable in targets 'w'",
    ),
    _c(
        "inference.infer_action",
        "target rows",
        lambda: infer_action(plant(), Q0, {"q": torch.zeros(3, 1)}),
        "targets['q'] has 3 rows, expected 2",
    ),
    _c(
        "inference.infer_action",
        "target nan",
        lambda: infer_action(plant(), Q0, {"q": torch.full((2, 1), NAN)}),
        "targets['q'] contains 2 NaN",
    ),
    _c(
        "inference.infer_action",
        "target an action",
        lambda: infer_action(plant(), Q0, {"a": torch.zeros(2, 1)}),
        "target 'a' is an optimised action",
    ),
    _c(
        "inference.infer_action",
        "no targets",
        lambda: infer_action(plant(), Q0, None),
        "give targets or a log_preference",
    ),
    _c(
        "inference.infer_action",
        "actions not actions",
        lambda: infer_action(plant(), Q0, QT, actions=["q"]),
        "only actions can be optimised",
    ),
    _c(
        "inference.infer_action",
        "actions a str",
        lambda: infer_action(plant(), Q0, QT, actions="a"),
        "actions must be a sequence of names",
    ),
    _c(
        "inference.infer_action",
        "actions unknown",
        lambda: infer_action(plant(), Q0, QT, actions=["w"]),
        "unknown action 'w'",
    ),
    _c(
        "inference.infer_action",
        "unknown init",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(init="zero")),
        "init 'zero' unknown",
    ),
    _c(
        "inference.infer_action",
        "init an int",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(init=5)),
        "init must be 'midpoint', 'random' or a mapping",
    ),
    _c(
        "inference.infer_action",
        "init out of bounds",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(init={"a": torch.full((2, 1), 3.0)})),
        "init['a'] lies outside the bounds",
    ),
    _c(
        "inference.infer_action",
        "init unknown name",
        lambda: infer_action(
            plant(), Q0, QT, options=ActionOptions(init={"a": torch.zeros(2, 1), "b": torch.zeros(2, 1)})
        ),
        "init names ['b']",
    ),
    _c(
        "inference.infer_action",
        "steps 0",
        lambda: infer_action(plant(), Q0, QT, num_steps=0),
        "steps must be a positive int, got 0",
    ),
    _c(
        "inference.infer_action",
        "steps str",
        lambda: infer_action(plant(), Q0, QT, num_steps="200"),
        "steps must be a positive int, got '200'",
    ),
    _c(
        "inference.infer_action",
        "lr 0",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(lr=0.0)),
        "lr must be > 0",
    ),
    _c(
        "inference.infer_action",
        "scale 0",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(scale=0.0)),
        "scale must be > 0",
    ),
    _c(
        "inference.infer_action",
        "scale str",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(scale="1")),
        "scale must be > 0 (a finite number), got '1'",
    ),
    _c(
        "inference.infer_action",
        "scale unknown name",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(scale={"w": 1.0})),
        "unknown names ['w'], missing ['q']",
    ),
    _c(
        "inference.infer_action",
        "scale nan",
        lambda: infer_action(plant(), Q0, QT, options=ActionOptions(scale={"q": NAN})),
        "scale['q'] must be > 0",
    ),
    _c(
        "inference.infer_action",
        "log_preference an int",
        lambda: infer_action(plant(), Q0, options=ActionOptions(log_preference=5)),
        "log_preference must be callable",
    ),
    _c(
        "inference.infer_action",
        "log_preference returns a float",
        lambda: infer_action(plant(), Q0, options=ActionOptions(log_preference=lambda p: 1.0), num_steps=1),
        "log_preference returned 1.0 (float)",
    ),
    _c(
        "inference.infer_action",
        "log_preference wrong shape",
        lambda: infer_action(
            plant(), Q0, options=ActionOptions(log_preference=lambda p: p["q"]), num_steps=1
        ),
        "log_preference returned (2, 1), expected a tensor of shape (2,)",
    ),
    _c(
        "inference.infer_action",
        "fixed action out of bounds",
        lambda: infer_action(
            finger(), {**FSTATE, "act.finger": torch.full((2, 1), 5.0)}, {"q.finger": torch.zeros(2, 1)}
        ),
        "state['act.finger'] has 2 entries outside the action bounds",
    ),
    _c(
        "inference.infer_action",
        "seed negative",
        lambda: infer_action(plant(), Q0, QT, seed=-2),
        "seed must be a non-negative int",
    ),
    _c(
        "inference.infer_action",
        "state int",
        lambda: infer_action(plant(), {"q_prev": np.zeros((2, 1), int)}, QT),
        "state['q_prev'] has dtype int64",
    ),
    _c(
        "inference.infer_action",
        "state and targets empty",
        lambda: infer_action(plant(), {}, {}),
        "state and targets are empty",
    ),
    _c(
        "inference.infer_action",
        "preference targets empty",
        lambda: gaussian_log_preference({}),
        "targets is empty",
    ),
    _c(
        "inference.infer_action",
        "preference scale negative",
        lambda: gaussian_log_preference(QT, -1.0),
        "scale must be > 0",
    ),
    _c(
        "inference.infer_action",
        "preference targets a str",
        lambda: gaussian_log_preference("q"),
        "targets must be a mapping",
    ),
    # curiosity
    _c("inference.curiosity", "low >= high", lambda: CuriositySampler(1.0, 0.0), "need finite low < high"),
    _c(
        "inference.curiosity",
        "low str",
        lambda: CuriositySampler("0", 1.0),
        "low must be a finite number, got '0'",
    ),
    _c(
        "inference.curiosity",
        "high inf",
        lambda: CuriositySampler(0.0, INF),
        "high must be a finite number, got inf",
    ),
    _c(
        "inference.curiosity",
        "bins 1",
        lambda: CuriositySampler(0.0, 1.0, bins=1),
        "bins must be an int >= 2, got 1",
    ),
    _c(
        "inference.curiosity",
        "bins float",
        lambda: CuriositySampler(0.0, 1.0, bins=2.5),
        "bins must be an int >= 2, got 2.5",
    ),
    _c(
        "inference.curiosity",
        "bins bool",
        lambda: CuriositySampler(0.0, 1.0, bins=True),
        "bins must be an int >= 2, got True",
    ),
    _c(
        "inference.curiosity",
        "alpha inf",
        lambda: CuriositySampler(0.0, 1.0, alpha=INF),
        "alpha must be >= 0 (a finite number), got inf",
    ),
    _c(
        "inference.curiosity",
        "alpha nan",
        lambda: CuriositySampler(0.0, 1.0, alpha=NAN),
        "alpha must be >= 0 (a finite number), got nan",
    ),
    _c(
        "inference.curiosity",
        "alpha negative",
        lambda: CuriositySampler(0.0, 1.0, alpha=-1.0),
        "alpha must be >= 0",
    ),
    _c("inference.curiosity", "sigma 0", lambda: CuriositySampler(0.0, 1.0, sigma=0.0), "sigma must be > 0"),
    _c(
        "inference.curiosity",
        "sigma inf",
        lambda: CuriositySampler(0.0, 1.0, sigma=INF),
        "sigma must be > 0 (a finite number), got inf",
    ),
    _c(
        "inference.curiosity",
        "unknown form",
        lambda: CuriositySampler(0.0, 1.0, form="log"),
        "form 'log' unknown",
    ),
    _c("inference.curiosity", "eps 0", lambda: CuriositySampler(0.0, 1.0, eps=0.0), "eps must be > 0"),
    _c(
        "inference.curiosity",
        "eps str",
        lambda: CuriositySampler(0.0, 1.0, eps="1"),
        "eps must be > 0 (a finite number), got '1'",
    ),
    _c(
        "inference.curiosity",
        "fit nan",
        lambda: CuriositySampler(0.0, 1.0).fit([0.1, NAN]),
        "values contains 1 NaN",
    ),
    _c(
        "inference.curiosity",
        "fit 2 columns",
        lambda: CuriositySampler(0.0, 1.0).fit(np.zeros((3, 2))),
        "expected (N,) or (N, 1)",
    ),
    _c(
        "inference.curiosity",
        "fit strings",
        lambda: CuriositySampler(0.0, 1.0).fit(["a"]),
        "values is not numeric",
    ),
    _c(
        "inference.curiosity",
        "fit bools",
        lambda: CuriositySampler(0.0, 1.0).fit(np.array([True])),
        "values has dtype bool",
    ),
    _c(
        "inference.curiosity",
        "sample no rng",
        lambda: CuriositySampler(0.0, 1.0).sample(None, [0.5]),
        "rng must be a numpy.random.Generator",
    ),
    _c(
        "inference.curiosity",
        "sample no size",
        lambda: CuriositySampler(0.0, 1.0).sample(np.random.default_rng(0)),
        "give current values or a positive size",
    ),
    _c(
        "inference.curiosity",
        "sample size float",
        lambda: CuriositySampler(0.0, 1.0).sample(np.random.default_rng(0), size=2.5),
        "size must be a positive int, got 2.5",
    ),
    _c(
        "inference.curiosity",
        "sample size and current",
        lambda: CuriositySampler(0.0, 1.0).sample(np.random.default_rng(0), [0.5], size=3),
        "size is only used without current",
    ),
    _c(
        "inference.curiosity",
        "density strings",
        lambda: CuriositySampler(0.0, 1.0).density(["x"]),
        "current is not numeric",
    ),
    _c(
        "inference.curiosity",
        "occupancy bins 0",
        lambda: occupancy([0.1], 0.0, 1.0, bins=0),
        "bins must be an int >= 2, got 0",
    ),
    _c(
        "inference.curiosity",
        "occupancy low >= high",
        lambda: occupancy([0.1], 1.0, 0.0),
        "need finite low < high",
    ),
    _c(
        "inference.curiosity",
        "entropy of nothing",
        lambda: normalized_entropy([], 0.0, 1.0),
        "no values to compute an entropy",
    ),
    # discover, admissible_parents, shd
    _c(
        "inference.discover",
        "variables a str",
        lambda: discover("xy", discovery_data()),
        "expected a CausalGraph or a sequence of Variable",
    ),
    _c(
        "inference.discover",
        "data a list",
        lambda: discover(scalars("x", "y"), [1]),
        "data must be a mapping",
    ),
    _c(
        "inference.discover",
        "missing column",
        lambda: discover(scalars("x", "y", "z"), discovery_data()),
        "missing ['z']",
    ),
    _c(
        "inference.discover",
        "str column",
        lambda: discover(scalars("x", "y"), discovery_data(x=[["a"]] * 40)),
        "data['x'] is not numeric",
    ),
    _c(
        "inference.discover",
        "int column",
        lambda: discover(scalars("x", "y"), discovery_data(x=np.zeros((40, 1), int))),
        "data['x'] has dtype int64",
    ),
    _c(
        "inference.discover",
        "nan column",
        lambda: discover(scalars("x", "y"), discovery_data(x=np.full((40, 1), NAN))),
        "data['x'] contains NaN",
    ),
    _c(
        "inference.discover",
        "5 rows",
        lambda: discover(scalars("x", "y"), discovery_data(5)),
        "at least 8 rows, got 5",
    ),
    _c(
        "inference.discover",
        "1-d column",
        lambda: discover(scalars("x", "y"), discovery_data(x=np.zeros(40))),
        "data['x'] has shape (40,)",
    ),
    _c(
        "inference.discover",
        "float mask",
        lambda: discover(scalars("x", "y"), discovery_data(), intervened={"x": np.zeros(40)}),
        "intervened['x'] has shape (40,) and dtype float64, expected (40,) bool",
    ),
    _c(
        "inference.discover",
        "mask unknown name",
        lambda: discover(scalars("x", "y"), discovery_data(), intervened={"w": np.zeros(40, bool)}),
        "intervened names unknown variable 'w'",
    ),
    _c(
        "inference.discover",
        "intervened a list",
        lambda: discover(scalars("x", "y"), discovery_data(), intervened=[1]),
        "intervened must be a mapping",
    ),
    _c(
        "inference.discover",
        "unknown sparsify",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(sparsify="lasso")),
        "sparsify 'lasso' unknown",
    ),
    _c(
        "inference.discover",
        "min_gain str",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(min_gain="10")),
        "min_gain must be a finite number, got '10'",
    ),
    _c(
        "inference.discover",
        "prune above gain",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(prune_nats=20.0)),
        "prune_nats (20.0) must be <= min_gain",
    ),
    _c(
        "inference.discover",
        "max_parents 0",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(max_parents=0)),
        "max_parents must be a positive int, got 0",
    ),
    _c(
        "inference.discover",
        "max_moves float",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(max_moves=1.5)),
        "max_moves must be a positive int, got 1.5",
    ),
    _c(
        "inference.discover",
        "features negative",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(features=-1)),
        "features must be a non-negative int, got -1",
    ),
    _c(
        "inference.discover",
        "folds 1",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(folds=1)),
        "folds must be an int >= 2, got 1",
    ),
    _c(
        "inference.discover",
        "ridge str",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(ridge="1")),
        "ridge must be a number > 0",
    ),
    _c(
        "inference.discover",
        "ridge empty",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(ridge=[])),
        "ridge is an empty sequence",
    ),
    _c(
        "inference.discover",
        "ridge negative",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(ridge=(0.1, -1.0))),
        "ridge[1] must be > 0",
    ),
    _c(
        "inference.discover",
        "length 0",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(length=0.0)),
        "length must be > 0",
    ),
    _c(
        "inference.discover",
        "floor 0",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(floor=0.0)),
        "floor must be > 0",
    ),
    _c(
        "inference.discover",
        "repeats 0",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(repeats=0)),
        "repeats must be a positive int, got 0",
    ),
    _c(
        "inference.discover",
        "gated unknown key",
        lambda: discover(scalars("x", "y"), discovery_data(), options=DiscoveryOptions(gated={"depth": 2})),
        "gated has unknown keys ['depth']",
    ),
    _c(
        "inference.discover",
        "gated steps 0",
        lambda: discover(
            scalars("x", "y"),
            discovery_data(),
            options=DiscoveryOptions(features=4, sparsify="gated", gated={"steps": 0}),
        ),
        "steps must be a positive int, got 0",
    ),
    _c(
        "inference.discover",
        "seed negative",
        lambda: discover(scalars("x", "y"), discovery_data(), seed=-1),
        "seed must be a non-negative int",
    ),
    _c(
        "inference.discover",
        "required a str",
        lambda: discover(scalars("x", "y"), discovery_data(), required="xy"),
        "required must be a sequence of (parent, child) pairs",
    ),
    _c(
        "inference.discover",
        "required unknown",
        lambda: discover(scalars("x", "y"), discovery_data(), required=[("x", "w")]),
        "required edge ('x', 'w') is not a (parent, child) pair of known variables",
    ),
    _c(
        "inference.admissible",
        "tiers a str",
        lambda: admissible_parents(scalars("x", "y"), tiers="xy"),
        "tiers must be a sequence",
    ),
    _c(
        "inference.admissible",
        "tier an int",
        lambda: admissible_parents(scalars("x", "y"), tiers=[["x"], 5]),
        "tier 1 is 5 (int)",
    ),
    _c(
        "inference.admissible",
        "name in two tiers",
        lambda: admissible_parents(scalars("x", "y"), tiers=[["x"], ["x"]]),
        "'x' is in tiers 0 and 1",
    ),
    _c(
        "inference.admissible",
        "forbidden of one",
        lambda: admissible_parents(scalars("x", "y"), forbidden=[("x",)]),
        "edge ('x',) is not a (parent, child) pair",
    ),
    _c(
        "inference.admissible",
        "variables an int",
        lambda: admissible_parents(5),
        "expected a CausalGraph or a sequence of Variable, got 5",
    ),
    _c(
        "inference.shd",
        "learnt an int",
        lambda: shd(5, []),
        "learnt must be a sequence of (parent, child) pairs",
    ),
    _c(
        "inference.shd",
        "triple",
        lambda: shd([("a", "b", "c")], []),
        "edge ('a', 'b', 'c') is not a (parent, child) pair",
    ),
    # design
    _c(
        "inference.design",
        "result a str",
        lambda: choose_interventions("r", {}, 1),
        "result must be a DiscoveryResult",
    ),
    _c(
        "inference.design",
        "budget negative",
        lambda: choose_interventions(fake_discovery(), {}, -1),
        "budget must be a non-negative int, got -1",
    ),
    _c(
        "inference.design",
        "budget float",
        lambda: choose_interventions(fake_discovery(), {}, 2.5),
        "budget must be a non-negative int, got 2.5",
    ),
    _c(
        "inference.design",
        "margin of a non-edge",
        lambda: structure_uncertainty(fake_discovery(), {("a", "b"): 1.0}),
        "margins names ('a', 'b'), which is not an edge",
    ),
    # context
    _c(
        "inference.context",
        "model a str",
        lambda: active_subgraph("m", {}, ["q"]),
        "model must be a WorldModel",
    ),
    _c(
        "inference.context",
        "targets a str",
        lambda: active_subgraph(*finger_samples(), "q.finger"),
        "targets must be a sequence of names",
    ),
    _c(
        "inference.context",
        "targets empty",
        lambda: active_subgraph(*finger_samples(), []),
        "targets is empty",
    ),
    _c(
        "inference.context",
        "unknown target",
        lambda: active_subgraph(*finger_samples(), ["w"]),
        "unknown target 'w'",
    ),
    _c(
        "inference.context",
        "threshold negative",
        lambda: active_subgraph(*finger_samples(), ["q.finger"], -1.0),
        "threshold must be >= 0",
    ),
    _c(
        "inference.context",
        "threshold nan",
        lambda: active_subgraph(*finger_samples(), ["q.finger"], NAN),
        "threshold must be >= 0 (a finite number), got nan",
    ),
    _c(
        "inference.context",
        "samples incomplete",
        lambda: active_subgraph(finger(), FIN, ["q.finger"]),
        "context needs a value for every variable; missing",
    ),
    _c(
        "inference.context",
        "sub a str",
        lambda: subgraph_model(finger(), "sub"),
        "sub must be an ActiveSubgraph",
    ),
    _c(
        "inference.context",
        "relevance targets a str",
        lambda: target_relevance(finger(), FIN, "q.finger"),
        "targets must be a sequence of names",
    ),
    # ensemble
    _c("inference.ensemble", "one member", lambda: Ensemble([member()]), "at least 2 members, got 1"),
    _c(
        "inference.ensemble",
        "members a str",
        lambda: Ensemble("ab"),
        "members must be a sequence of WorldModel",
    ),
    _c(
        "inference.ensemble",
        "member a str",
        lambda: Ensemble([member(), "x"]),
        "ensemble member 1 must be a WorldModel",
    ),
    _c(
        "inference.ensemble",
        "different graphs",
        lambda: Ensemble([member(), chain()]),
        "must share one graph",
    ),
    _c("inference.ensemble", "make not callable", lambda: Ensemble.create(5), "make must be callable"),
    _c(
        "inference.ensemble",
        "k 1",
        lambda: Ensemble.create(lambda s: member(), k=1),
        "k must be an int >= 2, got 1",
    ),
    _c(
        "inference.ensemble",
        "k float",
        lambda: Ensemble.create(lambda s: member(), k=2.0),
        "k must be an int >= 2, got 2.0",
    ),
    _c(
        "inference.ensemble",
        "fit unknown kwarg",
        lambda: ensemble().fit({"a": torch.zeros(4, 1), "y": torch.zeros(4, 1)}, epoch=3),
        "fit_kwargs has unknown keys ['epoch']",
    ),
    _c(
        "inference.ensemble",
        "fit one row",
        lambda: ensemble().fit({"a": torch.zeros(1, 1), "y": torch.zeros(1, 1)}),
        "at least 2 rows, got 1",
    ),
    _c(
        "inference.ensemble",
        "target a root",
        lambda: ensemble().information({"a": torch.zeros(1, 1)}, ["a"]),
        "target 'a' is a root",
    ),
    _c(
        "inference.ensemble",
        "targets a str",
        lambda: ensemble().information({"a": torch.zeros(1, 1)}, "y"),
        "targets must be a sequence of names",
    ),
    _c(
        "inference.ensemble", "no candidates", lambda: ensemble().choose({}, {}, ["y"]), "candidates is empty"
    ),
    _c(
        "inference.ensemble",
        "spread 0",
        lambda: ensemble().choose({}, {"a": torch.zeros(2, 3, 1)}, ["y"], spread=0.0),
        "spread must be > 0",
    ),
    _c(
        "inference.ensemble",
        "candidate out of bounds",
        lambda: ensemble().choose({}, {"a": torch.full((2, 3, 1), 2.0)}, ["y"]),
        "values['a'] has 6 entries outside the action bounds",
    ),
    # metalearn
    _c(
        "inference.metalearn",
        "monitor model a str",
        lambda: ResidualMonitor("m"),
        "model must be a WorldModel",
    ),
    _c(
        "inference.metalearn",
        "window 0",
        lambda: ResidualMonitor(finger(), window=0),
        "window must be a positive int, got 0",
    ),
    _c(
        "inference.metalearn",
        "window float",
        lambda: ResidualMonitor(finger(), window=1.5),
        "window must be a positive int, got 1.5",
    ),
    _c(
        "inference.metalearn",
        "threshold 0",
        lambda: ResidualMonitor(finger(), threshold=0),
        "threshold must be > 0",
    ),
    _c(
        "inference.metalearn",
        "patience bool",
        lambda: ResidualMonitor(finger(), patience=True),
        "patience must be a positive int, got True",
    ),
    _c(
        "inference.metalearn",
        "tolerance of a root",
        lambda: ResidualMonitor(finger(), tolerance={"act.finger": 0.1}),
        "'act.finger', a root",
    ),
    _c(
        "inference.metalearn",
        "tolerance 0",
        lambda: ResidualMonitor(finger(), tolerance={"dq.finger": 0.0}),
        "tolerance['dq.finger'] must be",
    ),
    _c(
        "inference.metalearn",
        "tolerance str",
        lambda: ResidualMonitor(finger(), tolerance={"dq.finger": "a"}),
        "tolerance['dq.finger'] is not numeric",
    ),
    _c(
        "inference.metalearn",
        "tolerance unknown",
        lambda: ResidualMonitor(finger(), tolerance={"w": 1.0}),
        "unknown tolerance variable 'w'",
    ),
    _c(
        "inference.metalearn",
        "update incomplete",
        lambda: ResidualMonitor(finger()).update(finger(), FIN),
        "values needs rows of every variable; missing",
    ),
    _c(
        "inference.metalearn",
        "revise variables a str",
        lambda: revise(finger(), finger_data(), "dq.finger"),
        "variables must be a sequence of names",
    ),
    _c(
        "inference.metalearn",
        "revise unknown kind",
        lambda: revise(finger(), finger_data(), ["dq.finger"], kinds=("grow",)),
        "unknown revision kinds ['grow']",
    ),
    _c(
        "inference.metalearn",
        "revise a root",
        lambda: revise(finger(), finger_data(), ["act.finger"]),
        "'act.finger' is a root",
    ),
    _c(
        "inference.metalearn",
        "revise val_fraction 1",
        lambda: revise(finger(), finger_data(), ["dq.finger"], val_fraction=1.0),
        "val_fraction must be > 0 and < 1",
    ),
    _c(
        "inference.metalearn",
        "revise unknown fit kwarg",
        lambda: revise(finger(), finger_data(), ["dq.finger"], fit_kwargs={"epoch": 1}),
        "fit_kwargs has unknown keys ['epoch']",
    ),
    _c(
        "inference.metalearn",
        "revise hidden 0",
        lambda: revise(finger(), finger_data(), ["dq.finger"], hidden=(0,)),
        "hidden[0] must be a positive int",
    ),
    _c(
        "inference.metalearn",
        "revise data incomplete",
        lambda: revise(finger(), FIN, ["dq.finger"]),
        "revise needs rows of every variable; missing",
    ),
    _c(
        "inference.metalearn",
        "split component out of range",
        lambda: SplitMechanism(LinearMechanism(1, seed=0), LinearMechanism(1, seed=1), 5, 0.0),
        "split component 5 out of range",
    ),
    _c(
        "inference.metalearn",
        "split regime a str",
        lambda: SplitMechanism("a", LinearMechanism(1, seed=1), 0, 0.0),
        "low regime must be a Mechanism",
    ),
    _c(
        "inference.metalearn",
        "split cut nan",
        lambda: SplitMechanism(LinearMechanism(1, seed=0), LinearMechanism(1, seed=1), 0, NAN),
        "cut must be a finite number, got nan",
    ),
    # rewire
    _c("inference.rewire", "model a str", lambda: rewire("m", finger_graph()), "model must be a WorldModel"),
    _c(
        "inference.rewire",
        "graph a str",
        lambda: rewire(finger(), "g", refit="none"),
        "graph must be a CausalGraph",
    ),
    _c(
        "inference.rewire",
        "unknown refit",
        lambda: rewire(finger(), finger_graph(), finger_data(), refit="some"),
        "refit 'some' unknown",
    ),
    _c("inference.rewire", "no data", lambda: rewire(finger(), finger_graph()), "data is needed to refit"),
    _c(
        "inference.rewire",
        "epochs str",
        lambda: rewire(finger(), finger_graph(), finger_data(), schedule=FitSchedule(epochs="3")),
        "epochs must be a positive int, got '3'",
    ),
    _c(
        "inference.rewire",
        "unknown fit kwarg",
        lambda: rewire(finger(), finger_graph(), finger_data(), epoch=3),
        "fit_kwargs has unknown keys ['epoch']",
    ),
    _c(
        "inference.rewire",
        "mask shape",
        lambda: rewire(finger(), finger_graph(), finger_data(), intervened=cut(np.zeros(3, bool))),
        "intervened['dq.finger'] has shape (3,)",
    ),
    _c(
        "inference.rewire",
        "mask unknown name",
        lambda: rewire(finger(), finger_graph(), finger_data(), intervened={"w": np.zeros(16, bool)}),
        "intervened names ['w']",
    ),
    _c(
        "inference.rewire",
        "seed negative",
        lambda: rewire(finger(), finger_graph(), refit="none", seed=-1),
        "seed must be a non-negative int",
    ),
    _c("inference.rewire", "data empty", lambda: rewire(finger(), finger_graph(), {}), "data is empty"),
]


def binary() -> WorldModel:
    """X -> T (Bernoulli) -> Y, and X -> C (3 categories)."""
    graph = CausalGraph([Variable(n, "observed") for n in "xtcy"], [("x", "t"), ("x", "c"), ("t", "y")])
    return WorldModel(graph, seed=0, kind="linear", discrete={"t": 2, "c": 3})


def bin_data(**cols: Any) -> dict[str, Any]:
    return {
        "x": np.zeros((4, 1)),
        "t": np.ones((4, 1)),
        "c": np.full((4, 1), 2.0),
        "y": np.zeros((4, 1)),
        **cols,
    }


HALF = np.array([[0.0], [0.5], [1.0], [1.0]])
THREE = np.full((4, 1), 3.0)

CASES += [
    # discrete sites
    _c(
        "models.WorldModel",
        "discrete unknown site",
        lambda: WorldModel(chain_graph(), discrete={"w": 2}),
        "discrete site 'w'",
    ),
    _c(
        "models.WorldModel",
        "discrete K of 1",
        lambda: WorldModel(chain_graph(), discrete={"y": 1}),
        "number of categories",
    ),
    _c(
        "models.WorldModel",
        "discrete action",
        lambda: WorldModel(finger_graph(), discrete={"act.finger": 2}),
        "'act.finger' is an action",
    ),
    _c(
        "models.WorldModel",
        "discrete K disagrees with the mechanism",
        lambda: WorldModel(chain_graph(), {"y": CategoricalMechanism(1, 3, seed=0)}, discrete={"y": 4}),
        "discrete['y'] = 4 categories, but its mechanism has 3",
    ),
    _c(
        "models.WorldModel",
        "discrete with a continuous mechanism",
        lambda: WorldModel(chain_graph(), {"y": LinearMechanism(1, seed=0)}, discrete={"y": 2}),
        "its mechanism is a continuous LinearMechanism",
    ),
    _c(
        "models.discrete",
        "categories of 1",
        lambda: CategoricalMechanism(1, 1),
        "categories must be an int >= 2, got 1",
    ),
    _c(
        "models.discrete", "sigma of a Bernoulli", lambda: BernoulliMechanism(1, seed=0).sigma, "has no sigma"
    ),
    _c(
        "models.WorldModel",
        "Bernoulli observed with 0.5 (program)",
        lambda: binary()(bin_data(t=HALF)),
        "data['t'] has 1 values that are not 0 or 1 (a Bernoulli site) (first: 0.5 at index (1, 0))",
    ),
    _c(
        "inference.fit",
        "Bernoulli observed with 0.5",
        lambda: fit(binary(), bin_data(t=HALF)),
        "data['t'] has 1 values that are not 0 or 1",
    ),
    _c(
        "inference.infer_state",
        "Bernoulli observed with 0.5",
        lambda: infer_state(binary(), {"x": HALF, "t": HALF}),
        "observed['t'] has 1 values that are not 0 or 1",
    ),
    _c(
        "inference.counterfactual",
        "Bernoulli observed with 0.5",
        lambda: counterfactual(binary(), bin_data(t=HALF), {"x": 0.0}),
        "factual['t'] has 1 values that are not 0 or 1",
    ),
    _c(
        "inference.counterfactual",
        "categorical value outside range",
        lambda: counterfactual(binary(), bin_data(c=THREE), {"x": 0.0}),
        "factual['c'] has 4 values that are not an integer code 0 .. 2 (first: 3 at index (0, 0))",
    ),
    _c(
        "inference.fit",
        "categorical value outside range",
        lambda: fit(binary(), bin_data(c=-THREE)),
        "data['c'] has 4 values that are not an integer code 0 .. 2 (first: -3",
    ),
    _c(
        "inference.do",
        "categorical intervention outside range",
        lambda: do(binary(), {"c": 3.0}),
        "intervention on 'c' has 1 values that are not an integer code 0 .. 2",
    ),
    _c(
        "inference.do",
        "Bernoulli intervention of 0.5",
        lambda: do(binary(), {"t": 0.5}),
        "intervention on 't' has 1 values that are not 0 or 1",
    ),
    _c(
        "inference.do",
        "shift intervention leaves the categories",
        lambda: simulate(binary(), 3, {"c": lambda c: c + 5}),
        "intervention on 'c' has 3 values that are not an integer code 0 .. 2",
    ),
    _c(
        "models.WorldModel",
        "residuals of a discrete site",
        lambda: binary().residuals(
            {k: torch.as_tensor(v, dtype=torch.float32) for k, v in bin_data().items()}
        ),
        "residuals are not determined for the discrete sites ['t', 'c']",
    ),
    # posteriors and composition
    _c(
        "inference.infer_state",
        "guide unknown",
        lambda: infer_state(chain(), Z, guide="laplace"),
        "guide 'laplace' unknown; expected one of",
    ),
    _c(
        "inference.infer_state",
        "options of another guide",
        lambda: infer_state(chain(), Z, guide="grid", options=SVIOptions()),
        "guide='grid' takes options=GridOptions(...), got",
    ),
    _c(
        "inference.infer_state",
        "SVI options for importance sampling",
        lambda: infer_state(chain(), Z, guide="importance", options=SVIOptions(lr=0.1)),
        "guide='importance' takes options=ImportanceOptions(...), got SVIOptions(",
    ),
    _c("inference.SVIOptions", "lr zero", lambda: SVIOptions(lr=0.0), "lr must be > 0"),
    _c(
        "inference.GridOptions",
        "max_dims 3",
        lambda: GridOptions(max_dims=3),
        "max_dims must be 1 or 2, got 3",
    ),
    _c(
        "inference.ImportanceOptions",
        "too few particles",
        lambda: ImportanceOptions(num_particles=2),
        "num_particles must be an int >= 10, got 2",
    ),
    _c(
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
    _c(
        "inference.counterfactual",
        "posterior not a StateResult",
        lambda: counterfactual(chain(), {"x": torch.ones(1, 1), "z": Z["z"]}, {"x": 0.0}, posterior={"y": 1}),
        "posterior must be a StateResult from infer_state",
    ),
    _c(
        "inference.counterfactual",
        "guide unknown",
        lambda: counterfactual(chain(), Z, {"x": 0.0}, guide="exact"),
        "guide 'exact' unknown",
    ),
    _c(
        "inference.handlers",
        "handler naming a site of another graph",
        lambda: MeasurementScale({"q": torch.ones(1)})(chain()),
        "MeasurementScale names ['q'], which are not sites of the program",
    ),
    _c(
        "inference.Program",
        "a Program of something else",
        lambda: Program(lambda d, n: None),
        "a Program wraps a WorldModel",
    ),
    _c(
        "inference.fit",
        "schedule a dict",
        lambda: fit(xy_model(), xy(), schedule={"epochs": 1}),
        "schedule must be a FitSchedule or None",
    ),
    _c(
        "inference.FitSchedule",
        "validation 1",
        lambda: FitSchedule(validation=1.0),
        "validation must be >= 0 and < 1",
    ),
    _c(
        "inference.infer_action",
        "options a dict",
        lambda: infer_action(finger(), FSTATE, {"q.finger": np.zeros((2, 1))}, options={"lr": 0.1}),
        "options must be an ActionOptions or None",
    ),
]

RAW = (TypeError, KeyError, RuntimeError, AttributeError, IndexError, AssertionError, NotImplementedError)


_OUTCOMES: dict[int, BaseException | None] = {}


def _outcome(case: BadInput) -> BaseException | None:
    """The exception ``case.call()`` raises (None if it returns); computed once per case."""
    key = id(case)
    if key not in _OUTCOMES:
        try:
            case.call()
        except Exception as err:  # the raised error is what the tests inspect
            _OUTCOMES[key] = err
        else:
            _OUTCOMES[key] = None
    return _OUTCOMES[key]


def test_case_ids_are_unique_and_there_are_enough():
    keys = [(c.area, c.id) for c in CASES]
    assert len(keys) == len(set(keys)), [k for k, n in Counter(keys).items() if n > 1]
    assert len(CASES) >= 130, len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[f"{c.area}: {c.id}" for c in CASES])
def test_bad_input_raises_a_specific_error_naming_the_value(case):
    err = _outcome(case)
    assert err is not None, f"{case.id}: no error raised"
    assert type(err) is case.error, f"{case.id}: {type(err).__name__}: {err}"
    assert case.match in str(err), f"{case.id}: {case.match!r} not in {str(err)!r}"


def test_no_bad_input_gets_a_raw_library_error():
    raw = []
    for case in CASES:
        err = _outcome(case)
        if isinstance(err, RAW) or err is None:
            raw.append(f"{case.area}: {case.id}: {type(err).__name__}: {err}")
    assert raw == [], "\n".join(raw)
