"""Gated sites: a Bernoulli switch chooses between an on branch and an off floor.

Oracle: a tiny linear gated SCM, ``c ~ Bernoulli(sigmoid(a - 0.5))``, ``x | c = 1 ~ Normal(2b + 0.5,
exp(0.3b - 1))`` and ``x | c = 0 ~ Normal(0.5b, 0.05)``, computed by hand.
"""

import json
import math

import numpy as np
import pytest
import torch

from inference.handlers import ReplayNoise
from models import (
    BernoulliMechanism,
    CausalGraph,
    EnsembleMechanism,
    GatedMechanism,
    HeteroscedasticMechanism,
    LinearMechanism,
    MLPMechanism,
    ModelFileError,
    Variable,
    WorldModel,
    load,
    save,
)
from models import io as model_io

FLOOR = 0.05


def gated_graph():
    """a -> c (Bernoulli), b -> x, c -> x."""
    return CausalGraph(
        [Variable(n, "observed") for n in ("a", "b", "c", "x")], [("a", "c"), ("b", "x"), ("c", "x")]
    )


def gated_model(off=True):
    on = HeteroscedasticMechanism.from_coefficients(
        [[2.0, 0.0]], 0.5, log_scale_weight=[[0.3, 0.0]], log_scale_bias=-1.0
    )
    off_mech = LinearMechanism.from_coefficients([[0.5, 0.0]], 0.0) if off else None
    return WorldModel(
        gated_graph(),
        {
            "c": BernoulliMechanism.from_coefficients([1.0], -0.5),
            "x": GatedMechanism("c", on, FLOOR, off_mech),
        },
    )


B = torch.tensor([[0.7], [-0.2], [1.5]])
A = torch.tensor([[0.3], [-1.0], [0.0]])
C = torch.tensor([[1.0], [0.0], [0.0]])


def test_loc_and_scale_switch_with_the_parent():
    model = gated_model()
    vals = {"a": A, "b": B, "c": C}
    loc = model.predict(vals)["x"][:, 0]
    scale = model.predict_scale(vals)["x"][:, 0]
    b = B[:, 0].tolist()
    assert loc.tolist() == pytest.approx([2 * b[0] + 0.5, 0.5 * b[1], 0.5 * b[2]], abs=1e-6)
    assert scale.tolist() == pytest.approx([math.exp(0.3 * b[0] - 1), FLOOR, FLOOR], abs=1e-6)
    # without an off mean the off rows predict 0
    assert gated_model(off=False).predict(vals)["x"][1:, 0].tolist() == [0.0, 0.0]


def test_the_program_and_predict_agree_and_the_site_is_normal_given_c():
    model = gated_model()
    eps = {"c": torch.zeros(3, 2), "x": torch.tensor([[0.4], [-1.2], [2.0]])}
    fast = model.predict({"a": A, "b": B, "c": C}, noise=eps)
    with torch.no_grad():
        slow = ReplayNoise(eps)(model)({"a": A, "b": B, "c": C}, 3)
    assert torch.allclose(fast["x"], slow["x"], atol=1e-6)
    loc, scale = model.mechanism("x").loc_scale(torch.cat([B, C], -1))
    x = torch.tensor([[1.0], [0.0], [0.3]])
    expected = torch.distributions.Normal(loc, scale).log_prob(x).sum(-1)
    site = model.site_distribution("x", {"b": B, "c": C}, 3)
    assert torch.allclose(site.log_prob(x), expected, atol=1e-6)


def test_rollout_and_sampling_respect_the_switch():
    model = gated_model(off=False)
    draws = model.sample(2000, generator=torch.Generator().manual_seed(0))
    off = draws["c"][:, 0] == 0
    # off rows: x ~ Normal(0, floor)
    assert float(draws["x"][off].std()) == pytest.approx(FLOOR, rel=0.1)
    assert float(draws["x"][~off].abs().mean()) > 10 * FLOOR


