"""No public query of ``models`` or ``inference`` touches the global RNGs.

Every query takes its randomness as an argument (``seed`` or a generator). Each case below
runs one query on a tiny input and checks that Python's ``random``, NumPy's global and
torch's global RNG states are exactly as before. Running the Pyro program itself with
unobserved sites samples from torch's RNG by design (that is what :func:`inference.simulate`
seeds), so the program is only run here with every site given.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyro
import pytest
import torch

import inference
import models
from inference import (
    AbductNoise,
    ActionOptions,
    CalibrationOptions,
    CuriositySampler,
    DiscoveryOptions,
    Ensemble,
    FitSchedule,
    Intervene,
    MeasurementScale,
    ReplayNoise,
    ResidualMonitor,
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
from inference.context import context_sensitivity, local_sensitivity, target_relevance
from inference.design import choose_interventions, orientation_margins, structure_uncertainty
from models import (
    CausalGraph,
    EnsembleMechanism,
    FromPushFrameMechanism,
    FunctionMechanism,
    GatedMechanism,
    HeteroscedasticMechanism,
    JointLimitMechanism,
    KinematicChain,
    KinematicMechanism,
    KinematicPointsMechanism,
    LinearMechanism,
    MLPMechanism,
    PushFrameMechanism,
    Variable,
    WorldModel,
    chain_graph,
    finger_graph,
    joint_chain_graph,
    pushing_graph,
    random_graph,
)
from models.mechanisms import make_mechanism


def _chain() -> WorldModel:
    return WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients([[2.0]]), "z": LinearMechanism.from_coefficients([[-1.5]])},
    )


def _finger(seed: int = 0) -> WorldModel:
    return WorldModel(finger_graph("state"), seed=seed, hidden=(4,))


def _finger_data(n: int = 24) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    a = -1.0 + 1.33 * torch.rand(n, 1, generator=gen)
    q_prev = torch.rand(n, 1, generator=gen) - 1.0
    dq = 0.5 * a - 0.2 * q_prev + 0.05 * torch.randn(n, 1, generator=gen)
    return {"act.finger": a, "q_prev.finger": q_prev, "dq.finger": dq, "q.finger": q_prev + dq}


def _fitted_finger() -> WorldModel:
    model = _finger()
    fit(model, _finger_data(), schedule=FitSchedule(epochs=2, batch_size=8))
    return model


FACTUAL = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-3.0]])}
STATE = {"q_prev.finger": torch.zeros(3, 1)}
TARGET = {"q.finger": torch.full((3, 1), -0.2)}


def _discovery_data() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 1))
    y = np.tanh(2 * x) + 0.2 * rng.normal(size=(40, 1))
    return {"x": x, "y": y}


def _discovered() -> inference.DiscoveryResult:
    vs = [Variable("x", "observed"), Variable("y", "observed")]
    return discover(vs, _discovery_data(), options=DiscoveryOptions(features=8), seed=0)


def _save_load(tmp: Path) -> None:
    path = models.save(_finger(), tmp / "m.npz")
    models.load(path)


def _ensemble() -> None:
    ens = Ensemble.create(lambda s: WorldModel(finger_graph("state"), seed=s, hidden=(4,)), k=2, seed=0)
    ens.fit(_finger_data(), schedule=FitSchedule(epochs=1, batch_size=8))
    ens.predict({"act.finger": torch.zeros(2, 1), "q_prev.finger": torch.zeros(2, 1)})
    ens.information({"act.finger": torch.zeros(2, 1), "q_prev.finger": torch.zeros(2, 1)}, ["q.finger"])
    ens.choose(STATE, {"act.finger": torch.zeros(3, 2, 1)}, ["q.finger"], spread=0.5)


def _gated_queries() -> None:
    """A gated site: fit (on rows only), predict, and counterfactual_mixture over its latent switch."""
    graph = CausalGraph(
        [Variable(n, "observed") for n in ("b", "c", "x")], [("b", "c"), ("b", "x"), ("c", "x")]
    )
    on = HeteroscedasticMechanism(2, 1, hidden=(3,), seed=0)
    model = WorldModel(graph, {"x": GatedMechanism("c", on, 1e-3)}, discrete={"c": 2}, seed=0)
    g = torch.Generator().manual_seed(0)
    b = torch.randn(40, 1, generator=g)
    c = (b > 0).to(b.dtype)
    data = {"b": b, "c": c, "x": c * (b + 0.1 * torch.randn(40, 1, generator=g))}
    fit(model, data, schedule=FitSchedule(epochs=2, batch_size=8, validation=0.25))
    calibration = CalibrationOptions(rule="conformal", level=0.9, folds=2)  # fresh refits of the on branch
    fit(model, data, schedule=FitSchedule(epochs=2, batch_size=8, validation=0.25, calibration=calibration))
    model.predict({"b": b[:3]}, noise="sampled", generator=torch.Generator().manual_seed(1))
    assert inference.counterfactual_mixture(model, {"b": b[:3], "x": data["x"][:3]}, {"b": 0.0}).mean
    interval = inference.predictive_interval(model, {"b": b[:3]}, "x", num_samples=8, seed=1)
    assert isinstance(interval, inference.PredictiveInterval)
    inference.coverage_by_regime(data["x"][:3], interval.lower, interval.upper, c[:3, 0])
    several = inference.predictive_intervals(model, {"b": b[:3]}, "x", (0.5, 0.9), num_samples=8, seed=1)
    assert len(several) == 2


def _kinematics(tmp: Path) -> None:
    """A hinge chain, its effector-motion and joint-limit mechanisms, saved and loaded in a model."""
    chain = KinematicChain(
        torch.eye(3).expand(2, 3, 3),
        [[0, 0, 0], [0.3, 0, 0]],
        torch.zeros(2, 3),
        [[0, 0, 1]] * 2,
        [0, 0],
        [0.2, 0, 0],
        [[-1, 1], [-2, 2]],
    )
    graph = CausalGraph(
        [
            Variable("q_prev", "observed", 2),
            Variable("dq", "observed", 2),
            Variable("q", "latent", 2),
            Variable("dee", "latent", 3),
        ],
        [("q_prev", "q"), ("dq", "q"), ("q_prev", "dee"), ("dq", "dee")],
    )
    mechs = {"q": JointLimitMechanism([[-1, 1], [-2, 2]]), "dee": KinematicMechanism(chain, [0, 1], 2)}
    model = WorldModel(graph, mechs, seed=0)
    model.predict({"q_prev": torch.zeros(2, 2), "dq": torch.ones(2, 2)})
    models.load(models.save(model, tmp / "kinematic.npz"))
    KinematicPointsMechanism([chain, chain], [0, 1], 2)(torch.zeros(2, 2))  # fixed: no randomness
    PushFrameMechanism([3, 3])(torch.ones(2, 6))
    FromPushFrameMechanism(3, 2)(torch.ones(2, 5))


def _calibrated_models(tmp: Path) -> None:
    """Heteroscedastic and ensemble mechanisms: construction, fit, member queries, calibration, files."""
    HeteroscedasticMechanism(2, 1, hidden=(3,), seed=0)(torch.zeros(2, 2))
    HeteroscedasticMechanism.from_coefficients([[1.0]], log_scale_weight=[[0.5]])
    EnsembleMechanism.replicate(lambda g: MLPMechanism(1, 1, hidden=(2,), seed=g), 3, seed=1)
    make_mechanism({"kind": "ensemble", "members": [{"kind": "hetero", "in_dim": 1, "hidden": [2]}] * 2})
    values = {"act.finger": torch.zeros(2, 1), "q_prev.finger": torch.zeros(2, 1)}
    for kind, members in (("hetero", 1), ("mlp", 3), ("hetero", 2)):
        model = WorldModel(finger_graph("state"), seed=2, kind=kind, members=members, hidden=(4,))
        fit(model, _finger_data(), schedule=FitSchedule(epochs=2, batch_size=8, validation=0.25, patience=1))
        model.predict(values, members=True)
        model.predict(values, "sampled", torch.Generator().manual_seed(0), members=True)
        model.rollout(
            {"q_prev.finger": torch.zeros(2, 1)}, {"act.finger": torch.zeros(2, 3, 1)}, members=True
        )
        model.predict_scale(values)
        model.predict_scale(values, component="epistemic")
        model.residuals(model.sample(4, torch.Generator().manual_seed(0)))
        model.with_graph(finger_graph("thesis"), seed=1)
        predictive_check(model, _finger_data(), levels=[0.5, 0.9])
        models.load(models.save(model, tmp / f"{kind}{members}.npz"))
    counterfactual(
        WorldModel(chain_graph(), seed=0, kind="hetero", members=2, hidden=(3,)), FACTUAL, {"x": 0.0}
    )


def _handlers() -> None:
    chain = _chain()
    with AbductNoise() as ab:
        chain(FACTUAL, 1)
    ReplayNoise(ab.noise)(chain)({"x": FACTUAL["x"]}, 1)
    Intervene({"x": torch.zeros(1, 1)})(ReplayNoise({}, default="expected")(chain))(None, 1)
    MeasurementScale({"z": torch.ones(1)})(chain)(FACTUAL, 1)


def _curiosity() -> None:
    s = CuriositySampler(0.0, 1.0, bins=5).fit([0.1, 0.2, 0.9])
    s.partial_fit([0.5])
    s.density([0.3])
    s.sample(np.random.default_rng(0), [0.3, 0.4])
    s.sample(np.random.default_rng(0), size=3)
    s.occupancy()
    s.normalized_entropy()
    occupancy([0.1, 0.5], 0.0, 1.0, 4)
    normalized_entropy([0.1, 0.5], 0.0, 1.0, 4)


def _context() -> None:
    model = _finger()
    values = model.sample(16, torch.Generator().manual_seed(0))
    local_sensitivity(model, values)
    context_sensitivity(model, values)
    target_relevance(model, values, ["q.finger"])
    sub = active_subgraph(model, values, ["q.finger"])
    subgraph_model(model, sub)


def _graph_ops() -> None:
    g = finger_graph("thesis")
    g2 = CausalGraph.from_json(g.to_json()).with_edges(add=[("q_prev.finger", "dq.finger")])
    g2.with_confidence({("act.finger", "dq.finger"): 0.9}).fingerprint()
    g2.to_dot()
    joint_chain_graph(["a", "b"], {"a": (-1, 1), "b": (-1, 1)}, "state")
    pushing_graph(["j"], {"j": (-1.0, 1.0)})
    random_graph(5, seed=3)
    Variable.from_dict(g["q.finger"].to_dict())


def _mechanisms() -> None:
    MLPMechanism(2, 1, hidden=(3,), seed=0)(torch.zeros(4, 2))
    LinearMechanism(2, 1, seed=torch.Generator().manual_seed(0))
    FunctionMechanism(torch.sin, 1)(torch.zeros(2, 1))
    make_mechanism({"kind": "mlp", "in_dim": 2, "out_dim": 1, "hidden": [3], "activation": "tanh"})


def _world_queries() -> None:
    model = _finger(seed=3)
    values = {"act.finger": torch.zeros(2, 1), "q_prev.finger": torch.zeros(2, 1)}
    model.predict(values)
    model.predict(values, "sampled", torch.Generator().manual_seed(0))
    full = model.sample(4, torch.Generator().manual_seed(0))
    model.residuals(full)
    model(full)  # every site given: the program samples nothing
    model.rollout({"q_prev.finger": torch.zeros(2, 1)}, {"act.finger": torch.zeros(2, 3, 1)})
    model.rollout(
        {"q_prev.finger": torch.zeros(2, 1)},
        {"act.finger": torch.zeros(2, 3, 1)},
        "sampled",
        torch.Generator().manual_seed(0),
    )
    new = model.with_graph(finger_graph("thesis"), seed=1)
    new.copy_root_priors_from(model)
    model.loc("q.finger", full)


def _metalearn() -> None:
    model = _fitted_finger()
    data = _finger_data(40)
    monitor = ResidualMonitor(model, window=10)
    monitor.update(model, data)
    monitor.flagged()
    revise(
        model, data, ["dq.finger"], hidden=(4,), fit_kwargs={"schedule": FitSchedule(epochs=1, batch_size=16)}
    )


def _rewire() -> None:
    model = _fitted_finger()
    rewire(model, finger_graph("thesis"), _finger_data(), schedule=FitSchedule(epochs=1, batch_size=8))


def _design() -> None:
    result = _discovered()
    margins = orientation_margins(result, _discovery_data())
    structure_uncertainty(result, margins)
    choose_interventions(result, margins, 3)


CASES: dict[str, Callable[[Path], object]] = {
    "graph and presets": lambda tmp: _graph_ops(),
    "mechanisms with seed": lambda tmp: _mechanisms(),
    "WorldModel(seed=)": lambda tmp: WorldModel(pushing_graph(["j"], {"j": (-1.0, 1.0)}), seed=0),
    "WorldModel linear (seed=)": lambda tmp: WorldModel(finger_graph(), seed=0, kind="linear"),
    "predict, sample, rollout, residuals, program, with_graph": lambda tmp: _world_queries(),
    "save and load": _save_load,
    "handlers": lambda tmp: _handlers(),
    "do": lambda tmp: ReplayNoise({}, default="expected")(do(_chain(), {"x": 1.0}))(None, 2),
    "simulate": lambda tmp: simulate(_chain(), 5, {"x": 0.5}, seed=3),
    "simulate observational": lambda tmp: simulate(_chain(), 5, seed=3),
    "abduct": lambda tmp: abduct(_chain(), FACTUAL, 1),
    "counterfactual exact": lambda tmp: counterfactual(_chain(), FACTUAL, [{"x": 0.0}, {"y": 1.0}]).interval(
        "z"
    ),
    "counterfactual with latents": lambda tmp: counterfactual(
        _chain(),
        {"x": FACTUAL["x"], "z": FACTUAL["z"]},
        {"x": 0.0},
        posterior=infer_state(_chain(), {"x": FACTUAL["x"], "z": FACTUAL["z"]}, num_steps=5, num_samples=5),
    ),
    "infer_state": lambda tmp: infer_state(
        _chain(), {"z": FACTUAL["z"]}, num_steps=5, num_samples=4
    ).interval("y"),
    "infer_state mvn": lambda tmp: infer_state(
        _chain(), {"z": FACTUAL["z"]}, guide="mvn", num_steps=5, num_samples=4
    ),
    "infer_action midpoint": lambda tmp: infer_action(_finger(), STATE, TARGET, num_steps=3),
    "infer_action random init": lambda tmp: infer_action(
        _finger(), STATE, TARGET, num_steps=3, options=ActionOptions(init="random")
    ),
    "infer_action sampling, horizon, ensemble risk": lambda tmp: infer_action(
        WorldModel(finger_graph("state"), seed=0, members=2, hidden=(4,)),
        STATE,
        TARGET,
        num_steps=2,
        options=ActionOptions(
            sampling=inference.SamplingConfig(population=8, elites=2, iterations=1), risk="mean"
        ),
        seed=1,
    ),
    "gaussian_log_preference": lambda tmp: gaussian_log_preference(TARGET, 0.5)(TARGET),
    "fit": lambda tmp: fit(
        _finger(), _finger_data(), schedule=FitSchedule(epochs=2, batch_size=8, validation=0.25)
    ),
    "fit nll": lambda tmp: fit(
        _finger(), _finger_data(), loss="nll", schedule=FitSchedule(epochs=2, batch_size=8)
    ),
    "fit thesis protocol": lambda tmp: fit(
        _finger(), _finger_data(), loss="mse", schedule=FitSchedule(epochs=2, batch_size=8, validation=0.0)
    ),
    "heteroscedastic and ensemble models": _calibrated_models,
    "kinematic chain, KinematicMechanism, JointLimitMechanism, the push frame": _kinematics,
    "gated site: fit, predict, counterfactual_mixture (MixtureCounterfactual), predictive_interval(s)": (
        lambda tmp: _gated_queries()
    ),
    "curiosity": lambda tmp: _curiosity(),
    "admissible_parents and shd": lambda tmp: (
        admissible_parents(finger_graph(), tiers=[["act.finger", "q_prev.finger"]]),
        shd([("a", "b")], [("b", "a")]),
    ),
    "discover": lambda tmp: _discovered(),
    "discover gated": lambda tmp: discover(
        [Variable("x", "observed"), Variable("y", "observed")],
        _discovery_data(),
        options=DiscoveryOptions(features=8, sparsify="gated", gated={"steps": 5}),
        seed=0,
    ),
    "design": lambda tmp: _design(),
    "context and subgraph": lambda tmp: _context(),
    "ensemble": lambda tmp: _ensemble(),
    "residual monitor and revise": lambda tmp: _metalearn(),
    "rewire": lambda tmp: _rewire(),
}


def _discrete_model() -> WorldModel:
    graph = models.CausalGraph(
        [models.Variable(n, "observed") for n in "xtcy"], [("x", "t"), ("x", "c"), ("t", "y"), ("c", "y")]
    )
    return WorldModel(
        graph,
        {
            "t": models.BernoulliMechanism(1, seed=0),
            "c": models.CategoricalMechanism(1, 3, hidden=(4,), seed=1),
        },
        seed=2,
        kind="linear",
    )


def _discrete_queries() -> None:
    model = _discrete_model()
    data = simulate(model, 40, seed=1)
    fit(model, data, schedule=inference.FitSchedule(epochs=2, batch_size=8, validation=0.25, patience=1))
    fit(model, data)  # the automatic schedule
    model.sample(3, torch.Generator().manual_seed(0))
    counterfactual(model, {k: v[:3] for k, v in data.items()}, {"x": 0.0}, num_samples=7)
    counterfactual(model, {k: data[k][:3] for k in "xy"}, {"x": 0.0}, num_samples=7, guide="grid")
    infer_state(model, {k: data[k][:2] for k in "xy"}, guide="normal", num_steps=3, num_samples=5)
    abduct(model, {k: v[:2] for k, v in data.items()}, 2, seed=3)


def _posteriors() -> None:
    z = {"z": FACTUAL["z"]}
    infer_state(_chain(), z, guide="grid", num_samples=5, options=inference.GridOptions(points=51, pilot=20))
    infer_state(
        _chain(), z, guide="importance", num_samples=5, options=inference.ImportanceOptions(num_particles=50)
    )
    infer_state(_chain(), z, guide="flow", num_steps=3, num_samples=5, options=inference.SVIOptions(bins=4))
    state = infer_state(_chain(), {"x": FACTUAL["x"], "z": FACTUAL["z"]}, guide="grid", num_samples=5)
    counterfactual(_chain(), {"x": FACTUAL["x"], "z": FACTUAL["z"]}, {"x": 0.0}, posterior=state).to_dict()
    state.to_dict()
    state.diagnostics.to_dict()
    isinstance(state.diagnostics, inference.Diagnostics)
    isinstance(models.CategoricalMechanism(1, 3, seed=0), models.DiscreteMechanism)
    issubclass(inference.PoorPosteriorWarning, UserWarning)


def _composed() -> None:
    program = inference.MeasurementScale({"z": torch.ones(1)})(do(_chain(), {"x": 1.0}))
    assert isinstance(program, inference.Program)
    infer_state(program, {"z": FACTUAL["z"]}, guide="grid", num_samples=4)
    with inference.Intervene({"x": 1.0}):
        infer_state(_chain(), {"z": FACTUAL["z"]}, num_steps=3, num_samples=4)
        counterfactual(_chain(), {"z": FACTUAL["z"]}, {"y": 0.0}, num_samples=4)
    infer_action(
        inference.ReplayNoise({}, default="expected")(_finger()),
        STATE,
        TARGET,
        num_steps=2,
        options=inference.ActionOptions(init="random"),
        seed=2,
    )


def _tables_and_effects() -> None:
    """Table, as_table, CausalGraph.from_edges, cpdag, compare_edges, DiscoveryOptions, treatment_effect, unit_effects."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=200)
    t = (rng.random(200) < 1 / (1 + np.exp(-x))).astype(float)
    table = models.as_table({"x": x, "t": t, "y [kg]": 2 * t + x + rng.normal(size=200)})
    assert isinstance(table, models.Table)
    g = CausalGraph.from_edges([("x", "t"), ("x", "y [kg]"), ("t", "y [kg]")])
    m = WorldModel(g, seed=0, kind="linear", discrete={"t": 2})
    fit(m, table, schedule=inference.FitSchedule(epochs=2, batch_size=64), seed=0)
    r = inference.treatment_effect(m, table, "t", "y [kg]")
    assert isinstance(r, inference.EffectResult) and isinstance(r.units, inference.UnitEffects)
    assert isinstance(inference.unit_effects(m, table, "t", "y [kg]"), inference.UnitEffects)
    res = discover(table, options=inference.DiscoveryOptions(bootstrap=1, features=8), seed=0)
    assert isinstance(res.cpdag, inference.CPDAG)
    assert isinstance(inference.compare_edges(res.graph, [("x", "t"), ("t", "x")]), inference.EdgeComparison)
    inference.cpdag(g)


