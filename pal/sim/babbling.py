"""The motor-babbling data source: steps a :class:`BabblingEnv` under a babbling policy.

Protocol (thesis §5.2.1): at every environment step the policy draws a command for each
selected actuator, the body moves for ``frame_skip`` MuJoCo steps, and the transition
``(act, q(t-1), dq(t-1), dq, q(t))`` is recorded per joint together with the full simulator
state before the step; ``dq_prev(t) = dq(t-1) = q(t-1) - q(t-2)`` is the previous step's
displacement, 0 for the first step of an episode (the body starts at rest). The environment
resets every ``reset_every`` steps (thesis: 10 000).

Commands are drawn over each actuator's ``ctrlrange``, or over a narrower override
(``action_ranges``), or over the effective range (``effective_range=True``: a short probe run
of ``probe_steps`` finds it with :func:`~pal.sim.ranges.effective_ranges`, seeded by
``SeedSequence([seed, 2])``). Every dataset's metadata reports the effective ranges found in
it.

Seeds: the policy draws from ``default_rng(SeedSequence([seed, 0]))``; the reset of episode
e uses ``episode_seed(seed, e)``. Everything else is deterministic, so a run is a function
of its :class:`BabbleConfig`, and a resumed run (:func:`babble` with ``resume=True``)
produces the same rows as an uninterrupted one. The stepping backend (:data:`BACKENDS`:
``mj_step`` from Python, or ``mujoco.rollout``) does not change a single bit of the data.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from pal.checks import MAX_STEPS, check_int, check_seed
from pal.io.dataset import FORMAT, DatasetFileError, DatasetWriter, TransitionDataset, column_names
from pal.sim.batched import rollout_steps
from pal.sim.bodies import check_name, load_model
from pal.sim.env import STATE_SPEC, BabblingEnv
from pal.sim.policies import POLICIES, make_policy
from pal.sim.ranges import babbling_ranges, effective_ranges
from pal.sim.transitions import TransitionBlock

__all__ = [
    "BACKENDS",
    "BabbleConfig",
    "BabblingSource",
    "TransitionBlock",  # re-exported from pal.sim.transitions
    "babble",
    "check_config",
    "collect",
    "effective_ranges",
    "episode_seed",
    "make_source",
    "probe_seed",
    "replay",
]

logger = logging.getLogger(__name__)


#: Stepping backends of :class:`BabblingSource` (same transitions, bit for bit).
BACKENDS = ("loop", "rollout")


def episode_seed(seed: int, episode: int) -> int:
    """The ``env.reset`` seed of episode ``episode`` of a run seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, 1, episode]).generate_state(1)[0])


@dataclass(frozen=True)
class BabbleConfig:
    """A babbling run.

    Attributes:
        body: shipped body name (``"finger"``, ``"arm"``) or a path to an MJCF file.
        joints: recorded joints (default all hinge/slide joints).
        actuators: babbling actuators (default all that drive a recorded joint).
        steps: number of transitions, at most :data:`pal.checks.MAX_STEPS`.
        seed: master seed, in ``[0, 2**32 - 1]``.
        policy: ``"uniform"`` or ``"ou"``.
        policy_params: extra policy parameters (``{"theta": 1.0, "sigma": 0.5}`` for ``"ou"``).
        frame_skip: MuJoCo steps per transition (50: 0.25 s).
        reset_every: environment reset period, steps.
        reset_noise: reset noise half-width on joint positions, rad.
        chunk_size: rows per chunk file when writing to disk.
        name: the body's name in metadata and reports (default the model's own name).
        action_ranges: ``(actuator, low, high)`` triples babbled instead of the ctrlrange
            (each inside it).
        effective_range: babble over the effective ranges found by a probe run.
        probe_steps: transitions of that probe run.
    """

    body: str = "finger"
    joints: tuple[str, ...] | None = None
    actuators: tuple[str, ...] | None = None
    steps: int = 100_000
    seed: int = 0
    policy: str = "uniform"
    policy_params: dict[str, float] = field(default_factory=dict)
    frame_skip: int = 50
    reset_every: int = 10_000
    reset_noise: float = 0.0
    chunk_size: int = 10_000
    name: str | None = None
    action_ranges: tuple[tuple[str, float, float], ...] = ()
    effective_range: bool = False
    probe_steps: int = 2000

    def __post_init__(self) -> None:
        check_int("steps", self.steps, minimum=0, maximum=MAX_STEPS)
        check_seed("seed", self.seed)
        for key in ("reset_every", "chunk_size", "frame_skip", "probe_steps"):
            check_int(key, getattr(self, key))
        if self.name is not None:
            check_name("body name", self.name)
        bad = [r for r in self.action_ranges if not isinstance(r, (tuple, list))]
        if bad:
            raise ValueError(f"action_ranges entries must be (actuator, low, high) triples, got {bad}")
        object.__setattr__(self, "action_ranges", tuple(tuple(r) for r in self.action_ranges))
        if not isinstance(self.effective_range, bool):
            raise ValueError(f"effective_range must be True or False, got {self.effective_range!r}")
        if self.policy not in POLICIES:
            raise ValueError(f"unknown policy {self.policy!r}; expected one of {POLICIES}")
        for key in ("joints", "actuators"):
            value = getattr(self, key)
            if isinstance(value, str):
                raise ValueError(f"{key} must be a tuple of names, got the string {value!r}")


