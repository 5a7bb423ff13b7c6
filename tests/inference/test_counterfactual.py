"""Counterfactuals against closed-form answers on the linear-Gaussian chain."""

import math

import pytest
import torch

from inference import counterfactual, counterfactual_mixture, do, infer_state
from models import (
    BernoulliMechanism,
    CausalGraph,
    EnsembleMechanism,
    GatedMechanism,
    HeteroscedasticMechanism,
    LinearMechanism,
    Mechanism,
    MLPMechanism,
    Variable,
    WorldModel,
    chain_graph,
)

FACTUAL = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-3.0]])}


def test_fully_observed_do_x(chain):
    r = counterfactual(chain, FACTUAL, {"x": 0.0})
    assert r.exact and r.posterior is None
    assert r.samples["y"].shape == (1, 1, 1, 1)
    assert float(r.mean["y"][0, 0, 0]) == pytest.approx(0.5, abs=1e-5)
    assert float(r.mean["z"][0, 0, 0]) == pytest.approx(0.0, abs=1e-5)
    assert float(r.mean["x"][0, 0, 0]) == pytest.approx(0.0, abs=1e-5)


def test_fully_observed_do_y(chain):
    r = counterfactual(chain, FACTUAL, {"y": 0.0})
    assert float(r.mean["z"][0, 0, 0]) == pytest.approx(0.75, abs=1e-5)
    # non-descendants keep their factual values
    assert float(r.mean["x"][0, 0, 0]) == pytest.approx(1.0, abs=1e-5)


def test_scenarios_run_as_one_batch_and_match_single_runs(chain):
    g = torch.Generator().manual_seed(0)
    n = 50
    x = torch.randn(n, 1, generator=g)
    y = 2 * x + torch.randn(n, 1, generator=g)
    z = -1.5 * y + torch.randn(n, 1, generator=g)
    fact = {"x": x, "y": y, "z": z}
    scenarios = [{"x": 0.0}, {"y": torch.linspace(-1, 1, n)[:, None]}, {"x": lambda v: v + 1.0}, {}]
    batch = counterfactual(chain, fact, scenarios)
    assert batch.samples["z"].shape == (1, 4, n, 1)
    for k, sc in enumerate(scenarios):
        single = counterfactual(chain, fact, sc)
        torch.testing.assert_close(batch.samples["z"][:, k], single.samples["z"][:, 0])
    # shift: Z_cf - Z = -1.5 * 2 * 1
    torch.testing.assert_close(batch.mean["z"][2] - z, torch.full((n, 1), -3.0), atol=1e-5, rtol=0)
    # the empty scenario reproduces the factual world
    torch.testing.assert_close(batch.mean["z"][3], z, atol=1e-5, rtol=0)


def test_exact_for_nonlinear_normal_sites_written_naturally():
    torch.manual_seed(0)
    g = CausalGraph([Variable("x", "observed"), Variable("y", "latent")], [("x", "y")])
    mech = MLPMechanism(1, 1, sigma=0.3)
    m = WorldModel(g, {"y": mech})
    x, y = torch.tensor([[0.7]]), torch.tensor([[1.1]])
    r = counterfactual(m, {"x": x, "y": y}, {"x": -0.2})
    with torch.no_grad():
        u = y - mech(x)
        expected = mech(torch.tensor([[-0.2]])) + u
    torch.testing.assert_close(r.mean["y"][0], expected, atol=1e-6, rtol=0)