CASES.update(
    {
        "tables, from_edges, cpdag, compare_edges, treatment_effect": lambda tmp: _tables_and_effects(),
        "discrete sites: sample, fit, counterfactual, infer_state, abduct": lambda tmp: _discrete_queries(),
        "posteriors: grid, importance, flow, posterior=": lambda tmp: _posteriors(),
        "programs and handlers entered with with": lambda tmp: _composed(),
    }
)


def _states() -> tuple[object, tuple, torch.Tensor]:
    return random.getstate(), np.random.get_state(), torch.get_rng_state()


def _same_numpy_state(a: tuple, b: tuple) -> bool:
    return a[0] == b[0] and np.array_equal(a[1], b[1]) and tuple(a[2:]) == tuple(b[2:])


# the queries run few SVI steps: the test checks random states, not posteriors
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
@pytest.mark.parametrize("name", list(CASES))
def test_query_leaves_the_global_rngs_alone(name, tmp_path):
    random.seed(12345)
    np.random.seed(12345)
    torch.manual_seed(12345)
    py_before, np_before, torch_before = _states()
    CASES[name](tmp_path)
    py_after, np_after, torch_after = _states()
    assert py_after == py_before, f"{name} changed Python's random state"
    assert _same_numpy_state(np_after, np_before), f"{name} changed NumPy's global RNG state"
    assert torch.equal(torch_after, torch_before), f"{name} changed torch's global RNG state"