@pytest.mark.parametrize(
    "make",
    [
        lambda g: MLPMechanism(2, 1, hidden=(4,), seed=0),
        lambda g: EnsembleMechanism.replicate(
            lambda s: HeteroscedasticMechanism(2, 1, hidden=(4,), seed=s), 3, 0
        ),
    ],
    ids=["mlp", "ensemble"],
)
def test_any_continuous_kind_is_an_on_branch_and_round_trips(make, tmp_path):
    model = WorldModel(gated_graph(), {"x": GatedMechanism("c", make(None), 1e-3)}, discrete={"c": 2}, seed=0)
    path = save(model, tmp_path / "gated.npz")
    back = load(path)
    vals = {"a": A, "b": B, "c": C}
    assert isinstance(back.mechanism("x"), GatedMechanism)
    assert back.mechanism("x").switch_index == 1
    for key in ("x",):
        assert torch.equal(model.predict(vals)[key], back.predict(vals)[key])
        assert torch.equal(model.predict_scale(vals)[key], back.predict_scale(vals)[key])


def test_a_file_whose_gated_site_lacks_its_on_branch_is_refused(tmp_path):
    path = save(gated_model(), tmp_path / "gated.npz")
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    doc = json.loads(arrays.pop("__meta__").tobytes())
    del doc["meta"]["mechanisms"]["x"]["on"]
    doc["checksum"] = model_io._checksum(doc["format"], doc["versions"], doc["meta"], arrays)
    arrays["__meta__"] = np.frombuffer(json.dumps(doc).encode(), dtype=np.uint8)
    np.savez(path, **arrays)
    with pytest.raises(ModelFileError, match="lacks its on branch"):
        load(path)


def test_members_of_an_ensemble_on_branch_are_propagated_and_the_off_rows_stay_at_the_floor():
    on = EnsembleMechanism.replicate(lambda s: HeteroscedasticMechanism(2, 1, hidden=(4,), seed=s), 3, 0)
    model = WorldModel(gated_graph(), {"x": GatedMechanism("c", on, FLOOR)}, discrete={"c": 2}, seed=0)
    assert model.ensemble_size == 3
    vals = {"a": A, "b": B, "c": C}
    members = model.predict(vals, members=True)["x"]  # (K, N, 1)
    locs, _ = on.member_loc_scale(torch.cat([B, C], -1))
    assert torch.allclose(members[:, 0], locs[:, 0], atol=1e-6)
    assert torch.equal(members[:, 1:], torch.zeros(3, 2, 1))
    epistemic = model.predict_scale(vals, component="epistemic")["x"][:, 0]
    aleatoric = model.predict_scale(vals, component="aleatoric")["x"][:, 0]
    assert float(epistemic[0]) > 0 and epistemic[1:].tolist() == [0.0, 0.0]
    assert aleatoric[1:].tolist() == pytest.approx([FLOOR, FLOOR], rel=1e-6)
    total = model.predict_scale(vals)["x"][:, 0]
    assert torch.allclose(total.pow(2), aleatoric.pow(2) + epistemic.pow(2), atol=1e-7)


def test_a_gated_site_with_an_unserialisable_branch_cannot_be_saved(tmp_path):
    from models import FunctionMechanism

    on = FunctionMechanism(lambda z: z[..., :1], 2)
    model = WorldModel(gated_graph(), {"x": GatedMechanism("c", on, FLOOR)}, discrete={"c": 2}, seed=0)
    with pytest.raises(ValueError, match="is \\(or holds\\) a FunctionMechanism, which cannot be saved"):
        save(model, tmp_path / "f.npz")


def test_with_graph_rewires_a_gated_site_and_keeps_its_switch():
    model = gated_model()
    graph = CausalGraph(
        [Variable(n, "observed") for n in ("a", "b", "c", "x")],
        [("a", "c"), ("a", "x"), ("b", "x"), ("c", "x")],
    )
    new = model.with_graph(graph, seed=0)
    assert new.provenance["warm_start"]["x"] == "rewired"
    mech = new.mechanism("x")
    assert isinstance(mech, GatedMechanism) and mech.switch_index == 2
    vals = {"a": A, "b": B, "c": C}
    assert torch.allclose(new.predict(vals)["x"], model.predict(vals)["x"], atol=1e-6)
    assert torch.allclose(new.predict_scale(vals)["x"], model.predict_scale(vals)["x"], atol=1e-6)
    # without the switch edge the site gets a fresh default mechanism
    cut = CausalGraph([Variable(n, "observed") for n in ("a", "b", "c", "x")], [("a", "c"), ("b", "x")])
    assert model.with_graph(cut, seed=0).provenance["warm_start"]["x"] == "new"
