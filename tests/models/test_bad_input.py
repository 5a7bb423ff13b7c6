"""Bad input to the public API of ``models`` raises a specific error naming the value.

Every entry of :data:`CASES` is one bad call (:class:`tests.bad_input.BadInput`): the exact
exception type it must raise and a substring of the message that names the offending value or
parameter. The shared builders and checks are in ``tests/bad_input.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from models import (
    BernoulliMechanism,
    CategoricalMechanism,
    CausalGraph,
    EnsembleMechanism,
    FunctionMechanism,
    GatedMechanism,
    HeteroscedasticMechanism,
    LinearMechanism,
    MLPMechanism,
    ModelFileError,
    Variable,
    WorldModel,
    chain_graph,
    finger_graph,
    joint_chain_graph,
    pushing_graph,
    random_graph,
)
from models.mechanisms import make_mechanism
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

RANGES = {"j": (-1.0, 1.0)}


def gated_graph(switch_parent: bool = True) -> CausalGraph:
    """b -> x, and the switch c -> x (c is a root)."""
    edges = [("b", "x"), ("c", "x")] if switch_parent else [("b", "x")]
    return CausalGraph([Variable(n, "observed") for n in ("b", "c", "x")], edges)


def gated(switch: str = "c", discrete: dict | None = None, parent: bool = True) -> WorldModel:
    width = 2 if parent else 1
    mech = GatedMechanism(switch, LinearMechanism.from_coefficients([[1.0] * width]), 0.01)
    return WorldModel(gated_graph(parent), {"x": mech}, discrete={"c": 2} if discrete is None else discrete)


def gated_file_without(branch: str) -> None:
    """Save a gated model, drop one key of its site's config (checksum fixed), and load it."""
    import json
    import tempfile

    from models import io as model_io
    from models import load, save

    path = save(gated(), tempfile.mkdtemp() + "/gated.npz")
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    doc = json.loads(arrays.pop("__meta__").tobytes())
    del doc["meta"]["mechanisms"]["x"][branch]
    doc["checksum"] = model_io._checksum(doc["format"], doc["versions"], doc["meta"], arrays)
    arrays["__meta__"] = np.frombuffer(json.dumps(doc).encode(), dtype=np.uint8)
    np.savez(path, **arrays)
    load(path)


MECH2 = LinearMechanism.from_coefficients([[1.0], [2.0]])  # 1 -> 2


