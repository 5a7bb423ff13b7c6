import numpy as np
import pytest

from inference import CuriositySampler, normalized_entropy, occupancy


def sampler(**kw):
    s = CuriositySampler(0.0, 1.0, bins=10, **kw)
    # bin k visited 10 * (k + 1) times except bin 9 (never)
    values = np.concatenate([np.full(10 * (k + 1), (k + 0.5) / 10) for k in range(9)])
    return s.fit(values)


@pytest.mark.parametrize("form", ["count", "inverse"])
def test_density_sums_to_one_and_favours_rare_bins(form):
    s = sampler(form=form, alpha=0.0)
    p = s.density()
    assert p.sum() == pytest.approx(1.0)
    assert np.all(np.diff(p[:9]) < 0)  # more visits -> less curiosity
    assert p[9] == p.max()


def test_count_form_is_eq_5_8():
    s = sampler(alpha=0.5, sigma=0.1, eps=1.0)
    c = s.counts_.astype(float)
    cur = 0.33
    raw = (c.max() - c + 1.0) * (1 + 0.5 * np.exp(-0.5 * ((s.centers_ - cur) / 0.1) ** 2))
    np.testing.assert_allclose(s.density([cur])[0], raw / raw.sum(), rtol=1e-12)


def test_inverse_form_is_eq_4_34():
    s = sampler(form="inverse", alpha=0.0, eps=1e-3)
    p_hat = s.counts_ / s.counts_.sum()
    raw = 1 / (p_hat + 1e-3)
    np.testing.assert_allclose(s.density(), raw / raw.sum(), rtol=1e-12)


def test_locality_favours_bins_near_the_current_value():
    flat = CuriositySampler(0.0, 1.0, bins=10, alpha=2.0).fit(np.linspace(0, 1, 1000))
    p = flat.density([0.05, 0.95])
    assert p.shape == (2, 10)
    assert np.argmax(p[0]) == 0 and np.argmax(p[1]) == 9
    assert p[0, 0] > p[0, 5] and p[1, 9] > p[1, 5]
    no_locality = CuriositySampler(0.0, 1.0, bins=10, alpha=0.0).fit(np.linspace(0, 1, 1000))
    np.testing.assert_allclose(no_locality.density([0.05])[0], np.full(10, 0.1))


def test_sampling_follows_the_density():
    s = sampler(alpha=0.5)
    rng = np.random.default_rng(0)
    targets = s.sample(rng, np.full(20000, 0.5))
    assert targets.shape == (20000,)
    assert targets.min() >= 0.0 and targets.max() <= 1.0
    freq = np.histogram(targets, bins=10, range=(0, 1))[0] / 20000
    np.testing.assert_allclose(freq, s.density([0.5])[0], atol=0.01)
    again = s.sample(np.random.default_rng(0), np.full(20000, 0.5))
    np.testing.assert_array_equal(targets, again)
    assert s.sample(rng, size=5).shape == (5,)


def test_metrics():
    assert occupancy([0.05, 0.15, 0.15], 0, 1, 10) == pytest.approx(0.2)
    assert normalized_entropy(np.linspace(0, 1, 1000), 0, 1, 10) == pytest.approx(1.0, abs=1e-3)
    assert normalized_entropy(np.full(5, 0.5), 0, 1, 10) == pytest.approx(0.0)
    s = sampler()
    assert s.occupancy() == pytest.approx(0.9)
    assert 0 < s.normalized_entropy() < 1
    s.partial_fit([0.95])
    assert s.occupancy() == pytest.approx(1.0)
    fig = s.plot(current=0.5)
    bars, density = fig.axes[0], fig.axes[1]
    heights = [p.get_height() for p in bars.patches]
    np.testing.assert_array_equal(heights, s.counts_)  # one bar per bin, the visit counts
    assert bars.get_xlabel() == "value" and bars.get_ylabel() == "visits" and density.get_ylabel() == "p_tar"
    step = density.get_lines()[0].get_ydata()
    np.testing.assert_allclose(step, s.density([0.5]).reshape(-1))
    assert bars.get_lines()[0].get_xdata()[0] == 0.5  # the current value is marked


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"low": 1.0, "high": 0.0}, "need finite low < high"),
        ({"bins": 1}, "bins must be an int >= 2"),
        ({"alpha": -1.0}, "alpha must be >= 0"),
        ({"sigma": 0.0}, "sigma must be > 0"),
        ({"form": "log"}, "form 'log' unknown"),
        ({"eps": 0.0}, "eps must be > 0"),
    ],
)
def test_bad_parameters(kwargs, match):
    args = {"low": 0.0, "high": 1.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        CuriositySampler(**args)


def test_bad_values_and_rng():
    s = CuriositySampler(0.0, 1.0)
    with pytest.raises(ValueError, match="NaN or inf"):
        s.fit([0.1, np.nan])
    with pytest.raises(ValueError, match="expected \\(N,\\) or \\(N, 1\\)"):
        s.fit(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="numpy.random.Generator"):
        s.sample(None, [0.5])