def test_latent_y_oracle(chain):
    r = counterfactual(
        chain, {"x": torch.tensor([[1.0]]), "z": torch.tensor([[-2.0]])}, {"x": 0.0}, num_samples=4000
    )
    assert not r.exact
    # Z_cf = -1.5 U_y + U_z = 3 + Z - 1.5 * 2 X... = 1.0 for every posterior draw
    torch.testing.assert_close(r.samples["z"], torch.ones_like(r.samples["z"]), atol=1e-4, rtol=0)
    post = r.posterior
    u_mean = float(post.mean["y"][0, 0]) - 2.0
    u_var = float(post.sd["y"][0, 0]) ** 2
    assert u_mean == pytest.approx(-0.4615, abs=0.02)
    assert u_var == pytest.approx(0.3077, rel=0.05)
    # Y_cf = U_y, so its samples carry the posterior of U_y
    assert float(r.samples["y"].mean()) == pytest.approx(-0.4615, abs=0.03)
    assert float(r.noise["y"].var()) == pytest.approx(0.3077, rel=0.08)


@pytest.mark.slow
def test_latent_counterfactual_intervals_are_calibrated(chain):
    """90 % intervals for Y_cf = U_y under do(X=0) cover the truth 88-92 % of the time."""
    n = 2000
    coverages = []
    for seed in (0, 1):
        g = torch.Generator().manual_seed(100 + seed)
        x = torch.randn(n, 1, generator=g)
        u_y = torch.randn(n, 1, generator=g)
        z = -1.5 * (2 * x + u_y) + torch.randn(n, 1, generator=g)
        r = counterfactual(chain, {"x": x, "z": z}, {"x": 0.0}, num_samples=1000, seed=seed)
        lo, hi = r.interval("y", 0.9)
        truth = u_y  # Y_cf = 2 * 0 + U_y
        coverages.append(float(((lo[0] <= truth) & (truth <= hi[0])).float().mean()))
    for c in coverages:
        assert 0.88 <= c <= 0.92, coverages


def test_no_evidence_counted_twice(chain):
    """The abduction uses one posterior over Y, not a second conditioning on Z."""
    r = counterfactual(
        chain, {"x": torch.tensor([[1.0]]), "z": torch.tensor([[-2.0]])}, {"y": 0.0}, num_samples=2000
    )
    # Z_cf = U_z = Z + 1.5 Y with Y ~ posterior N(1.538, 0.3077): mean 0.3077, var 2.25 * 0.3077
    assert float(r.samples["z"].mean()) == pytest.approx(-2 + 1.5 * 1.5385, abs=0.05)
    assert float(r.samples["z"].var()) == pytest.approx(2.25 * 0.3077, rel=0.1)


@pytest.mark.parametrize(
    ("interventions", "match"),
    [
        ({"w": 0.0}, "unknown intervention target 'w'"),
        ({"x": float("nan")}, "NaN or inf"),
        ({"x": torch.zeros(3, 1)}, "has 3 rows, expected 1"),
        ({"x": torch.zeros(1, 2)}, "expected a scalar"),
        ([], "empty sequence"),
    ],
)
def test_bad_interventions(chain, interventions, match):
    with pytest.raises(ValueError, match=match):
        counterfactual(chain, FACTUAL, interventions)


def test_bad_factual(chain):
    with pytest.raises(ValueError, match="unknown variable in factual 'w'"):
        counterfactual(chain, {"w": torch.zeros(1, 1)}, {"x": 0.0})
    with pytest.raises(ValueError, match="NaN or inf"):
        counterfactual(chain, {"x": torch.tensor([[float("nan")]])}, {"x": 0.0})


@pytest.mark.slow
def test_state_posterior_matches_closed_form(chain):
    post = infer_state(chain, {"x": torch.tensor([[1.0]]), "z": torch.tensor([[-2.0]])})
    assert post.latent == ("y",)
    assert float(post.mean["y"][0, 0]) == pytest.approx(5 / 3.25, abs=0.02)
    assert float(post.sd["y"][0, 0]) ** 2 == pytest.approx(1 / 3.25, rel=0.05)
    assert post.samples["y"].shape == (1000, 1, 1)
    assert len(post.loss) == 500 and post.loss[-1] < post.loss[0]


