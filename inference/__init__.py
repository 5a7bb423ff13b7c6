"""Algorithms that act on world models through Pyro handlers.

The program contract: ``model.graph`` is a :class:`models.CausalGraph`, and
``model(data, n)`` runs the Pyro program with one sample site per variable, named after
it, inside ``pyro.plate("units", N)``, passing ``data`` as ``obs=``.
:class:`models.WorldModel` is the reference implementation.
"""

from inference.action import ActionResult, gaussian_log_preference, infer_action
from inference.admissible import admissible_parents
from inference.calibration import predictive_check
from inference.context import active_subgraph, subgraph_model
from inference.counterfactual import CounterfactualResult, abduct, counterfactual
from inference.curiosity import CuriositySampler, normalized_entropy, occupancy
from inference.discovery import DiscoveryResult, discover, shd
from inference.ensemble import Ensemble
from inference.fit import FitResult, fit
from inference.handlers import AbductNoise, Intervene, MeasurementScale, ReplayNoise
from inference.interventions import do, simulate
from inference.metalearn import ResidualMonitor, Revision, revise
from inference.planning import SamplingConfig
from inference.rewire import RewireResult, rewire
from inference.state import StateResult, infer_state

__all__ = [
    "AbductNoise",
    "ActionResult",
    "CounterfactualResult",
    "CuriositySampler",
    "DiscoveryResult",
    "Ensemble",
    "FitResult",
    "Intervene",
    "MeasurementScale",
    "ReplayNoise",
    "ResidualMonitor",
    "Revision",
    "RewireResult",
    "SamplingConfig",
    "StateResult",
    "abduct",
    "active_subgraph",
    "admissible_parents",
    "counterfactual",
    "discover",
    "do",
    "fit",
    "gaussian_log_preference",
    "infer_action",
    "infer_state",
    "normalized_entropy",
    "occupancy",
    "predictive_check",
    "revise",
    "rewire",
    "shd",
    "simulate",
    "subgraph_model",
]