# the queries run few SVI steps: the test checks random states, not posteriors
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
def test_seeded_queries_do_not_depend_on_the_global_rng():
    """The same seed gives the same answer whatever the global RNGs hold."""
    results = []
    for global_seed in (1, 2):
        pyro.set_rng_seed(global_seed)
        post = infer_state(_chain(), {"z": FACTUAL["z"]}, num_steps=20, num_samples=8, seed=5)
        sim = simulate(_chain(), 4, seed=5)
        model = WorldModel(finger_graph("state"), seed=5, hidden=(4,))
        results.append((post.mean["y"], sim["z"], model.mechanism("dq.finger").net[0].weight.detach()))
    for a, b in zip(*results, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_seed_reproduces_the_manual_seed_pattern():
    """``WorldModel(g, seed=s)`` has the weights ``torch.manual_seed(s); WorldModel(g)`` had."""
    with torch.random.fork_rng():
        torch.manual_seed(7)
        old = WorldModel(finger_graph("state"), hidden=(5, 3))
    new = WorldModel(finger_graph("state"), seed=7, hidden=(5, 3))
    for (k, a), (_, b) in zip(old.state_dict().items(), new.state_dict().items(), strict=True):
        assert torch.equal(a, b), k


def test_every_public_name_is_exercised_here():
    """A name added to ``models.__all__`` or ``inference.__all__`` must get a case above."""
    text = Path(__file__).read_text()
    results = {
        "ActionResult",
        "CounterfactualResult",
        "DiscoveryResult",
        "FitResult",
        "Revision",
        "RewireResult",
    }
    results |= {"StateResult", "Mechanism", "ModelFileError", "Role"}  # made by the queries / types only
    missing = [n for n in [*models.__all__, *inference.__all__] if n not in results and n not in text]
    assert missing == [], missing
