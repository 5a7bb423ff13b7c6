"""Algorithms that act on world models through Pyro handlers.

The program contract: ``model.graph`` is a :class:`models.CausalGraph`, and
``model(data, n)`` runs the Pyro program with one sample site per variable, named after
it, inside ``pyro.plate("units", N)``, passing ``data`` as ``obs=``.
:class:`models.WorldModel` is the reference implementation.
"""

from inference.action import ActionOptions, ActionResult, gaussian_log_preference, infer_action
from inference.admissible import admissible_parents
from inference.calibration import predictive_check
from inference.context import active_subgraph, subgraph_model
from inference.counterfactual import CounterfactualResult, abduct, counterfactual
from inference.counterfactual_mixture import MixtureCounterfactual, counterfactual_mixture
from inference.curiosity import CuriositySampler, normalized_entropy, occupancy
from inference.diagnostics import Diagnostics, PoorPosteriorWarning
from inference.discovery import DiscoveryOptions, DiscoveryResult, discover, shd
from inference.effects import EffectResult, treatment_effect
from inference.ensemble import Ensemble
from inference.equivalence import CPDAG, EdgeComparison, compare_edges, cpdag
from inference.fit import CalibrationOptions, FitResult, FitSchedule, fit
from inference.handlers import AbductNoise, Intervene, MeasurementScale, ReplayNoise
from inference.importance import ImportanceOptions
from inference.interventions import do, simulate
from inference.metalearn import ResidualMonitor, Revision, revise
from inference.planning import SamplingConfig
from inference.predictive import (
    PredictiveInterval,
    coverage_by_regime,
    predictive_interval,
    predictive_intervals,
)
from inference.program import Program
from inference.quadrature import GridOptions
from inference.rewire import RewireResult, rewire
from inference.state import StateResult, infer_state
from inference.svi_state import SVIOptions
from inference.unit_effects import UnitEffects, unit_effects

__all__ = [
    "CPDAG",
    "AbductNoise",
    "ActionOptions",
    "ActionResult",
    "CalibrationOptions",
    "CounterfactualResult",
    "CuriositySampler",
    "Diagnostics",
    "DiscoveryOptions",
    "DiscoveryResult",
    "EdgeComparison",
    "EffectResult",
    "Ensemble",
    "FitResult",
    "FitSchedule",
    "GridOptions",
    "ImportanceOptions",
    "Intervene",
    "MeasurementScale",
    "MixtureCounterfactual",
    "PoorPosteriorWarning",
    "PredictiveInterval",
    "Program",
    "ReplayNoise",
    "ResidualMonitor",
    "Revision",
    "RewireResult",
    "SVIOptions",
    "SamplingConfig",
    "StateResult",
    "UnitEffects",
    "abduct",
    "active_subgraph",
    "admissible_parents",
    "compare_edges",
    "counterfactual",
    "counterfactual_mixture",
    "coverage_by_regime",
    "cpdag",
    "discover",
    "do",
    "fit",
    "gaussian_log_preference",
    "infer_action",
    "infer_state",
    "normalized_entropy",
    "occupancy",
    "predictive_check",
    "predictive_interval",
    "predictive_intervals",
    "revise",
    "rewire",
    "shd",
    "simulate",
    "subgraph_model",
    "treatment_effect",
    "unit_effects",
]