@pytest.mark.slow
def test_state_mvn_guide_captures_correlation():
    """Two latents Y1, Y2 with a common child Z: the posterior is correlated."""
    g = CausalGraph(
        [Variable("y1", "latent"), Variable("y2", "latent"), Variable("z", "observed")],
        [("y1", "z"), ("y2", "z")],
    )
    m = WorldModel(g, {"z": LinearMechanism.from_coefficients([[1.0, 1.0]], sigma=0.5)})
    post = infer_state(m, {"z": torch.tensor([[2.0]])}, guide="mvn", num_steps=800)
    # prior N(0, I), z = y1 + y2 + N(0, .25): posterior mean 2/2.25 each, var 1 - 1/2.25
    assert float(post.mean["y1"][0, 0]) == pytest.approx(2 / 2.25, abs=0.05)
    assert float(post.sd["y1"][0, 0]) ** 2 == pytest.approx(1 - 1 / 2.25, rel=0.1)
    corr = torch.corrcoef(torch.stack([post.samples["y1"].ravel(), post.samples["y2"].ravel()]))[0, 1]
    assert float(corr) == pytest.approx(-(1 / 2.25) / (1 - 1 / 2.25), abs=0.1)


def test_state_errors(chain):
    with pytest.raises(ValueError, match="guide 'x' unknown"):
        infer_state(chain, {"x": torch.ones(1, 1)}, guide="x")
    with pytest.raises(ValueError, match="no latent site"):
        infer_state(chain, FACTUAL)
    with pytest.raises(ValueError, match="both observed and intervened"):
        infer_state(do(chain, {"x": 0.0}), {"x": torch.ones(1, 1)})
    with pytest.raises(ValueError, match="observed is empty"):
        infer_state(chain, {})


@pytest.mark.parametrize(("kind", "members"), [("mlp", 1), ("hetero", 1), ("mlp", 3), ("hetero", 3)])
def test_descendants_only_replay_equals_the_full_intervened_program(kind, members):
    from inference.counterfactual import abduct
    from inference.handlers import Intervene, ReplayNoise
    from inference.interventions import check_interventions
    from models import random_graph

    torch.manual_seed(3)
    model = WorldModel(random_graph(12, seed=3), kind=kind, members=members)
    root = max(model.graph.roots, key=lambda r: len(model.graph.descendants(r)))
    assert 0 < len(model.graph.descendants(root)) < 11  # some sites are left untouched
    factual = model.sample(20, torch.Generator().manual_seed(0))
    scenarios = [{root: 0.5}, {root: lambda x: x + 1.0}, {}]
    fast = counterfactual(model, factual, scenarios)
    noise = abduct(model, factual, 20)
    for k, sc in enumerate(scenarios):  # the whole intervened program, one scenario at a time
        full = Intervene(check_interventions(model.graph, sc))(ReplayNoise(noise)(model))(None, 20)
        for name, value in full.items():
            torch.testing.assert_close(fast.samples[name][0, k], value.detach(), atol=1e-5, rtol=0)
    # the empty scenario reproduces the factual world
    for name, value in factual.items():
        torch.testing.assert_close(fast.samples[name][0, 2], value, atol=1e-5, rtol=0)


def test_nested_interventions_recompute_the_downstream_natural_value(chain):
    fact = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-3.0]])}
    # do(X=0) and shift Y by +1 of its counterfactual natural value 0.5 -> Y = 1.5, Z = -2.25 + 0.75
    cf = counterfactual(chain, fact, {"x": 0.0, "y": lambda y: y + 1.0})
    assert cf.samples["y"].item() == pytest.approx(1.5, abs=1e-5)
    assert cf.samples["z"].item() == pytest.approx(-1.5 * 1.5 + 0.75, abs=1e-5)


# ---------------------------------------------------------------------------- closed forms
def _clamp(s, low=-30.0, high=30.0):
    """The soft clamp of HeteroscedasticMechanism, in float64 by hand."""

    def softplus(v):
        return math.log1p(math.exp(-abs(v))) + max(v, 0.0)

    s = high - softplus(high - s)
    return low + softplus(s - low)