CASES: list[BadInput] = [
    # Variable
    bad("models.Variable", "name not a str", lambda: Variable(5, "latent"), "variable name 5"),
    bad("models.Variable", "unknown role", lambda: Variable("x", "bogus"), "role 'bogus'"),
    bad("models.Variable", "role a list", lambda: Variable("x", ["latent"]), "role ['latent']"),
    bad(
        "models.Variable",
        "dim float",
        lambda: Variable("x", "latent", dim=2.0),
        "dim must be a positive int, got 2.0",
    ),
    bad(
        "models.Variable",
        "dim bool",
        lambda: Variable("x", "latent", dim=True),
        "dim must be a positive int, got True",
    ),
    bad(
        "models.Variable",
        "dim str",
        lambda: Variable("x", "latent", dim="2"),
        "dim must be a positive int, got '2'",
    ),
    bad(
        "models.Variable",
        "lag bool",
        lambda: Variable("x", "latent", lag=True),
        "lag must be 0 or 1, got True",
    ),
    bad("models.Variable", "lag 2", lambda: Variable("x", "latent", lag=2), "lag must be 0 or 1, got 2"),
    bad(
        "models.Variable",
        "bounds strings",
        lambda: Variable("a", "action", bounds=("0", "1")),
        "bounds side '0'",
    ),
    bad(
        "models.Variable",
        "bounds bool",
        lambda: Variable("a", "action", bounds=(True, 2)),
        "bounds side True",
    ),
    bad(
        "models.Variable",
        "bounds inf",
        lambda: Variable("a", "action", bounds=(0, INF)),
        "bounds must be finite",
    ),
    bad(
        "models.Variable",
        "bounds nan",
        lambda: Variable("a", "action", bounds=(NAN, 1)),
        "bounds must be finite",
    ),
    bad("models.Variable", "bounds reversed", lambda: Variable("a", "action", bounds=(1, 0)), "low >= high"),
    bad(
        "models.Variable", "bounds scalar", lambda: Variable("a", "action", bounds=5), "bounds must be a pair"
    ),
    bad(
        "models.Variable",
        "bounds wrong dim",
        lambda: Variable("a", "action", dim=2, bounds=([0], [1])),
        "expected 2",
    ),
    bad(
        "models.Variable",
        "action without bounds",
        lambda: Variable("a", "action"),
        "action 'a' has no bounds",
    ),
    bad(
        "models.Variable",
        "unit not str",
        lambda: Variable("x", "latent", unit=3),
        "unit must be a str, got 3",
    ),
    bad(
        "models.Variable",
        "lag_of at lag 0",
        lambda: Variable("x", "latent", lag_of="q"),
        "lag_of is only meaningful",
    ),
    bad(
        "models.Variable",
        "lag_of not str",
        lambda: Variable("x", "latent", lag=1, lag_of=3),
        "lag_of must be",
    ),
    bad(
        "models.Variable",
        "from_dict not mapping",
        lambda: Variable.from_dict("x"),
        "variable entry must be a mapping",
    ),
    bad(
        "models.Variable",
        "from_dict unknown field",
        lambda: Variable.from_dict({"name": "x", "role": "latent", "colour": 1}),
        "unknown variable fields ['colour']",
    ),
    bad(
        "models.Variable",
        "from_dict no role",
        lambda: Variable.from_dict({"name": "x"}),
        "needs 'name' and 'role'",
    ),
    # CausalGraph
    bad(
        "models.CausalGraph",
        "variables a str",
        lambda: CausalGraph("ab"),
        "variables must be a sequence of Variable",
    ),
    bad(
        "models.CausalGraph",
        "variables an int",
        lambda: CausalGraph(5),
        "variables must be a sequence of Variable",
    ),
    bad(
        "models.CausalGraph",
        "variable a str",
        lambda: CausalGraph(["x"]),
        "expected Variable instances, got str",
    ),
    bad(
        "models.CausalGraph",
        "duplicate names",
        lambda: CausalGraph(scalars("x", "x")),
        "duplicate variable name 'x'",
    ),
    bad(
        "models.CausalGraph",
        "cycle",
        lambda: CausalGraph(scalars("x", "y"), [("x", "y"), ("y", "x")]),
        "graph has a cycle",
    ),
    bad(
        "models.CausalGraph",
        "edges a str",
        lambda: CausalGraph(scalars("x", "y"), "xy"),
        "edges must be a sequence",
    ),
    bad(
        "models.CausalGraph",
        "edge of one",
        lambda: CausalGraph(scalars("x"), [("x",)]),
        "edge ('x',) is not a",
    ),
    bad(
        "models.CausalGraph",
        "edge an int",
        lambda: CausalGraph(scalars("x"), [5]),
        "edge 5 is not a (parent, child)",
    ),
    bad(
        "models.CausalGraph",
        "edge end a list",
        lambda: CausalGraph(scalars("x", "y"), [(["x"], "y")]),
        "expected variable names",
    ),
    bad(
        "models.CausalGraph",
        "edge unknown name",
        lambda: CausalGraph(scalars("x"), [("x", "w")]),
        "names unknown variable 'w'",
    ),
    bad(
        "models.CausalGraph", "self-loop", lambda: CausalGraph(scalars("x"), [("x", "x")]), "self-loop on 'x'"
    ),
    bad(
        "models.CausalGraph",
        "action with a parent",
        lambda: CausalGraph([*scalars("x"), Variable("a", "action", bounds=(0, 1))], [("x", "a")]),
        "action 'a' has parent 'x'",
    ),
    bad(
        "models.CausalGraph",
        "confidence a str",
        lambda: chain_graph().with_confidence({("x", "y"): "0.5"}),
        "confidence of edge 'x' -> 'y' must be a finite number, got '0.5'",
    ),
    bad(
        "models.CausalGraph",
        "confidence above 1",
        lambda: chain_graph().with_confidence({("x", "y"): 1.5}),
        "is 1.5, expected [0, 1]",
    ),
    bad(
        "models.CausalGraph",
        "confidence nan",
        lambda: chain_graph().with_confidence({("x", "y"): NAN}),
        "confidence of edge 'x' -> 'y' must be a finite number, got nan",
    ),
    bad(
        "models.CausalGraph",
        "confidence of a non-edge",
        lambda: chain_graph().with_confidence({("x", "z"): 0.5}),
        "confidence given for ('x', 'z')",
    ),
    bad(
        "models.CausalGraph",
        "confidence not a mapping",
        lambda: CausalGraph(scalars("x"), [], [("x", "y")]),
        "confidence must be a mapping",
    ),
    bad("models.CausalGraph", "getitem unknown", lambda: chain_graph()["w"], "unknown variable 'w'"),
    bad("models.CausalGraph", "getitem int", lambda: chain_graph()[5], "variable name must be a str, got 5"),
    bad(
        "models.CausalGraph", "parents of a list", lambda: chain_graph().parents(["x"]), "name must be a str"
    ),
    bad(
        "models.CausalGraph",
        "by_role unknown",
        lambda: chain_graph().by_role("bogus"),
        "role 'bogus' unknown",
    ),
    bad(
        "models.CausalGraph",
        "with_edges a str",
        lambda: chain_graph().with_edges(add=["xz"]),
        "edge 'xz' is not a",
    ),
    bad(
        "models.CausalGraph",
        "with_edges remove missing",
        lambda: chain_graph().with_edges(remove=[("x", "z")]),
        "cannot remove edges [('x', 'z')]",
    ),
    bad(
        "models.CausalGraph",
        "edge_confidence non-edge",
        lambda: chain_graph().edge_confidence("x", "z"),
        "'x' -> 'z'",
    ),
    bad("models.CausalGraph", "from_json not str", lambda: CausalGraph.from_json(5), "must be a str, got 5"),
    bad("models.CausalGraph", "from_json malformed", lambda: CausalGraph.from_json("{"), "malformed"),
    bad(
        "models.CausalGraph",
        "from_dict no variables",
        lambda: CausalGraph.from_dict({"format": "pal.causal_graph/1"}),
        "no 'variables' entry",
    ),
    bad(
        "models.CausalGraph",
        "from_dict variables a str",
        lambda: CausalGraph.from_dict({"format": "pal.causal_graph/1", "variables": "x", "edges": []}),
        "'variables' must be a list",
    ),
    bad(
        "models.CausalGraph", "from_dict format", lambda: CausalGraph.from_dict({"format": "x"}), "format 'x'"
    ),
    bad(
        "models.CausalGraph",
        "from_dict variable entry",
        lambda: CausalGraph.from_dict({"format": "pal.causal_graph/1", "variables": [5], "edges": []}),
        "variable entry 5 is not a mapping",
    ),
    # presets
    bad(
        "models.presets",
        "joints a str",
        lambda: joint_chain_graph("ab", {"a": (0, 1)}),
        "joints must be a sequence",
    ),
    bad("models.presets", "joints empty", lambda: joint_chain_graph([], {}), "joints is empty"),
    bad(
        "models.presets",
        "joints repeated",
        lambda: joint_chain_graph(["j", "j"], RANGES),
        "names ['j'] more than once",
    ),
    bad(
        "models.presets",
        "action_ranges a list",
        lambda: joint_chain_graph(["j"], [(-1, 1)]),
        "action_ranges must be a mapping",
    ),
    bad(
        "models.presets",
        "missing action range",
        lambda: joint_chain_graph(["a"], RANGES),
        "no action range for joints ['a']",
    ),
    bad(
        "models.presets",
        "unknown variant",
        lambda: joint_chain_graph(["j"], RANGES, "x"),
        "graph variant 'x' unknown",
    ),
    bad(
        "models.presets",
        "q_ranges unknown joint",
        lambda: joint_chain_graph(["j"], RANGES, q_ranges={"k": (0, 1)}),
        "q_ranges names unknown joints ['k']",
    ),
    bad("models.presets", "finger joint an int", lambda: finger_graph(joint=5), "joint must be a joint name"),
    bad(
        "models.presets", "random_graph d float", lambda: random_graph(2.5), "d must be an int >= 2, got 2.5"
    ),
    bad("models.presets", "random_graph d 1", lambda: random_graph(1), "d must be an int >= 2, got 1"),
    bad(
        "models.presets",
        "random_graph expected_parents nan",
        lambda: random_graph(4, expected_parents=NAN),
        "expected_parents must be",
    ),
    bad(
        "models.presets",
        "random_graph seed -1",
        lambda: random_graph(4, seed=-1),
        "seed must be a non-negative int",
    ),
    bad(
        "models.presets",
        "random_graph seed str",
        lambda: random_graph(4, seed="0"),
        "seed must be a non-negative int",
    ),
    bad(
        "models.presets",
        "pushing objects a str",
        lambda: pushing_graph(["j"], RANGES, objects="box"),
        "objects must be",
    ),
    bad(
        "models.presets",
        "pushing object_dim float",
        lambda: pushing_graph(["j"], RANGES, object_dim=2.0),
        "object_dim must be 2 or 3, got 2.0",
    ),
    bad(
        "models.presets",
        "pushing clash",
        lambda: pushing_graph(["j"], RANGES, objects=("hand",)),
        "clash with the hand",
    ),
    # mechanisms
    bad("models.mechanisms", "in_dim 0", lambda: MLPMechanism(0), "in_dim must be a positive int, got 0"),
    bad(
        "models.mechanisms",
        "in_dim float",
        lambda: MLPMechanism(2.5),
        "in_dim must be a positive int, got 2.5",
    ),
    bad(
        "models.mechanisms",
        "in_dim bool",
        lambda: MLPMechanism(True),
        "in_dim must be a positive int, got True",
    ),
    bad(
        "models.mechanisms",
        "out_dim str",
        lambda: LinearMechanism(1, "1"),
        "out_dim must be a positive int, got '1'",
    ),
    bad("models.mechanisms", "hidden an int", lambda: MLPMechanism(1, hidden=5), "hidden must be a sequence"),
    bad(
        "models.mechanisms",
        "hidden float",
        lambda: MLPMechanism(1, hidden=(2.5,)),
        "hidden[0] must be a positive int",
    ),
    bad(
        "models.mechanisms",
        "hidden 0",
        lambda: MLPMechanism(1, hidden=(0,)),
        "hidden[0] must be a positive int, got 0",
    ),
    bad(
        "models.mechanisms",
        "unknown activation",
        lambda: MLPMechanism(1, activation="nope"),
        "activation 'nope' unknown",
    ),
    bad(
        "models.mechanisms",
        "activation a list",
        lambda: MLPMechanism(1, activation=["tanh"]),
        "activation ['tanh']",
    ),
    bad("models.mechanisms", "sigma 0", lambda: MLPMechanism(1, sigma=0), "sigma must be > 0"),
    bad(
        "models.mechanisms",
        "sigma inf",
        lambda: LinearMechanism(1, sigma=INF),
        "sigma must be > 0 (a finite number), got inf",
    ),
    bad(
        "models.mechanisms",
        "sigma str",
        lambda: LinearMechanism(1, sigma="1"),
        "sigma must be > 0 (a finite number), got '1'",
    ),
    bad(
        "models.mechanisms",
        "seed negative",
        lambda: MLPMechanism(1, seed=-3),
        "seed must be a non-negative int, got -3",
    ),
    bad(
        "models.mechanisms",
        "seed float",
        lambda: LinearMechanism(1, seed=1.5),
        "seed must be a non-negative int, got 1.5",
    ),
    bad(
        "models.mechanisms",
        "weight nan",
        lambda: LinearMechanism.from_coefficients([[NAN]]),
        "weight contains 1 NaN or inf",
    ),
    bad(
        "models.mechanisms",
        "weight str",
        lambda: LinearMechanism.from_coefficients("abc"),
        "weight is not numeric",
    ),
    bad(
        "models.mechanisms",
        "weight 3-d",
        lambda: LinearMechanism.from_coefficients(np.ones((2, 2, 2))),
        "weight has shape (2, 2, 2)",
    ),
    bad(
        "models.mechanisms",
        "weight empty",
        lambda: LinearMechanism.from_coefficients([]),
        "weight has shape (1, 0)",
    ),
    bad(
        "models.mechanisms",
        "weight int array",
        lambda: LinearMechanism.from_coefficients(np.array([[1, 2]])),
        "weight has dtype int64",
    ),
    bad(
        "models.mechanisms",
        "bias nan",
        lambda: LinearMechanism.from_coefficients([[1.0]], bias=NAN),
        "bias contains 1 NaN or inf",
    ),
    bad(
        "models.mechanisms",
        "bias too long",
        lambda: LinearMechanism.from_coefficients([[1.0]], bias=[1.0, 2.0]),
        "bias has 2 entries, expected 1",
    ),
    bad(
        "models.mechanisms",
        "coefficient sigma negative",
        lambda: LinearMechanism.from_coefficients([[1.0]], sigma=-1.0),
        "sigma must be > 0",
    ),
    bad(
        "models.mechanisms",
        "coefficient sigma inf",
        lambda: LinearMechanism.from_coefficients([[1.0]], sigma=INF),
        "sigma contains 1 NaN or inf",
    ),
    bad(
        "models.mechanisms",
        "fn not callable",
        lambda: FunctionMechanism(5, 1),
        "fn must be callable, got int",
    ),
    bad(
        "models.mechanisms",
        "fn returns a float",
        lambda: FunctionMechanism(lambda z: 1.0, 1)(torch.zeros(2, 1)),
        "function mechanism returned float",
    ),
    bad(
        "models.mechanisms",
        "fn returns nan",
        lambda: FunctionMechanism(lambda z: z * NAN, 1)(torch.zeros(2, 1)),
        "function mechanism returned NaN or inf",
    ),
    bad(
        "models.mechanisms",
        "input wrong dim",
        lambda: LinearMechanism(1, seed=0)(torch.ones(4, 3)),
        "last dim 3, expected 1",
    ),
    bad(
        "models.mechanisms",
        "input int tensor",
        lambda: LinearMechanism(1, seed=0)(torch.ones(2, 1, dtype=torch.int64)),
        "mechanism input has dtype torch.int64",
    ),
    bad(
        "models.mechanisms",
        "input str",
        lambda: LinearMechanism(1, seed=0)("abc"),
        "mechanism input is not numeric",
    ),
    bad("models.mechanisms", "set_sigma negative", lambda: MECH2.set_sigma([1.0, -1.0]), "sigma must be > 0"),
    bad("models.mechanisms", "set_sigma str", lambda: MECH2.set_sigma("a"), "sigma is not numeric"),
    bad(
        "models.mechanisms",
        "set_normalization scale 0",
        lambda: LinearMechanism(1, seed=0).set_normalization(0.0, 0.0, 0.0, 1.0),
        "in_scale must be > 0",
    ),
    bad(
        "models.mechanisms",
        "set_normalization nan",
        lambda: LinearMechanism(1, seed=0).set_normalization(NAN, 1.0, 0.0, 1.0),
        "in_loc contains 1 NaN or inf",
    ),
    bad(
        "models.mechanisms",
        "make config a str",
        lambda: make_mechanism("mlp"),
        "mechanism config must be a mapping",
    ),
    bad(
        "models.mechanisms",
        "make unknown kind",
        lambda: make_mechanism({"kind": "gp"}),
        "mechanism kind 'gp'",
    ),
    bad(
        "models.mechanisms",
        "make unknown key",
        lambda: make_mechanism({"kind": "mlp", "in_dim": 1, "depth": 3}),
        "unknown keys ['depth']",
    ),
    bad("models.mechanisms", "make no in_dim", lambda: make_mechanism({"kind": "linear"}), "needs 'in_dim'"),
    # WorldModel constructor
    bad("models.WorldModel", "graph a str", lambda: WorldModel("g"), "graph must be a CausalGraph, got str"),
    bad(
        "models.WorldModel",
        "mechanisms a list",
        lambda: WorldModel(chain_graph(), [MECH2]),
        "mechanisms must be a mapping",
    ),
    bad(
        "models.WorldModel",
        "mechanism for unknown",
        lambda: WorldModel(chain_graph(), {"w": LinearMechanism(1, seed=0)}),
        "unknown mechanism target 'w'",
    ),
    bad(
        "models.WorldModel",
        "mechanism for a root",
        lambda: WorldModel(chain_graph(), {"x": LinearMechanism(1, seed=0)}),
        "'x' is a root",
    ),
    bad(
        "models.WorldModel",
        "mechanism a str",
        lambda: WorldModel(chain_graph(), {"y": "linear"}),
        "mechanism for 'y' must be a Mechanism, got str",
    ),
    bad(
        "models.WorldModel",
        "mechanism wrong dims",
        lambda: WorldModel(chain_graph(), {"y": LinearMechanism(2, 1, seed=0)}),
        "maps 2 -> 1, expected 1",
    ),
    bad(
        "models.WorldModel", "unknown kind", lambda: WorldModel(chain_graph(), kind="gp"), "kind 'gp' unknown"
    ),
    bad(
        "models.WorldModel",
        "hidden an int",
        lambda: WorldModel(chain_graph(), hidden=32),
        "hidden must be a sequence",
    ),
    bad(
        "models.WorldModel",
        "hidden float",
        lambda: WorldModel(chain_graph(), hidden=(32.0,)),
        "hidden[0] must be",
    ),
    bad(
        "models.WorldModel",
        "unknown activation",
        lambda: WorldModel(chain_graph(), activation="sigmoid"),
        "activation 'sigmoid' unknown",
    ),
    bad(
        "models.WorldModel",
        "seed str",
        lambda: WorldModel(chain_graph(), seed="0"),
        "seed must be a non-negative int",
    ),
    bad(
        "models.WorldModel",
        "seed negative",
        lambda: WorldModel(chain_graph(), seed=-1),
        "seed must be a non-negative int",
    ),
    # WorldModel.predict
    bad(
        "models.predict",
        "int array",
        lambda: chain().predict({"x": np.array([[1]])}),
        "values['x'] has dtype int64",
    ),
    bad(
        "models.predict",
        "bool tensor",
        lambda: chain().predict({"x": torch.tensor([[True]])}),
        "values['x'] has dtype torch.bool",
    ),
    bad("models.predict", "str value", lambda: chain().predict({"x": "abc"}), "values['x'] is not numeric"),
    bad(
        "models.predict",
        "ragged list",
        lambda: chain().predict({"x": [[1.0], [2.0, 3.0]]}),
        "not a rectangular array",
    ),
    bad(
        "models.predict",
        "1-d column",
        lambda: chain().predict({"x": torch.ones(3)}),
        "values['x'] has shape (3,)",
    ),
    bad(
        "models.predict",
        "no rows",
        lambda: chain().predict({"x": torch.ones(0, 1)}),
        "values['x'] has shape (0, 1): no rows",
    ),
    bad(
        "models.predict",
        "nan value",
        lambda: chain().predict({"x": torch.tensor([[NAN]])}),
        "values['x'] contains 1 NaN",
    ),
    bad(
        "models.predict",
        "unknown name",
        lambda: chain().predict({"w": torch.ones(3, 1)}),
        "unknown variable in values 'w'",
    ),
    bad(
        "models.predict",
        "name an int",
        lambda: chain().predict({5: torch.ones(3, 1)}),
        "name must be a str, got 5",
    ),
    bad("models.predict", "values a list", lambda: chain().predict([1.0]), "values must be a mapping"),
    bad(
        "models.predict",
        "rows differ",
        lambda: chain().predict({"x": torch.ones(3, 1), "y": torch.ones(2, 1)}),
        "values['y'] has 2 rows, expected 3",
    ),
    bad("models.predict", "missing root", lambda: chain().predict({"y": torch.ones(2, 1)}), "missing ['x']"),
    bad(
        "models.predict",
        "unknown noise mode",
        lambda: chain().predict(FACTUAL, noise="bogus"),
        "noise 'bogus' unknown",
    ),
    bad(
        "models.predict",
        "noise an int",
        lambda: chain().predict(FACTUAL, noise=5),
        "noise must be 'expected', 'sampled'",
    ),
    bad(
        "models.predict",
        "noise nan",
        lambda: chain().predict(
            {"x": torch.ones(1, 1)}, noise={"y": torch.tensor([[NAN]]), "z": torch.zeros(1, 1)}
        ),
        "noise['y'] contains 1 NaN",
    ),
    bad(
        "models.predict",
        "noise for a root",
        lambda: chain().predict({"x": torch.ones(1, 1)}, noise={"x": torch.zeros(1, 1)}),
        "noise names ['x'] are not non-root",
    ),
    bad(
        "models.predict",
        "noise rows",
        lambda: chain().predict(
            {"x": torch.ones(1, 1)}, noise={"y": torch.zeros(3, 1), "z": torch.zeros(1, 1)}
        ),
        "noise['y'] has shape (3, 1)",
    ),
    bad(
        "models.predict",
        "noise incomplete",
        lambda: chain().predict({"x": torch.ones(1, 1)}, noise={"y": torch.zeros(1, 1)}),
        "no residual for 'z'",
    ),
    bad(
        "models.predict",
        "generator an int",
        lambda: chain().predict(FACTUAL, "sampled", 0),
        "generator must be a torch.Generator or None, got 0",
    ),
    bad(
        "models.predict",
        "grad a str",
        lambda: chain().predict(FACTUAL, grad="yes"),
        "grad must be True or False, got 'yes'",
    ),
    bad(
        "models.predict",
        "action above bounds",
        lambda: finger().predict({**FSTATE, "act.finger": torch.full((2, 1), 5.0)}),
        "values['act.finger'] has 2 entries outside the action bounds [-1, 0.33] (first: 5",
    ),
    bad(
        "models.predict",
        "action below bounds",
        lambda: finger().predict({**FSTATE, "act.finger": torch.full((2, 1), -1.001)}),
        "outside the action bounds [-1, 0.33] (first: -1.001",
    ),
    # WorldModel: other methods
    bad("models.WorldModel", "sample n 0", lambda: chain().sample(0), "n must be a positive int, got 0"),
    bad(
        "models.WorldModel",
        "sample n float",
        lambda: chain().sample(2.5),
        "n must be a positive int, got 2.5",
    ),
    bad(
        "models.WorldModel",
        "sample n bool",
        lambda: chain().sample(True),
        "n must be a positive int, got True",
    ),
    bad(
        "models.WorldModel",
        "sample numpy generator",
        lambda: chain().sample(3, np.random.default_rng(0)),
        "generator must be a torch.Generator",
    ),
    bad(
        "models.rollout",
        "action out of bounds",
        lambda: finger().rollout(FSTATE, {"act.finger": torch.full((2, 3, 1), 2.0)}),
        "inputs['act.finger'] has 6 entries outside the action bounds",
    ),
    bad(
        "models.rollout",
        "inputs without T",
        lambda: finger().rollout(FSTATE, {"act.finger": torch.zeros(2, 1)}),
        "expected (N, T, 1)",
    ),
    bad(
        "models.rollout",
        "missing initial",
        lambda: finger().rollout({}, {"act.finger": torch.zeros(2, 3, 1)}),
        "missing ['q_prev.finger']",
    ),
    bad(
        "models.rollout",
        "noise steps",
        lambda: finger().rollout(
            FSTATE,
            {"act.finger": torch.zeros(2, 3, 1)},
            noise={"dq.finger": torch.zeros(2, 2, 1), "q.finger": torch.zeros(2, 1)},
        ),
        "noise['dq.finger'] has 2 steps, expected 3",
    ),
    bad(
        "models.rollout",
        "action in initial",
        lambda: finger().rollout(
            {**FSTATE, "act.finger": torch.zeros(2, 1)}, {"act.finger": torch.zeros(2, 3, 1)}
        ),
        "rollout got values for ['act.finger']",
    ),
    bad(
        "models.WorldModel",
        "residuals incomplete",
        lambda: chain().residuals({"x": torch.ones(1, 1)}),
        "missing ['y', 'z']",
    ),
    bad(
        "models.WorldModel",
        "root prior of a non-root",
        lambda: chain().set_root_prior("y", 0, 1),
        "'y' is not a non-action root",
    ),
    bad(
        "models.WorldModel",
        "root prior scale negative",
        lambda: chain().set_root_prior("x", 0, -1),
        "positive finite scale",
    ),
    bad(
        "models.WorldModel",
        "root prior loc str",
        lambda: chain().set_root_prior("x", "a", 1),
        "root prior loc of 'x' is not numeric",
    ),
    bad(
        "models.WorldModel",
        "root prior too long",
        lambda: chain().set_root_prior("x", [0, 0], 1),
        "needs 1 loc and scale entries",
    ),
    bad("models.WorldModel", "root prior nan", lambda: chain().set_root_prior("x", NAN, 1), "finite loc"),
    bad("models.WorldModel", "mechanism of a root", lambda: chain().mechanism("x"), "'x' is a root"),
    # heteroscedastic and ensemble mechanisms, the member axis, predictive scales
    bad(
        "models.WorldModel",
        "members 0",
        lambda: WorldModel(xy_graph(), members=0),
        "members must be a positive int, got 0",
    ),
    bad(
        "models.WorldModel",
        "members float",
        lambda: WorldModel(xy_graph(), members=2.0),
        "members must be a positive int",
    ),
    bad("models.WorldModel", "kind gp", lambda: WorldModel(xy_graph(), kind="gp"), "kind 'gp' unknown"),
    bad(
        "models.WorldModel",
        "sigma of a heteroscedastic site",
        lambda: WorldModel(xy_graph(), seed=0, kind="hetero", hidden=(2,)).sigma("y"),
        "is heteroscedastic: its scale depends on the parents",
    ),
    bad(
        "models.WorldModel",
        "predict members a str",
        lambda: finger().predict(FIN, members="yes"),
        "members must be True or False",
    ),
    bad(
        "models.WorldModel",
        "rollout members a str",
        lambda: finger().rollout(FSTATE, {"act.finger": torch.zeros(2, 3, 1)}, members=1),
        "members must be True or False",
    ),
    bad(
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
    bad(
        "models.WorldModel",
        "predict_scale component",
        lambda: finger().predict_scale(FIN, "all"),
        "component 'all' unknown",
    ),
    bad(
        "models.WorldModel",
        "predict_scale missing root",
        lambda: finger().predict_scale({"act.finger": torch.zeros(2, 1)}),
        "predict_scale needs a value for every root; missing ['q_prev.finger']",
    ),
    bad(
        "models.WorldModel",
        "predict_scale action out of bounds",
        lambda: finger().predict_scale({**FIN, "act.finger": torch.full((2, 1), 5.0)}),
        "outside the action bounds",
    ),
    bad("models.ensemble", "no members", lambda: EnsembleMechanism([]), "ensemble size must be >= 1), got 0"),
    bad(
        "models.ensemble",
        "replicate 0",
        lambda: EnsembleMechanism.replicate(MLPMechanism, 0),
        "members must be a positive int, got 0",
    ),
    bad(
        "models.ensemble",
        "members a mechanism",
        lambda: EnsembleMechanism(MECH2),
        "members must be a list of Mechanism",
    ),
    bad(
        "models.ensemble",
        "member a str",
        lambda: EnsembleMechanism([MECH2, "m"]),
        "ensemble member 1 must be a Mechanism",
    ),
    bad(
        "models.ensemble",
        "mixed kinds",
        lambda: EnsembleMechanism([MECH2, MLPMechanism(1, 2, seed=0)]),
        "ensemble members must be of one kind, got ['LinearMechanism', 'MLPMechanism']",
    ),
    bad(
        "models.ensemble",
        "mixed dims",
        lambda: EnsembleMechanism([MECH2, LinearMechanism(1, 1, seed=0)]),
        "ensemble members must share in_dim and out_dim, got (in, out) [(1, 1), (1, 2)]",
    ),
    bad(
        "models.ensemble",
        "nested",
        lambda: EnsembleMechanism([EnsembleMechanism([MECH2])]),
        "ensemble member 0 is itself an ensemble",
    ),
    bad(
        "models.ensemble",
        "paired parents of the wrong size",
        lambda: EnsembleMechanism([MECH2, MECH2]).member_loc_scale(torch.zeros(3, 4, 1), paired=True),
        "paired parents have shape (3, 4, 1), expected (2, ..., 1)",
    ),
    bad(
        "models.ensemble",
        "sigma of two members",
        lambda: EnsembleMechanism([MECH2, MECH2]).sigma,
        "an ensemble of 2 members has a scale that depends on the parents",
    ),
    bad(
        "models.ensemble",
        "config without members",
        lambda: make_mechanism({"kind": "ensemble"}),
        "ensemble config needs 'members', a non-empty list of configs",
    ),
    bad(
        "models.ensemble",
        "config nested",
        lambda: make_mechanism({"kind": "ensemble", "members": [{"kind": "ensemble", "members": []}]}),
        "ensemble member 0 is itself an ensemble",
    ),
    bad(
        "models.heteroscedastic",
        "bounds reversed",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=(2.0, -2.0)),
        "log_scale_bounds must have low < high, got (2, -2)",
    ),
    bad(
        "models.heteroscedastic",
        "bounds equal",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=(0.0, 0.0)),
        "log_scale_bounds must have low < high, got (0, 0)",
    ),
    bad(
        "models.heteroscedastic",
        "bound nan",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=(NAN, 1.0)),
        "log_scale_bounds[0] must be a finite number, got nan",
    ),
    bad(
        "models.heteroscedastic",
        "bound inf",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=(-1.0, INF)),
        "log_scale_bounds[1] must be a finite number, got inf",
    ),
    bad(
        "models.heteroscedastic",
        "bounds a number",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds=1.0),
        "log_scale_bounds must be a pair (low, high)",
    ),
    bad(
        "models.heteroscedastic",
        "bounds a str",
        lambda: HeteroscedasticMechanism(1, log_scale_bounds="ab"),
        "log_scale_bounds must be a pair (low, high)",
    ),
    bad(
        "models.heteroscedastic",
        "learn_bounds a str",
        lambda: HeteroscedasticMechanism(1, learn_bounds="no"),
        "learn_bounds must be True or False",
    ),
    bad(
        "models.heteroscedastic",
        "in_dim 0",
        lambda: HeteroscedasticMechanism(0),
        "in_dim must be a positive int, got 0",
    ),
    bad(
        "models.heteroscedastic",
        "activation unknown",
        lambda: HeteroscedasticMechanism(1, activation="gelu"),
        "activation 'gelu' unknown",
    ),
    bad(
        "models.heteroscedastic",
        "coefficients of the wrong shape",
        lambda: HeteroscedasticMechanism.from_coefficients([[1.0, 2.0]], log_scale_weight=[[1.0]]),
        "log_scale_weight has shape (1, 1), expected (1, 2)",
    ),
    bad(
        "models.heteroscedastic",
        "set_sigma",
        lambda: HeteroscedasticMechanism(1, seed=0).set_sigma(1.0),
        "it predicts its scale, which cannot be set",
    ),
    bad(
        "models.heteroscedastic",
        "config unknown key",
        lambda: make_mechanism({"kind": "hetero", "in_dim": 1, "sigma": 1.0}),
        "hetero mechanism config has unknown keys ['sigma']",
    ),
    bad("models.WorldModel", "mechanism name a list", lambda: chain().mechanism(["y"]), "name must be a str"),
    bad("models.WorldModel", "loc missing parent", lambda: chain().loc("y", {}), "missing ['x']"),
    bad(
        "models.WorldModel", "bounds of unbounded", lambda: chain().bounds("x"), "variable 'x' has no bounds"
    ),
    bad("models.WorldModel", "program without n", lambda: chain()(None), "needs data or n"),
    bad(
        "models.WorldModel",
        "program n float",
        lambda: chain()(None, 2.5),
        "n must be a positive int, got 2.5",
    ),
    bad(
        "models.WorldModel",
        "program action out of bounds",
        lambda: finger()({"act.finger": torch.full((2, 1), 3.0)}),
        "data['act.finger'] has 2 entries outside the action bounds",
    ),
    bad(
        "models.WorldModel",
        "with_graph a str",
        lambda: chain().with_graph("g"),
        "graph must be a CausalGraph",
    ),
    bad(
        "models.WorldModel",
        "with_graph dim change",
        lambda: chain().with_graph(CausalGraph([Variable("x", "observed", dim=2)])),
        "'x' has dim 2 in the new graph, expected 1",
    ),
    bad(
        "models.WorldModel",
        "copy priors from a str",
        lambda: chain().copy_root_priors_from("m"),
        "other must be a WorldModel",
    ),
    bad(
        "models.WorldModel",
        "copy priors of a non-root",
        lambda: chain().copy_root_priors_from(chain(), names=["y"]),
        "cannot copy root priors of ['y']",
    ),
    bad(
        "models.WorldModel",
        "copy priors names a str",
        lambda: chain().copy_root_priors_from(chain(), names="x"),
        "names must be a sequence of names",
    ),
    # discrete sites
    bad(
        "models.WorldModel",
        "discrete unknown site",
        lambda: WorldModel(chain_graph(), discrete={"w": 2}),
        "discrete site 'w'",
    ),
    bad(
        "models.WorldModel",
        "discrete K of 1",
        lambda: WorldModel(chain_graph(), discrete={"y": 1}),
        "number of categories",
    ),
    bad(
        "models.WorldModel",
        "discrete action",
        lambda: WorldModel(finger_graph(), discrete={"act.finger": 2}),
        "'act.finger' is an action",
    ),
    bad(
        "models.WorldModel",
        "discrete K disagrees with the mechanism",
        lambda: WorldModel(chain_graph(), {"y": CategoricalMechanism(1, 3, seed=0)}, discrete={"y": 4}),
        "discrete['y'] = 4 categories, but its mechanism has 3",
    ),
    bad(
        "models.WorldModel",
        "discrete with a continuous mechanism",
        lambda: WorldModel(chain_graph(), {"y": LinearMechanism(1, seed=0)}, discrete={"y": 2}),
        "its mechanism is a continuous LinearMechanism",
    ),
    bad(
        "models.discrete",
        "categories of 1",
        lambda: CategoricalMechanism(1, 1),
        "categories must be an int >= 2, got 1",
    ),
    bad(
        "models.discrete", "sigma of a Bernoulli", lambda: BernoulliMechanism(1, seed=0).sigma, "has no sigma"
    ),
    bad(
        "models.WorldModel",
        "Bernoulli observed with 0.5 (program)",
        lambda: binary()(bin_data(t=HALF)),
        "data['t'] has 1 values that are not 0 or 1 (a Bernoulli site) (first: 0.5 at index (1, 0))",
    ),
    bad(
        "models.WorldModel",
        "residuals of a discrete site",
        lambda: binary().residuals(
            {k: torch.as_tensor(v, dtype=torch.float32) for k, v in bin_data().items()}
        ),
        "residuals are not determined for the discrete sites ['t', 'c']",
    ),
    bad(
        "models.GatedMechanism",
        "switch site continuous",
        lambda: gated(discrete={}),
        "gated site 'x' has switch 'c', which is continuous; the switch must be a Bernoulli site",
    ),
    bad(
        "models.GatedMechanism",
        "switch site categorical with 3 categories",
        lambda: gated(discrete={"c": 3}),
        "which is categorical with 3 categories",
    ),
    bad(
        "models.GatedMechanism",
        "switch not a parent of the site",
        lambda: gated(parent=False),
        "gated site 'x' has switch 'c', which is not among its parents ['b']",
    ),
    bad(
        "models.GatedMechanism",
        "switch unknown",
        lambda: gated(switch="contact"),
        "gated site 'x' has switch 'contact', which is not among its parents ['b', 'c']",
    ),
    bad(
        "models.GatedMechanism",
        "floor 0",
        lambda: GatedMechanism("c", LinearMechanism.from_coefficients([[1.0, 1.0]]), 0.0),
        "floor (the off-branch sd sigma_0) must be finite and > 0, got [0.0]",
    ),
    bad(
        "models.GatedMechanism",
        "floor negative",
        lambda: GatedMechanism("c", LinearMechanism.from_coefficients([[1.0, 1.0]]), -1e-3),
        "must be finite and > 0, got [-0.001",
    ),
    bad(
        "models.GatedMechanism",
        "floor NaN",
        lambda: GatedMechanism("c", LinearMechanism.from_coefficients([[1.0, 1.0]]), NAN),
        "floor",
    ),
    bad(
        "models.GatedMechanism",
        "on branch discrete",
        lambda: GatedMechanism("c", BernoulliMechanism(2, seed=0), 0.01),
        "the on branch of a gated site must be a continuous mechanism, got a BernoulliMechanism",
    ),
    bad(
        "models.GatedMechanism",
        "switch observed with 0.5 (program)",
        lambda: gated()({"b": np.zeros((2, 1)), "c": np.array([[1.0], [0.5]]), "x": np.zeros((2, 1))}),
        "data['c'] has 1 values that are not 0 or 1 (a Bernoulli site) (first: 0.5",
    ),
    bad(
        "models.GatedMechanism",
        "switch given as 2 to predict",
        lambda: gated().predict({"b": np.zeros((2, 1)), "c": np.array([[2.0], [0.0]])}),
        "values['c'] has 1 values that are not 0 or 1",
    ),
    bad(
        "models.GatedMechanism",
        "switch column 0.5 given to the mechanism",
        lambda: gated().mechanism("x").loc_scale(torch.tensor([[0.0, 0.5]])),
        "gated site 'x': switch 'c' has 1 values that are not 0 or 1 (first: 0.5)",
    ),
    bad(
        "models.io",
        "gated site file without its on branch",
        lambda: gated_file_without("on"),
        "lacks its on branch",
        ModelFileError,
    ),
    bad(
        "models.io",
        "gated site file without its floor",
        lambda: gated_file_without("floor"),
        "lacks its floor",
        ModelFileError,
    ),
]


def test_case_ids_are_unique_and_there_are_enough():
    assert duplicate_ids(CASES) == []
    assert len(CASES) >= 60, len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[f"{c.area}: {c.id}" for c in CASES])
def test_bad_input_raises_a_specific_error_naming_the_value(case):
    check(case)


def test_no_bad_input_gets_a_raw_library_error():
    raw = raw_errors(CASES)
    assert raw == [], "\n".join(raw)
