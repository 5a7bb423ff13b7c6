"""Perceive: o(t) = (observation, info) -> s_sens(t) ∪ s_vis(t) through the spec (thesis Eq. 4.2-4.3).

:class:`Senses` reads every sensed quantity of an :class:`~pal.agent.spec.EnvSpec` from the
observation and ``info`` of a ``reset`` or ``step``: joint angles (and velocities), the effector,
touch, the goals and the state-based objects. Perception is optional: when the spec names
perceived objects, Π (:class:`pal.perception.Pipeline`) runs on the camera frame of ``info``
with the agent's own body removed (:func:`pal.agent.perception.self_filtered_frame`), and
:class:`pal.agent.perception.ObjectSlots` binds its tracks to the object slots. A slot without
evidence is None (lost), never NaN.

Ground truth that the environment reports for evaluation (``info["truth"]``, ``info["state"]``)
is copied into :attr:`Percept.evaluation` untouched, for the history; the agent never reads it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pal.agent.perception import Measurement, ObjectSlots, self_filtered_frame
from pal.agent.spec import EnvSpec
from pal.perception import PerceptionState, Pipeline, PipelineConfig, RGBDFrame

__all__ = ["Percept", "Senses"]


@dataclass(frozen=True, eq=False)
class Percept:
    """What the agent sensed at one step.

    Attributes:
        q: (J,) joint angles, rad. v: (J,) joint velocities, rad/s, or None.
        effector: (E,) end effector position, m, or None.
        touch: (O,) contact sensed with each object (zeros without touch sensing).
        measurements: object -> :class:`Measurement` (a sensed object has ``std`` 0 and source
            ``"sensed"``) or None (not seen).
        goals: object (or the effector's name) -> (d,) goal position, m, for those whose goal is observed.
        time: s on the agent's clock.
        frame: the self-filtered frame Π saw (perceived objects only).
        perception: Π's state (perceived objects only).
        table_from_camera: (4, 4) camera pose (perceived objects only).
        evaluation: the environment's ground truth for evaluation (``truth``, ``state``), if any.
    """

    q: np.ndarray
    v: np.ndarray | None
    effector: np.ndarray | None
    touch: np.ndarray
    measurements: dict[str, Measurement | None]
    goals: dict[str, np.ndarray]
    time: float
    frame: RGBDFrame | None = None
    perception: PerceptionState | None = None
    table_from_camera: np.ndarray | None = None
    evaluation: dict[str, Any] = field(default_factory=dict)

    @property
    def hand(self) -> np.ndarray | None:
        """Alias of :attr:`effector`."""
        return self.effector


class Senses:
    """Reads percepts through a spec (module docstring).

    Args:
        spec: the environment's spec.
        perception: Π's configuration (used when the spec has perceived objects).
        top_surface: perceived positions are top-surface centres (:func:`pal.agent.perception.top_centre`).
    """

    def __init__(
        self, spec: EnvSpec, perception: PipelineConfig | None = None, top_surface: bool = True
    ) -> None:
        self.spec = spec
        self.pipeline = Pipeline(perception or PipelineConfig(relations=None)) if spec.perceived else None
        self.slots = ObjectSlots(spec.perceived, use_top=top_surface) if spec.perceived else None

    def check_first(self, observation: Any) -> None:
        """Check the transforms on the first observation (cos^2 + sin^2 = 1 ...).

        Raises:
            ValueError: a transform whose entries do not fit, naming the role.
        """
        obs = np.asarray(observation, dtype=np.float64).reshape(-1)
        for role, sensor in self.spec.sensors().items():
            sensor.check_first(obs, role)

    def reset(self) -> None:
        """A new episode: Π and the slot bindings start afresh."""
        if self.pipeline is not None:
            self.pipeline.reset()
            self.slots.reset()

    def read(
        self,
        observation: Any,
        info: Mapping[str, Any],
        time: float,
        reference: Mapping[str, np.ndarray | None] | None = None,
    ) -> Percept:
        """The percept of one ``reset`` or ``step``.

        Args:
            observation: the environment's observation.
            info: its ``info``.
            time: the agent's clock, s (stamps the frame Π sees).
            reference: object -> current estimate (2,) or None; a lost slot is re-bound near it.

        Raises:
            ValueError: an info entry the spec reads is missing or malformed.
        """
        spec = self.spec
        obs = np.asarray(observation, dtype=np.float64).reshape(-1)
        read = lambda sensor, what: sensor.read(obs, info, what)  # noqa: E731
        q = read(spec.angles, "angles")
        v = None if spec.velocities is None else read(spec.velocities, "velocities")
        ee = None if spec.effector is None else read(spec.effector, "effector")
        touch = np.zeros(len(spec.objects)) if spec.touch is None else read(spec.touch, "touch")
        measurements: dict[str, Measurement | None] = {}
        goals: dict[str, np.ndarray] = {}
        for o in spec.objects:
            if o.position is not None:
                p = read(o.position, f"position of {o.name!r}")
                measurements[o.name] = Measurement(p, np.zeros(o.dim), -1, "sensed")
            if o.goal is not None:
                goals[o.name] = read(o.goal, f"goal of {o.name!r}")
        if spec.effector_goal is not None:
            goals[spec.effector_name] = read(spec.effector_goal, "effector goal")
        frame = state = pose = None
        if self.pipeline is not None:
            frame, state, pose, seen = self._perceive(info, time, reference)
            measurements.update(seen)
        evaluation = {k: info[k] for k in ("truth", "state") if k in info}
        return Percept(
            q,
            v,
            ee,
            touch,
            {o: measurements[o] for o in spec.object_names},
            goals,
            time,
            frame,
            state,
            pose,
            evaluation,
        )

    def _perceive(
        self, info: Mapping[str, Any], time: float, reference: Mapping[str, Any] | None
    ) -> tuple[RGBDFrame, PerceptionState, np.ndarray, dict[str, Measurement | None]]:
        key = self.spec.camera
        missing = [k for k in (key, "table_from_camera", "self_mask") if k not in info]
        if missing:
            raise ValueError(
                f"perceived objects need info entries {missing}; the environment's info has {sorted(info)} "
                "(PushingEnv reports its view with camera=True)"
            )
        view = info[key]
        if not isinstance(view, RGBDFrame):
            raise ValueError(f"info[{key!r}] is {type(view).__name__}, expected an RGBDFrame")
        pose = np.asarray(info["table_from_camera"], dtype=np.float64)
        frame = self_filtered_frame(view.rgb, view.depth, view.K, time, info["self_mask"])
        state = self.pipeline(frame)
        seen = self.slots.update(state, pose, dict(reference or {}), float(view.K[1, 1]), frame)
        return frame, state, pose, seen
