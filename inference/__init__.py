"""Algorithms that act on world models through Pyro handlers.

The program contract: ``model.graph`` is a :class:`models.CausalGraph`, and
``model(data, n)`` runs the Pyro program with one sample site per variable, named after
it, inside ``pyro.plate("units", N)``, passing ``data`` as ``obs=``.
:class:`models.WorldModel` is the reference implementation.
"""

from inference.action import ActionResult, gaussian_log_preference, infer_action
from inference.counterfactual import CounterfactualResult, abduct, counterfactual
from inference.curiosity import CuriositySampler, normalized_entropy, occupancy
from inference.fit import FitResult, fit
from inference.handlers import AbductNoise, Intervene, MeasurementScale, ReplayNoise
from inference.interventions import do, simulate
from inference.state import StateResult, infer_state

__all__ = [
    "AbductNoise",
    "ActionResult",
    "CounterfactualResult",
    "CuriositySampler",
    "FitResult",
    "Intervene",
    "MeasurementScale",
    "ReplayNoise",
    "StateResult",
    "abduct",
    "counterfactual",
    "do",
    "fit",
    "gaussian_log_preference",
    "infer_action",
    "infer_state",
    "normalized_entropy",
    "occupancy",
    "simulate",
]
