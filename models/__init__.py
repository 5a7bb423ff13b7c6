"""World-model programs: typed variables, causal graphs, mechanisms and the Pyro SCM.

Depends on torch, pyro and networkx only.
"""

from models.discrete import BernoulliMechanism, CategoricalMechanism, DiscreteMechanism
from models.ensemble import EnsembleMechanism
from models.gated import GatedMechanism
from models.graph import CausalGraph
from models.heteroscedastic import HeteroscedasticMechanism
from models.io import ModelFileError, load, save
from models.kinematics import (
    JointLimitMechanism,
    KinematicChain,
    KinematicMechanism,
    KinematicPointsMechanism,
)
from models.mechanisms import FunctionMechanism, LinearMechanism, Mechanism, MLPMechanism
from models.presets import chain_graph, finger_graph, joint_chain_graph, pushing_graph, random_graph
from models.push_frame import FromPushFrameMechanism, PushFrameMechanism
from models.tables import Table, as_table
from models.variables import Role, Variable
from models.world import WorldModel

__all__ = [
    "BernoulliMechanism",
    "CategoricalMechanism",
    "CausalGraph",
    "DiscreteMechanism",
    "EnsembleMechanism",
    "FromPushFrameMechanism",
    "FunctionMechanism",
    "GatedMechanism",
    "HeteroscedasticMechanism",
    "JointLimitMechanism",
    "KinematicChain",
    "KinematicMechanism",
    "KinematicPointsMechanism",
    "LinearMechanism",
    "MLPMechanism",
    "Mechanism",
    "ModelFileError",
    "PushFrameMechanism",
    "Role",
    "Table",
    "Variable",
    "WorldModel",
    "as_table",
    "chain_graph",
    "finger_graph",
    "joint_chain_graph",
    "load",
    "pushing_graph",
    "random_graph",
    "save",
]
