"""The agent: the composition root of the perception-action loop (thesis §4.1, §6.3), over any Gymnasium env.

- :mod:`pal.agent.spec`: :class:`EnvSpec`, which observation entries or perceived objects are what;
  :mod:`pal.agent.transforms`: sensor transforms (angles from cos/sin, absolute from relative);
  :mod:`pal.agent.body_checks`: the spec against a MuJoCo env's own model (actuator kinds, qpos, qvel);
- :mod:`pal.agent.goals`: what the goal mode reaches for (objects or the effector);
- :mod:`pal.agent.correction`: online correction of the rollouts from abducted residuals;
- :mod:`pal.agent.graph`: the world model built from the spec (a generalised pushing graph);
- :mod:`pal.agent.senses`: perceive, o(t) -> percept (Π optional); :mod:`pal.agent.perception`: Π's front end;
- :mod:`pal.agent.estimate`: the belief through the measurement sites;
- :mod:`pal.agent.plan`: the planner, a pure function of model, belief and target (MPC);
- :mod:`pal.agent.explore`: curiosity that seeks contact (the contact gate times the on branch's disagreement, with novelty);
- :mod:`pal.agent.influence`: curiosity by ensemble disagreement gated by causal action influence;
- :mod:`pal.agent.curiosity`: the density-based curiosity of Eq. 4.34-4.38 on a grid;
- :mod:`pal.agent.learn`: refits and structural revisions; :mod:`pal.agent.aggregate`: PETS-style data aggregation;
- :mod:`pal.agent.loop`: :class:`Agent`, which composes them; :mod:`pal.agent.config`: its settings;
- :mod:`pal.agent.history`: the sensorimotor history H_t; :mod:`pal.agent.video`: the annotated video.

Only this package, :mod:`pal.experiments` and :mod:`pal.cli` wire the simulator, perception, the
world model and inference together.
"""

from pal.agent.config import (
    AgentConfig,
    BabbleConfig,
    CorrectionConfig,
    CuriosityConfig,
    EstimateConfig,
    LearnConfig,
    ModelConfig,
    PlanConfig,
)
from pal.agent.graph import blanket, build_graph, build_model, discover_parents, restrict
from pal.agent.learn import fit_model
from pal.agent.loop import MODES, Agent, Decision
from pal.agent.plan import Plan, plan
from pal.agent.rollout_fit import RolloutFit
from pal.agent.senses import Percept
from pal.agent.spec import EnvSpec, ObjectSpec, Sensor, check_env, pusher_spec, pushing_spec, reacher_spec
from pal.agent.transforms import Transform, absolute_from_relative, angle_from_cos_sin, index_map

__all__ = [
    "MODES",
    "Agent",
    "AgentConfig",
    "BabbleConfig",
    "CorrectionConfig",
    "CuriosityConfig",
    "Decision",
    "EnvSpec",
    "EstimateConfig",
    "LearnConfig",
    "ModelConfig",
    "ObjectSpec",
    "Percept",
    "Plan",
    "PlanConfig",
    "RolloutFit",
    "Sensor",
    "Transform",
    "absolute_from_relative",
    "angle_from_cos_sin",
    "blanket",
    "build_graph",
    "build_model",
    "check_env",
    "discover_parents",
    "fit_model",
    "index_map",
    "plan",
    "pusher_spec",
    "pushing_spec",
    "reacher_spec",
    "restrict",
]