def test_heteroscedastic_counterfactual_matches_the_closed_form():
    """Y = a X + b + exp(c X + d) U_y, Z = e Y + exp(f Y + h) U_z; abduct, do(X = x'), replay."""
    a, b, c, d = 1.5, -0.5, 0.4, -1.0
    e, f, h = -0.8, 0.3, -0.2
    model = WorldModel(
        chain_graph(),
        {
            "y": HeteroscedasticMechanism.from_coefficients(a, b, log_scale_weight=c, log_scale_bias=d),
            "z": HeteroscedasticMechanism.from_coefficients(e, 0.0, log_scale_weight=f, log_scale_bias=h),
        },
    )
    xs, ys, zs = [0.7, -1.2, 2.0], [1.1, -3.0, 2.2], [-0.4, 2.5, -1.0]
    x_new = [-0.3, 1.0, 0.5]
    factual = {k: torch.tensor(v)[:, None] for k, v in (("x", xs), ("y", ys), ("z", zs))}
    cf = counterfactual(model, factual, {"x": torch.tensor(x_new)[:, None]})
    assert cf.exact
    for i in range(3):
        u_y = (ys[i] - (a * xs[i] + b)) / math.exp(_clamp(c * xs[i] + d))
        u_z = (zs[i] - e * ys[i]) / math.exp(_clamp(f * ys[i] + h))
        y_cf = a * x_new[i] + b + math.exp(_clamp(c * x_new[i] + d)) * u_y
        z_cf = e * y_cf + math.exp(_clamp(f * y_cf + h)) * u_z
        assert float(cf.noise["y"][0, i, 0]) == pytest.approx(u_y, abs=1e-5)
        assert float(cf.noise["z"][0, i, 0]) == pytest.approx(u_z, abs=1e-5)
        assert float(cf.samples["y"][0, 0, i, 0]) == pytest.approx(y_cf, abs=1e-5)
        assert float(cf.samples["z"][0, 0, i, 0]) == pytest.approx(z_cf, abs=1e-5)
    # do(Y = y') instead: Z' = e y' + exp(f y' + h) u_z, X and Y's own residual untouched
    cf_y = counterfactual(model, factual, {"y": 0.25})
    for i in range(3):
        u_z = (zs[i] - e * ys[i]) / math.exp(_clamp(f * ys[i] + h))
        z_cf = e * 0.25 + math.exp(_clamp(f * 0.25 + h)) * u_z
        assert float(cf_y.samples["z"][0, 0, i, 0]) == pytest.approx(z_cf, abs=1e-5)
        assert float(cf_y.samples["x"][0, 0, i, 0]) == pytest.approx(xs[i], abs=1e-6)


class LinearScale(Mechanism):
    """X = w pa + b + (c + d pa) eps: a fixed linear sigma(pa), positive for pa > -c/d."""

    def __init__(self, w, b, c, d):
        super().__init__(1, 1, sigma=None)
        self.coef = (w, b, c, d)

    def core(self, z):
        w, b, _, _ = self.coef
        return w * z + b

    def loc_scale(self, parents):
        _, _, c, d = self.coef
        x = self.check_input(parents)
        return self(x), c + d * x


