"""The bad-input catalogue's shared parts: the case type, the builders both halves use, the checks.

Each entry of ``CASES`` in ``tests/models/test_bad_input.py`` and
``tests/inference/test_bad_input.py`` is one bad call to the public API: the exact exception
type it must raise and a substring of the message that names the offending value or parameter.
A report can count the cases from the repository root with
``from tests.models.test_bad_input import CASES`` (and ``tests.inference.test_bad_input``),
by ``len(CASES)`` or by ``case.area``.
"""

from __future__ import annotations

import warnings
from collections import Counter
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import torch

from inference import PoorPosteriorWarning
from models import (
    CausalGraph,
    LinearMechanism,
    Role,
    Variable,
    WorldModel,
    chain_graph,
    finger_graph,
)

NAN, INF = float("nan"), float("inf")


class BadInput(NamedTuple):
    """One bad call: ``call()`` must raise exactly ``error`` with ``match`` in its message."""

    area: str
    id: str
    call: Callable[[], Any]
    error: type[Exception]
    match: str


def bad(
    area: str, id_: str, call: Callable[[], Any], match: str, error: type[Exception] = ValueError
) -> BadInput:
    """One case; ``error`` defaults to ``ValueError``."""
    return BadInput(area, id_, call, error, match)


# ---------------------------------------------------------------------------- builders
def chain() -> WorldModel:
    """Y = 2X + U_y, Z = -1.5Y + U_z."""
    return WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients([[2.0]]), "z": LinearMechanism.from_coefficients([[-1.5]])},
    )


def finger() -> WorldModel:
    return WorldModel(finger_graph("state"), seed=0, hidden=(4,))


def xy_graph() -> CausalGraph:
    return CausalGraph([Variable("x", "observed"), Variable("y", "latent")], [("x", "y")])


def scalars(*names: str) -> list[Variable]:
    return [Variable(n, Role.OBSERVED) for n in names]


FACTUAL = {"x": torch.tensor([[1.0]]), "y": torch.tensor([[2.5]]), "z": torch.tensor([[-3.0]])}
FSTATE = {"q_prev.finger": torch.zeros(2, 1)}
FIN = {"act.finger": torch.zeros(2, 1), "q_prev.finger": torch.zeros(2, 1)}


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


# ---------------------------------------------------------------------------- checks
RAW = (TypeError, KeyError, RuntimeError, AttributeError, IndexError, AssertionError, NotImplementedError)

_OUTCOMES: dict[int, BaseException | None] = {}


def outcome(case: BadInput) -> BaseException | None:
    """The exception ``case.call()`` raises (None if it returns); computed once per case."""
    key = id(case)
    if key not in _OUTCOMES:
        try:
            with warnings.catch_warnings():
                # a call may fit a few SVI steps before the check that refuses it
                warnings.simplefilter("ignore", PoorPosteriorWarning)
                case.call()
        except Exception as err:  # the raised error is what the tests inspect
            _OUTCOMES[key] = err
        else:
            _OUTCOMES[key] = None
    return _OUTCOMES[key]


def duplicate_ids(cases: list[BadInput]) -> list[tuple[str, str]]:
    """The ``(area, id)`` keys given to more than one case."""
    keys = Counter((c.area, c.id) for c in cases)
    return [k for k, n in keys.items() if n > 1]


def check(case: BadInput) -> None:
    """``case.call()`` raises exactly ``case.error`` with ``case.match`` in its message."""
    err = outcome(case)
    assert err is not None, f"{case.id}: no error raised"
    assert type(err) is case.error, f"{case.id}: {type(err).__name__}: {err}"
    assert case.match in str(err), f"{case.id}: {case.match!r} not in {str(err)!r}"


def raw_errors(cases: list[BadInput]) -> list[str]:
    """Cases that raise a raw library error (or nothing) instead of a specific one."""
    raw = []
    for case in cases:
        err = outcome(case)
        if isinstance(err, RAW) or err is None:
            raw.append(f"{case.area}: {case.id}: {type(err).__name__}: {err}")
    return raw