class BabblingSource:
    """Generates babbling transitions from an environment and a policy.

    Args:
        env: the environment (its actuators are the policy's).
        policy: a :class:`~pal.sim.policies.Policy` over ``env.actuator_names``.
        seed: master seed (episode reset seeds derive from it).
        reset_every: reset period, steps.
        probe: what the effective-range probe found (metadata), or None.
        backend: ``"loop"`` (``mj_step`` from Python, the default) or ``"rollout"`` (each step
            one ``mujoco.rollout`` call, :func:`pal.sim.batched.rollout_steps`); both give the
            same transitions bit for bit.
    """

    def __init__(
        self,
        env: BabblingEnv,
        policy: Any,
        *,
        seed: int,
        reset_every: int,
        probe: dict[str, Any] | None = None,
        backend: str = "loop",
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"unknown backend {backend!r}; expected one of {BACKENDS}")
        self.env, self.policy, self.seed, self.reset_every = env, policy, int(seed), int(reset_every)
        self.backend = backend
        self.probe = probe
        self.step_index = 0
        self._last_dq = np.zeros(len(env.qpos_indices))

    @property
    def action_ranges(self) -> dict[str, tuple[float, float]]:
        """The command range each actuator babbles over: actuator -> ``(low, high)``."""
        return {
            a: (float(lo), float(hi))
            for a, lo, hi in zip(self.env.actuator_names, self.policy.low, self.policy.high, strict=True)
        }

    def blocks(self, steps: int, block_size: int) -> Iterator[TransitionBlock]:
        """Run ``steps`` more steps, yielding blocks of at most ``block_size`` rows."""
        end = self.step_index + steps
        while self.step_index < end:
            yield self.run(min(block_size, end - self.step_index))

    def __iter__(self) -> Iterator[dict[str, Any]]:
        """Endless single transitions: dicts with ``ctrl``, ``q_prev``, ``dq_prev``, ``q``, ``state``, ``step``, ``episode``."""
        while True:
            b = self.run(1)
            yield {
                "ctrl": b.ctrl[0],
                "q_prev": b.q_prev[0],
                "dq_prev": b.dq_prev[0],
                "q": b.q[0],
                "state": b.states[0],
                "step": int(b.step[0]),
                "episode": int(b.episode[0]),
            }

    def run(self, n: int) -> TransitionBlock:
        """The next ``n`` transitions (one ``mj_step(nstep=frame_skip)``, or one ``mujoco.rollout`` call, each)."""
        env = self.env
        m, d, fs = env.model, env.data, env.frame_skip
        qidx, aidx = env.qpos_indices, env.actuator_ids
        acts = self.policy.sample(n)
        applied = np.clip(acts.astype(np.float64), env.ctrl_low, env.ctrl_high)
        q_prev = np.empty((n, len(qidx)))
        q = np.empty((n, len(qidx)))
        vidx = env.qvel_indices
        v_prev, v = np.empty((n, len(vidx))), np.empty((n, len(vidx)))
        states = np.empty((n, env.state_size))
        steps = np.arange(self.step_index, self.step_index + n, dtype=np.int64)
        episode = steps // self.reset_every
        qpos, ctrl = d.qpos, d.ctrl
        k, every = self.step_index, self.reset_every
        if self.backend == "rollout":

            def reset(i: int) -> bool:
                if (k + i) % every:
                    return False
                env.reset(seed=episode_seed(self.seed, (k + i) // every))
                return True

            states, after = rollout_steps(env, applied, reset)
            q_prev[:] = states[:, 1 + qidx]  # time, qpos, qvel ... in both signatures
            q[:] = after[:, 1 + qidx]
            v_prev[:] = states[:, 1 + m.nq + vidx]
            v[:] = after[:, 1 + m.nq + vidx]
        else:
            for i in range(n):
                if (k + i) % every == 0:
                    env.reset(seed=episode_seed(self.seed, (k + i) // every))
                mujoco.mj_getState(m, d, states[i], STATE_SPEC)
                q_prev[i] = qpos[qidx]
                v_prev[i] = d.qvel[vidx]
                ctrl[aidx] = applied[i]
                mujoco.mj_step(m, d, fs)
                q[i] = qpos[qidx]
                v[i] = d.qvel[vidx]
        dq = q - q_prev
        dq_prev = np.empty_like(dq)
        dq_prev[0] = self._last_dq
        dq_prev[1:] = dq[:-1]
        dq_prev[steps % every == 0] = 0.0  # an episode starts at rest
        if n:
            self._last_dq = dq[-1].copy()
        self.step_index += n
        return TransitionBlock(
            applied.astype(np.float32), q_prev, q, dq_prev, states, steps, episode, v_prev, v
        )

    # ------------------------------------------------------------------ resuming
    def resume_state(self) -> dict[str, Any]:
        """JSON-compatible state to continue exactly from here (see :meth:`restore`)."""
        return {
            "step": self.step_index,
            "policy": self.policy.get_state(),
            "sim_state": self.env.get_state().tolist(),
            "dq_prev": self._last_dq.tolist(),
        }

    def restore(self, state: dict[str, Any]) -> None:
        """Continue from a :meth:`resume_state` (simulator, policy generator, step counter)."""
        self.step_index = int(state["step"])
        self.policy.set_state(state["policy"])
        if self.step_index % self.reset_every != 0:  # otherwise the next step resets anyway
            self.env.set_state(np.asarray(state["sim_state"], np.float64))
            self._last_dq = np.asarray(state["dq_prev"], np.float64)

    # ------------------------------------------------------------------ dataset glue
    def columns(self, block: TransitionBlock) -> dict[str, np.ndarray]:
        """The per-joint ``(n, 1)`` float32 columns of a block (``dq``, ``dq_prev`` from float64 positions)."""
        env, out = self.env, {}
        for c, j in enumerate(env.joint_names):
            if j in env.joint_actuators:
                a = env.actuator_names.index(env.joint_actuators[j])
                out[f"act.{j}"] = block.ctrl[:, a : a + 1].copy()
            out[f"q_prev.{j}"] = block.q_prev[:, c : c + 1].astype(np.float32)
            out[f"dq_prev.{j}"] = block.dq_prev[:, c : c + 1].astype(np.float32)
            out[f"dq.{j}"] = (block.q[:, c : c + 1] - block.q_prev[:, c : c + 1]).astype(np.float32)
            out[f"q.{j}"] = block.q[:, c : c + 1].astype(np.float32)
            if block.v is not None:
                out[f"v_prev.{j}"] = block.v_prev[:, c : c + 1].astype(np.float32)
                out[f"v.{j}"] = block.v[:, c : c + 1].astype(np.float32)
        return out

    def metadata(self, config: BabbleConfig) -> dict[str, Any]:
        """Dataset metadata: body, model hash, physics settings, names, ranges, policy, seeds.

        ``actuator_ranges`` are the ctrl ranges (None for an unlimited side), ``action_ranges`` the babbled ranges,
        ``actuator_force_limits`` the commands within which no force limit binds (or None).
        """
        env = self.env
        return {
            "body": env.loaded.name,
            "mjcf_path": str(env.loaded.path),
            "mjcf_sha256": env.loaded.sha256,
            "timestep": float(env.model.opt.timestep),
            "frame_skip": env.frame_skip,
            "dt": env.dt,
            "joints": list(env.joint_names),
            "actuators": list(env.actuator_names),
            "joint_actuators": dict(env.joint_actuators),
            "actuator_ranges": {
                k: [float(x) if np.isfinite(x) else None for x in v] for k, v in env.actuator_ranges.items()
            },
            "action_ranges": {k: list(v) for k, v in self.action_ranges.items()},
            "actuator_force_limits": {
                k: (list(v) if v else None) for k, v in env.actuator_force_limits.items()
            },
            "effective_range_probe": self.probe,
            "joint_ranges": {k: (list(v) if v else None) for k, v in env.joint_ranges.items()},
            "columns": column_names(env.joint_names, list(env.joint_actuators), velocities=True),
            "state_spec": STATE_SPEC,
            "state_size": env.state_size,
            "policy": self.policy.config(),
            "seed": self.seed,
            "seed_derivation": "policy: default_rng(SeedSequence([seed, 0])); reset of episode e: "
            "SeedSequence([seed, 1, e]).generate_state(1)[0]",
            "reset_every": self.reset_every,
            "reset_noise": env.reset_noise,
            "chunk_size": config.chunk_size,
            "steps": config.steps,
            "config": json.loads(json.dumps({k: v for k, v in asdict(config).items() if k != "steps"})),
        }


def probe_seed(seed: int) -> int:
    """The seed of the effective-range probe run of a run seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, 2]).generate_state(1)[0])


def check_config(config: BabbleConfig) -> tuple[BabblingEnv, dict[str, tuple[float, float]]]:
    """Build the environment of ``config`` and its babbling command ranges, checking everything.

    This compiles the body and steps nothing, so a command line can be refused before any
    directory is touched. The effective-range probe is not run.

    Returns:
        ``(env, ranges)``: the environment and actuator -> ``(low, high)`` babbled (the
        ctrlrange or the override).

    Raises:
        MJCFError: missing or malformed MJCF file.
        ValueError: a bad body name, unknown or idle joints and actuators, an action range
            outside the ctrlrange, or an actuator without a finite ctrlrange.
    """
    env = BabblingEnv(
        load_model(config.body, name=config.name),
        joints=config.joints,
        actuators=config.actuators,
        frame_skip=config.frame_skip,
        reset_noise=config.reset_noise,
    )
    ranges = babbling_ranges(env.actuator_names, env.actuator_ranges, config.action_ranges)
    unbounded = [a for a, (lo, hi) in ranges.items() if not (np.isfinite(lo) and np.isfinite(hi))]
    if unbounded:
        raise ValueError(
            f"actuator(s) {unbounded} have no finite ctrlrange; babbling needs one (ctrllimited, or "
            "--action-range NAME=LOW,HIGH)"
        )
    return env, ranges


def make_source(config: BabbleConfig, *, backend: str = "loop") -> BabblingSource:
    """Build the environment, policy and source of ``config`` (runs the probe of ``effective_range``).

    ``backend`` is the source's stepping backend (:data:`BACKENDS`); it does not change the data.

    Raises:
        MJCFError, ValueError: see :func:`check_config`.
    """
    env, ranges = check_config(config)
    probe = None
    if config.effective_range:
        probe_config = replace(
            config,
            steps=config.probe_steps,
            seed=probe_seed(config.seed),
            effective_range=False,
            chunk_size=config.probe_steps,
        )
        found = collect(probe_config, backend=backend).metadata["effective_ranges"]
        ranges = {a: tuple(found[a]["effective"]) for a in ranges}
        probe = {"steps": config.probe_steps, "seed": probe_config.seed, "effective_ranges": found}
        logger.info("babbling over the effective ranges %s", ranges)
    low = np.array([r[0] for r in ranges.values()])
    high = np.array([r[1] for r in ranges.values()])
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0]))
    policy = make_policy(config.policy, low, high, rng, dt=env.dt, params=config.policy_params)
    return BabblingSource(
        env, policy, seed=config.seed, reset_every=config.reset_every, probe=probe, backend=backend
    )


def _bar(total: int, initial: int, enabled: bool) -> Any:
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, disable=not enabled, unit="step", desc="babbling")


def collect(config: BabbleConfig, *, progress_bar: bool = False, backend: str = "loop") -> TransitionDataset:
    """Run ``config`` in memory and return the transitions (nothing is written; ``backend``: :data:`BACKENDS`)."""
    source = make_source(config, backend=backend)
    meta = {"format": FORMAT, **source.metadata(config)}
    parts = []
    with _bar(config.steps, 0, progress_bar) as bar:
        for block in source.blocks(config.steps, config.chunk_size):
            parts.append((source.columns(block), block))
            bar.update(len(block.step))
    if not parts:
        raise ValueError("steps must be >= 1 to collect a dataset")
    cols = {k: np.concatenate([p[0][k] for p in parts]) for k in parts[0][0]}

    def cat(key: str) -> np.ndarray:
        return np.concatenate([getattr(p[1], key) for p in parts])

    dataset = TransitionDataset(
        cols,
        cat("ctrl"),
        cat("states"),
        cat("step"),
        cat("episode"),
        {**meta, "n_rows": config.steps, "complete": True},
    )
    dataset.metadata["effective_ranges"] = effective_ranges(dataset)
    return dataset


def babble(
    config: BabbleConfig,
    out_dir: str | os.PathLike[str],
    *,
    resume: bool = False,
    progress_bar: bool = False,
    backend: str = "loop",
) -> TransitionDataset:
    """Run ``config`` and write it to ``out_dir`` chunk by chunk (atomic ``.npz`` files).

    Args:
        config: the run.
        out_dir: dataset directory (created if needed).
        resume: continue an interrupted run in ``out_dir``: the last complete chunk's
            simulator state and policy generator state are restored, so the result equals
            an uninterrupted run. A larger ``config.steps`` extends a finished dataset.
        progress_bar: show a tqdm bar.
        backend: the stepping backend (:data:`BACKENDS`); the data do not depend on it.

    Returns:
        The dataset, loaded back from ``out_dir``.

    Raises:
        ValueError: ``out_dir`` holds a dataset and ``resume`` is False, or the stored
            configuration differs from ``config``.
        DirectoryLockedError: another writer is writing ``out_dir`` (the lock is released
            when this call returns or raises).
        DatasetFileError: a stored chunk is corrupted, missing or of another run.
    """
    if config.steps < 1:
        raise ValueError("steps must be >= 1 to write a dataset")
    source = make_source(config, backend=backend)
    with DatasetWriter(out_dir, source.metadata(config), resume=resume) as writer:
        if writer.resume_info is not None:
            source.restore(writer.resume_info)
            logger.info("resuming %s at step %d", out_dir, source.step_index)
        if writer.rows != source.step_index:
            raise DatasetFileError(
                f"{out_dir}: {writer.rows} rows on disk but the last chunk resumes at step {source.step_index}"
            )
        remaining = max(0, config.steps - source.step_index)
        with _bar(config.steps, source.step_index, progress_bar) as bar:
            for block in source.blocks(remaining, config.chunk_size):
                path = writer.write_chunk(
                    source.columns(block),
                    {"ctrl": block.ctrl, "state": block.states, "step": block.step, "episode": block.episode},
                    source.resume_state(),
                )
                logger.debug("wrote %s (%d rows)", path, len(block.step))
                bar.update(len(block.step))
        found = effective_ranges(TransitionDataset.load(Path(out_dir), allow_incomplete=True))
        writer.finish(config.steps, extra={"effective_ranges": found})
    return TransitionDataset.load(Path(out_dir))


def replay(env: BabblingEnv, state: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
    """Restore ``state``, apply ``ctrl`` for one environment step, return the new joint positions.

    Args:
        env: an environment on the same model and selection as the recording.
        state: (state_size,) float64 state before the step (``TransitionDataset.state(i)``).
        ctrl: (n_actuators,) command (``TransitionDataset.ctrl[i]`` or an inferred action).

    Returns:
        (n_joints,) float64 positions after the step, rad.
    """
    env.set_state(state)
    env.step(ctrl)
    return env.data.qpos[env.qpos_indices].copy()