def test_ensemble_counterfactual_matches_the_moment_matched_closed_form():
    """Two members m_k = w_k X + b_k, s_k = c_k + d_k X; Y's site is the moment-matched Normal.

    u = (y - m(x)) / s(x) with m = mean_k m_k, s^2 = mean_k s_k^2 + mean_k (m_k - m)^2, and
    under do(X = x') Y' = m(x') + s(x') u; Z = g Y + 0.5 U_z follows it.
    """
    members = [(2.0, 0.5, 0.3, 0.2), (1.0, -0.5, 0.6, 0.1)]
    g_z = -1.5
    model = WorldModel(
        chain_graph(),
        {
            "y": EnsembleMechanism([LinearScale(*m) for m in members]),
            "z": LinearMechanism.from_coefficients(g_z, sigma=0.5),
        },
    )

    def site(x):
        locs = [w * x + b for w, b, _, _ in members]
        scales = [c + d * x for _, _, c, d in members]
        m = sum(locs) / 2
        var = sum(s**2 for s in scales) / 2 + sum((loc - m) ** 2 for loc in locs) / 2
        return m, math.sqrt(var)

    xs, ys, zs = [0.5, 1.5, 0.1], [1.0, 4.0, -0.7], [-2.0, -5.5, 1.5]
    x_new = [1.2, 0.0, 2.0]
    factual = {k: torch.tensor(v)[:, None] for k, v in (("x", xs), ("y", ys), ("z", zs))}
    cf = counterfactual(model, factual, {"x": torch.tensor(x_new)[:, None]})
    for i in range(3):
        m, s = site(xs[i])
        u_y = (ys[i] - m) / s
        u_z = (zs[i] - g_z * ys[i]) / 0.5
        m_new, s_new = site(x_new[i])
        y_cf = m_new + s_new * u_y
        assert float(cf.noise["y"][0, i, 0]) == pytest.approx(u_y, abs=1e-5)
        assert float(cf.samples["y"][0, 0, i, 0]) == pytest.approx(y_cf, abs=1e-5)
        assert float(cf.samples["z"][0, 0, i, 0]) == pytest.approx(g_z * y_cf + 0.5 * u_z, abs=1e-5)
    # the empty scenario gives the factual world back exactly
    same = counterfactual(model, factual, {})
    torch.testing.assert_close(same.samples["y"][0, 0], factual["y"], atol=1e-6, rtol=0)


def test_a_latent_heteroscedastic_site_is_inferred_then_abducted():
    """Y latent with sigma(x) = exp(0.5 x - 1): the posterior of Y given X, Z is the Gaussian closed form."""
    model = WorldModel(
        chain_graph(),
        {
            "y": HeteroscedasticMechanism.from_coefficients(
                2.0, 0.0, log_scale_weight=0.5, log_scale_bias=-1.0
            ),
            "z": LinearMechanism.from_coefficients(-1.5, sigma=1.0),
        },
    )
    x, z = 1.0, -2.0
    s_y = math.exp(0.5 * x - 1.0)
    # Y | X, Z: prior N(2x, s_y^2), likelihood Z ~ N(-1.5 Y, 1)
    precision = 1 / s_y**2 + 1.5**2
    mean = (2 * x / s_y**2 + (-1.5) * z) / precision
    factual = {"x": torch.tensor([[x]]), "z": torch.tensor([[z]])}
    posterior = infer_state(model, factual, num_steps=300, num_samples=2000, seed=0)
    cf = counterfactual(model, factual, {"x": 0.0}, posterior=posterior)
    assert not cf.exact
    y_post = cf.posterior.samples["y"]
    assert float(y_post.mean()) == pytest.approx(mean, abs=0.05)
    assert float(y_post.std()) == pytest.approx(precision**-0.5, rel=0.15)
    # each draw is abducted exactly: Y' = 0 + exp(-1) * (y - 2x) / s_y
    expected = math.exp(-1.0) * (y_post - 2 * x) / s_y
    torch.testing.assert_close(cf.samples["y"][:, 0], expected, atol=1e-5, rtol=0)


@pytest.mark.parametrize("kind", ["mlp", "hetero", "ensemble"])
def test_torch_abduction_equals_the_program_abduction(kind):
    """The fast path's torch abduction is the AbductNoise handler's, site for site."""
    from inference.abduction import _abduct, _abduct_plain, _torch_abduction
    from inference.program import Program
    from models import finger_graph

    members = 3 if kind == "ensemble" else 1
    m = WorldModel(finger_graph("state"), seed=0, kind="mlp" if kind == "ensemble" else kind, members=members)
    s = m.sample(32, torch.Generator().manual_seed(0))
    acts = {a: s[a] for a in m.graph.actions}
    assert _torch_abduction(m, acts) and not _torch_abduction(m, {})
    want = _abduct(Program(m), s, 32, acts, torch.Generator().manual_seed(0))
    got = _abduct_plain(m, s, acts)
    assert list(got) == list(want)
    for k in want:
        torch.testing.assert_close(got[k], want[k], rtol=0, atol=1e-6)


