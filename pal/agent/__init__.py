"""The agent: the composition root of the perception-action loop (thesis §4.1, §6.3).

- :mod:`pal.agent.loop`: :class:`Agent`, the loop perceive -> estimate state -> target -> act;
- :mod:`pal.agent.world`: the pushing world model, its fitting from the history, sub-models;
- :mod:`pal.agent.perception`: o(t) -> Π -> object variables in table coordinates, object slots;
- :mod:`pal.agent.history`: the sensorimotor history H_t as columns;
- :mod:`pal.agent.curiosity`: curiosity targets over 2-D object variables;
- :mod:`pal.agent.video`: the annotated video of a run.

Only this package, :mod:`pal.experiments` and :mod:`pal.cli` wire the simulator, perception, the
world model and inference together.
"""

from pal.agent.loop import MODES, Agent, AgentConfig, Decision, Percept
from pal.agent.world import build_world_model, candidate_actions, fit_world_model, submodel

__all__ = [
    "MODES",
    "Agent",
    "AgentConfig",
    "Decision",
    "Percept",
    "build_world_model",
    "candidate_actions",
    "fit_world_model",
    "submodel",
]
