"""Command ranges of babbling: the ``ctrlrange`` override, and effective ranges found in the data.

An actuator's effective range can be narrower than its ``ctrlrange``: a force limit clamps its
output (``forcerange``, or a joint's ``actuatorfrcrange``), or the joint it drives saturates
(e.g. pinned at a joint limit) so that larger commands change nothing. :func:`effective_ranges`
finds both in babbling data, per actuator with a joint transmission to a recorded joint:

1. The babbled commands u are split into equal-width bins (8 to 40, about 150 rows each) and
   the joint's displacement dq (rad or m per step) is regressed on the bins and, linearly, on
   the joint's state (q_prev, dq_prev): the bin effects are ``E[dq | u]`` at the mean state,
   with standard errors se.
2. A plateau is a run of at least :data:`MIN_PLATEAU_BINS` bins at an end of the range over
   which the response is flat: the upper confidence bound (``z`` se) of its change across the
   run, and every bin's distance from the run's level, stay below ``rel_tol`` of the spread S
   of the bin effects (plus ``z`` se for the distances). It grows inwards while it stays flat.
3. The knee, where the plateau starts, is the corner of the clamped line
   ``dq = level + b min(u - c, 0)`` fitted to the rows around the plateau's first bin.

The measured range runs between the knees (or the babbled ends), and the effective range is
its intersection with the force-limit range of the model
(:func:`pal.sim.body_info.force_limit_ranges`), which is exact where it exists.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pal.checks import check_float

__all__ = [
    "MIN_PLATEAU_BINS",
    "babbling_ranges",
    "effective_ranges",
    "parse_action_range",
]

#: Bins a plateau must span at an end of the range (the detection floor: 3 / bins of the range).
MIN_PLATEAU_BINS = 3
#: Rows per bin aimed at when choosing the number of bins (between 8 and 40 bins).
_ROWS_PER_BIN = 150
#: Fewer rows than this in a bin and the actuator's range is not measured.
_MIN_ROWS_PER_BIN = 8


def parse_action_range(text: str) -> tuple[str, float, float]:
    """``"NAME=LOW,HIGH"`` -> ``(NAME, LOW, HIGH)`` (the text of ``--action-range``).

    Raises:
        ValueError: not of that form, numbers that do not parse or are not finite, or LOW >= HIGH.
    """
    name, sep, values = str(text).rpartition("=")
    parts = values.split(",")
    if not sep or not name or len(parts) != 2:
        raise ValueError(f"action range {text!r} is not NAME=LOW,HIGH (e.g. --action-range joint0=-0.5,0.5)")
    try:
        low, high = float(parts[0]), float(parts[1])
    except ValueError:
        raise ValueError(f"action range {text!r}: LOW and HIGH must be numbers, got {values!r}") from None
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise ValueError(f"action range {text!r}: expected finite LOW < HIGH, got [{low}, {high}]")
    return name, low, high


def babbling_ranges(
    actuators: Sequence[str],
    ctrl_ranges: Mapping[str, tuple[float, float]],
    overrides: Sequence[tuple[str, float, float]] = (),
) -> dict[str, tuple[float, float]]:
    """The command range each babbling actuator babbles over: its ``ctrlrange`` or an override.

    Args:
        actuators: the babbling actuators.
        ctrl_ranges: actuator -> ``(low, high)`` ctrl range.
        overrides: ``(name, low, high)`` triples; each must lie inside the actuator's ctrlrange.

    Returns:
        actuator -> ``(low, high)``, in the order of ``actuators``.

    Raises:
        ValueError: a malformed triple, an actuator that does not babble, an actuator named
            twice, LOW >= HIGH, or a range outside the ctrlrange; the message names the value.
    """
    out = {a: (float(ctrl_ranges[a][0]), float(ctrl_ranges[a][1])) for a in actuators}
    seen: set[str] = set()
    for item in overrides:
        if isinstance(item, str) or not isinstance(item, Sequence) or len(item) != 3:
            raise ValueError(f"action range {item!r} is not a (name, low, high) triple")
        name, low, high = item
        if not isinstance(name, str) or name not in out:
            raise ValueError(
                f"action range for {name!r}: not a babbling actuator; the babbling actuators are {list(out)}"
            )
        if name in seen:
            raise ValueError(f"action range for actuator {name!r} given more than once")
        seen.add(name)
        ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (low, high))
        if not ok or not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise ValueError(f"action range {name}={low!r},{high!r}: expected finite numbers LOW < HIGH")
        c_low, c_high = out[name]
        slack = 1e-9 * max(1.0, abs(c_low), abs(c_high))
        if low < c_low - slack or high > c_high + slack:
            raise ValueError(
                f"action range {name}=[{low}, {high}] lies outside the ctrlrange [{c_low}, {c_high}] of "
                f"actuator {name!r}; choose LOW and HIGH within it"
            )
        out[name] = (float(low), float(high))
    return out


def _flat(centers: np.ndarray, means: np.ndarray, ses: np.ndarray, tol: float, z: float) -> bool:
    """Whether bin means are flat: the change across them is below ``tol`` with confidence."""
    w = 1.0 / np.maximum(ses, 1e-12) ** 2
    dx = centers - np.sum(w * centers) / np.sum(w)
    sxx = float(np.sum(w * dx**2))
    slope = float(np.sum(w * dx * means)) / sxx
    level = float(np.sum(w * means) / np.sum(w))
    change = (abs(slope) + z / np.sqrt(sxx)) * float(centers[-1] - centers[0])
    return change <= tol and bool(np.all(np.abs(means - level) <= tol + z * ses))


def _plateau(centers: np.ndarray, means: np.ndarray, ses: np.ndarray, tol: float, z: float) -> int | None:
    """First bin of the plateau at the high end of the bins, or None without one."""
    start = len(means) - MIN_PLATEAU_BINS
    if start < 1 or not _flat(centers[start:], means[start:], ses[start:], tol, z):
        return None
    while start > 1 and _flat(centers[start - 1 :], means[start - 1 :], ses[start - 1 :], tol, z):
        start -= 1
    return start


def _knee(u: np.ndarray, y: np.ndarray, level: float, low: float, high: float) -> float:
    """The knee c in [low, high] of the clamped line ``y = level + b min(u - c, 0)`` fitted to (u, y).

    A grid of 11 candidates, refined three times around the best (resolution 1e-3 of the span).
    """

    def sse(c: float) -> float:
        x = np.minimum(u - c, 0.0)
        sxx = float(x @ x)
        if sxx == 0.0:
            return np.inf
        r = y - level - (float(x @ (y - level)) / sxx) * x
        return float(r @ r)

    lo, hi = low, high
    for _ in range(3):
        grid = np.linspace(lo, hi, 11)
        best = float(grid[int(np.argmin([sse(c) for c in grid]))])
        step = (hi - lo) / 10
        lo, hi = max(low, best - step), min(high, best + step)
    return best


def _measure(
    u: np.ndarray, y: np.ndarray, state: np.ndarray, low: float, high: float, rel_tol: float, z: float
) -> tuple[tuple[float, float] | None, int]:
    """The range between the plateaus of ``E[y | u]``, adjusted linearly for the joint's state."""
    n_bins = int(np.clip(len(u) // _ROWS_PER_BIN, 8, 40))
    edges = np.linspace(low, high, n_bins + 1)
    centers = (edges[:-1] + edges[1:]) / 2
    idx = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, n_bins - 1)
    counts = np.bincount(idx, minlength=n_bins)
    if counts.min() < _MIN_ROWS_PER_BIN:
        return None, n_bins
    # y = alpha_bin(u) + state @ beta + noise, solved within bins (Frisch-Waugh): the bin
    # effects alpha at the mean state
    state = state - state.mean(0)

    def within(x: np.ndarray) -> np.ndarray:
        return x - (np.bincount(idx, weights=x, minlength=n_bins) / counts)[idx]

    beta, *_ = np.linalg.lstsq(np.stack([within(c) for c in state.T], axis=1), within(y), rcond=None)
    adjusted = y - state @ beta
    means = np.bincount(idx, weights=adjusted, minlength=n_bins) / counts
    var = np.bincount(idx, weights=(adjusted - means[idx]) ** 2, minlength=n_bins) / np.maximum(counts - 1, 1)
    ses = np.sqrt(var / counts)
    spread = float(means.max() - means.min())
    if spread <= 2 * z * float(np.median(ses)):
        return None, n_bins  # no measurable response to the command
    tol = rel_tol * spread
    top = _plateau(centers, means, ses, tol, z)
    rev = _plateau(-centers[::-1], means[::-1], ses[::-1], tol, z)
    bottom = None if rev is None else n_bins - 1 - rev  # last bin of the low plateau
    first, last = (0 if bottom is None else bottom + 1), (n_bins if top is None else top)
    if last - first < 1:
        return None, n_bins  # the response is flat across the range
    mid = float(edges[first] + edges[last]) / 2
    eff_low, eff_high = low, high
    if top is not None:  # the knee lies within two bins before the plateau's first bin, or in it
        near = (u >= max(float(edges[max(top - 4, 0)]), mid)) & (u <= edges[min(top + 3, n_bins)])
        level = float(adjusted[idx > top].mean())
        span = max(float(edges[max(top - 2, 0)]), mid), float(edges[top + 1])
        eff_high = _knee(u[near], adjusted[near], level, *span)
    if bottom is not None:  # the mirror image, in -u
        near = (u <= min(float(edges[min(bottom + 5, n_bins)]), mid)) & (u >= edges[max(bottom - 2, 0)])
        level = float(adjusted[idx < bottom].mean())
        span = -min(float(edges[min(bottom + 3, n_bins)]), mid), -float(edges[bottom])
        eff_low = -_knee(-u[near], adjusted[near], level, *span)
    if not eff_low < eff_high:
        return None, n_bins
    return (float(eff_low), float(eff_high)), n_bins


def effective_ranges(dataset: Any, *, rel_tol: float = 0.05, z: float = 2.0) -> dict[str, dict[str, Any]]:
    """Per babbling actuator, the command range within which the joint still responds.

    Args:
        dataset: a :class:`~pal.io.dataset.TransitionDataset` of babbling (its metadata names the
            actuators, their ctrl, babbled and force-limit ranges and the joints they drive).
        rel_tol: plateau tolerance as a share of the spread of the bin effects, in (0, 1].
        z: confidence of the plateau test, in standard errors (>= 0).

    Returns:
        actuator -> ``{"joint", "ctrlrange", "babbled", "measured", "force_limit",
        "effective", "saturated_fraction", "bins"}``: ranges are ``[low, high]`` in ctrl
        units (``ctrlrange`` has None for an unlimited side); ``measured`` is None when the
        data cannot tell (no joint transmission to a recorded joint, too few rows per bin, or
        no response); ``effective`` is ``measured``
        (else ``babbled``) intersected with ``force_limit``; ``saturated_fraction`` is the
        share of the babbled range outside ``effective``.
    """
    rel_tol = check_float("rel_tol", rel_tol, 0.0, 1.0, open_low=True)
    z = check_float("z", z, 0.0)
    meta = dataset.metadata
    joint_of = {a: j for j, a in meta.get("joint_actuators", {}).items()}
    babbled = meta.get("action_ranges") or meta["actuator_ranges"]
    limits = meta.get("actuator_force_limits", {})
    out: dict[str, dict[str, Any]] = {}
    for k, name in enumerate(dataset.actuators):
        low, high = (float(v) for v in babbled[name])
        joint = joint_of.get(name)
        measured, n_bins = None, 0
        if joint is not None and len(dataset) > 0:
            u = dataset.ctrl[:, k].astype(np.float64)
            cols = dataset.columns
            y = cols[f"dq.{joint}"][:, 0].astype(np.float64)
            state = np.concatenate([cols[f"q_prev.{joint}"], cols[f"dq_prev.{joint}"]], axis=1)
            measured, n_bins = _measure(u, y, state.astype(np.float64), low, high, rel_tol, z)
        eff_low, eff_high = measured or (low, high)
        limit = limits.get(name)
        if limit is not None:
            eff_low, eff_high = max(eff_low, float(limit[0])), min(eff_high, float(limit[1]))
            if not eff_low < eff_high:
                eff_low, eff_high = (low, high) if measured is None else measured
        out[name] = {
            "joint": joint,
            "ctrlrange": list(meta["actuator_ranges"][name]),
            "babbled": [low, high],
            "measured": None if measured is None else list(measured),
            "force_limit": None if limit is None else [float(v) for v in limit],
            "effective": [eff_low, eff_high],
            "saturated_fraction": 1.0 - (eff_high - eff_low) / (high - low),
            "bins": n_bins,
        }
    return out