# ---------------------------------------------------------------------------- gated sites
# c ~ Bernoulli(sigmoid(a - 0.5)); x | c=1 ~ N(2b + 0.5, exp(0.3b - 1)); x | c=0 ~ N(0.5b, 0.05)
G_FLOOR = 0.05


def _gated():
    graph = CausalGraph(
        [Variable(n, "observed") for n in ("a", "b", "c", "x", "y")],
        [("a", "c"), ("b", "x"), ("c", "x"), ("x", "y")],
    )
    on = HeteroscedasticMechanism.from_coefficients(
        [[2.0, 0.0]], 0.5, log_scale_weight=[[0.3, 0.0]], log_scale_bias=-1.0
    )
    off = LinearMechanism.from_coefficients([[0.5, 0.0]], 0.0)
    return WorldModel(
        graph,
        {
            "c": BernoulliMechanism.from_coefficients([1.0], -0.5),
            "x": GatedMechanism("c", on, G_FLOOR, off),
            "y": LinearMechanism.from_coefficients([[-1.5]], 0.2, 0.3),
        },
    )


def _branch(c, b):
    """(f_c(b), sigma_c(b)) of the gated site."""
    return (2 * b + 0.5, math.exp(0.3 * b - 1)) if c else (0.5 * b, G_FLOOR)


G_A, G_B, G_C = [0.3, -1.0, 0.0], [0.7, -0.2, 1.5], [1.0, 0.0, 0.0]
G_X, G_Y = [1.5, -0.12, 0.8], [-2.0, 0.5, -1.0]
G_B_NEW = [0.1, 0.4, -0.6]


def _col(v):
    return torch.tensor(v)[:, None]


def test_gated_counterfactual_with_the_switch_observed_is_exact_per_branch():
    """u = (x - f_c(b)) / sigma_c(b); do(b = b'): x' = f_c(b') + sigma_c(b') u, y' = -1.5 x' + 0.2 + 0.3 u_y."""
    model = _gated()
    factual = {"a": _col(G_A), "b": _col(G_B), "c": _col(G_C), "x": _col(G_X), "y": _col(G_Y)}
    cf = counterfactual(model, factual, [{"b": _col(G_B_NEW)}, {"c": 1.0}], num_samples=4)
    # the switch is set in one scenario and not below b in the other: its Gumbel draws do not
    # matter, so one exact pass answers
    assert cf.exact and cf.samples["x"].shape[0] == 1
    for i in range(3):
        loc, scale = _branch(G_C[i], G_B[i])
        u = (G_X[i] - loc) / scale
        u_y = (G_Y[i] - (-1.5 * G_X[i] + 0.2)) / 0.3
        loc2, scale2 = _branch(G_C[i], G_B_NEW[i])
        x_b = loc2 + scale2 * u
        loc_on, scale_on = _branch(1, G_B[i])
        x_c = loc_on + scale_on * u  # do(c = 1): the on branch replays the same u
        assert cf.noise["x"][:, i, 0].tolist() == pytest.approx([u], abs=1e-5)
        assert cf.samples["x"][:, 0, i, 0].tolist() == pytest.approx([x_b], abs=1e-5)
        assert cf.samples["y"][:, 0, i, 0].tolist() == pytest.approx(
            [-1.5 * x_b + 0.2 + 0.3 * u_y], abs=1e-5
        )
        assert cf.samples["x"][:, 1, i, 0].tolist() == pytest.approx([x_c], abs=1e-5)


