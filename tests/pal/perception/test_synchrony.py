"""The synchrony of all pairs at once equals the synchrony of one pair at a time."""

from __future__ import annotations

import numpy as np

from pal.perception.synchrony import distinct_history, pair_synchrony, velocity_correlation


def _histories(seed: int = 0) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Objects seen at 30 Hz with gaps and a repeated frame: still, moving together, moving apart."""
    rng = np.random.default_rng(seed)
    times = np.arange(40) / 30.0
    out = {}
    for i in range(7):
        seen = rng.random(40) > (0.0 if i < 2 else 0.3)
        t = times[seen]
        if i == 3:
            t = np.sort(np.concatenate([t, t[5:6]]))  # one frame twice
        drift = [0.0, 0.0, 0.0] if i in (0, 4) else [0.1, 0.05 * (i % 2), 0.0] if i < 5 else [-0.2, 0.0, 0.1]
        p = np.outer(t, drift) + rng.normal(0.0, 0.0001, (len(t), 3))
        out[i] = distinct_history((t, p))
    out[7] = distinct_history((times[:2], np.zeros((2, 3))))  # too short
    return out


def test_all_pairs_at_once_equal_each_pair_alone():
    hist = _histories()
    pairs = [(a, b) for a in range(9) for b in range(9) if a < b]
    for now, window in ((39 / 30.0, 1.0), (39 / 30.0, 0.05), (2.0, 1.0)):
        got = pair_synchrony(pairs, hist, now, window, 0.02)
        empty = (np.zeros(0), np.zeros((0, 3)))
        for (a, b), g in zip(pairs, got, strict=True):
            ref = velocity_correlation(hist.get(a, empty), hist.get(b, empty), now, window, 0.02)
            assert (g is None) == (ref is None), (a, b, now, window)
            if ref is not None and g is not None:
                np.testing.assert_allclose(g, ref, rtol=1e-12, atol=1e-15)
    # the known answers: two objects moving the same way correlate, a still one with a moving one is 0
    one = dict(zip(pairs, pair_synchrony(pairs, hist, 39 / 30.0, 1.0, 0.02), strict=True))
    assert one[(1, 3)] > 0.9 and one[(0, 1)] == 0.0 and one[(0, 4)] is None and one[(1, 7)] is None
    assert pair_synchrony([], hist, 1.0, 1.0, 0.02) == []