def _enumerated(i, b_new):
    """The posterior mixture by hand: w_c ~ p(c | a) N(x; f_c(b), sigma_c(b)), x'_c = f_c(b') + sigma_c(b') u_c."""
    p1 = 1 / (1 + math.exp(-(G_A[i] - 0.5)))
    weights, values = [], []
    for c, prior in ((0, 1 - p1), (1, p1)):
        loc, scale = _branch(c, G_B[i])
        u = (G_X[i] - loc) / scale
        weights.append(prior * math.exp(-0.5 * u * u) / scale)
        loc2, scale2 = _branch(c, b_new)
        values.append(loc2 + scale2 * u)
    total = sum(weights)
    return [w / total for w in weights], values


def test_gated_counterfactual_with_a_latent_switch_is_the_exact_posterior_mixture():
    model = _gated()
    factual = {"a": _col(G_A), "b": _col(G_B), "x": _col(G_X), "y": _col(G_Y)}
    mix = counterfactual_mixture(model, factual, {"b": _col(G_B_NEW)})
    assert mix.latent == ("c",)
    for i in range(3):
        weights, values = _enumerated(i, G_B_NEW[i])
        assert mix.weights[:, i].tolist() == pytest.approx(weights, abs=1e-3)
        expected = sum(w * v for w, v in zip(weights, values, strict=True))
        assert float(mix.mean["x"][0, i, 0]) == pytest.approx(expected, abs=1e-3)
    # the sampled path (c drawn from its exact posterior, then abducted) agrees within its Monte Carlo error
    cf = counterfactual(model, factual, {"b": _col(G_B_NEW)}, num_samples=4000, seed=0)
    for i in range(3):
        weights, values = _enumerated(i, G_B_NEW[i])
        expected = sum(w * v for w, v in zip(weights, values, strict=True))
        sd = math.sqrt(sum(w * (v - expected) ** 2 for w, v in zip(weights, values, strict=True)))
        assert float(cf.mean["x"][0, i, 0]) == pytest.approx(expected, abs=5 * sd / math.sqrt(4000) + 1e-5)


def test_the_mixture_refuses_continuous_latent_sites():
    model = _gated()
    with pytest.raises(ValueError, match=r"continuous: \['x'\]"):
        counterfactual_mixture(
            model, {"a": _col(G_A), "b": _col(G_B), "c": _col(G_C), "y": _col(G_Y)}, {"b": 0.0}
        )


def test_a_set_discrete_site_needs_no_gumbel_draws_and_one_below_an_intervention_does():
    """do(c): c is set, so the answer is one exact pass, identical to many draws; do(a): c is recomputed."""
    model = _gated()
    factual = {"a": _col(G_A), "b": _col(G_B), "c": _col(G_C), "x": _col(G_X), "y": _col(G_Y)}
    scenarios = [{"c": 0.0}, {"c": 1.0}]
    one = counterfactual(model, factual, scenarios, num_samples=200, seed=1)
    assert one.exact and one.samples["x"].shape == (1, 2, 3, 1)
    for i in range(3):  # the closed form per unit: u from the factual branch, replayed in each branch
        loc, scale = _branch(G_C[i], G_B[i])
        u = (G_X[i] - loc) / scale
        for k, c in enumerate((0, 1)):
            loc_k, scale_k = _branch(c, G_B[i])
            assert float(one.samples["x"][0, k, i, 0]) == pytest.approx(loc_k + scale_k * u, abs=1e-5)
    below = counterfactual(model, factual, {"a": _col([3.0, 3.0, -3.0])}, num_samples=50, seed=1)
    assert not below.exact and below.samples["c"].shape[0] == 50
    p_on = below.samples["c"][:, 0, :, 0].mean(0)
    assert float(p_on[0]) == 1.0  # observed on and pushed further on: stays on in every draw
    assert 0.0 < float(p_on[1]) < 1.0  # observed off, pushed on: the Gumbel posterior decides
