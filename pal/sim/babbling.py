"""The motor-babbling data source: steps a :class:`BabblingEnv` under a babbling policy.

Protocol (thesis §5.2.1): at every environment step the policy draws a command for each
selected actuator, the body moves for ``frame_skip`` MuJoCo steps, and the transition
``(act, q(t-1), dq, q(t))`` is recorded per joint together with the full simulator state
before the step. The environment resets every ``reset_every`` steps (thesis: 10 000).

Seeds: the policy draws from ``default_rng(SeedSequence([seed, 0]))``; the reset of episode
e uses ``episode_seed(seed, e)``. Everything else is deterministic, so a run is a function
of its :class:`BabbleConfig`, and a resumed run (:func:`babble` with ``resume=True``)
produces the same rows as an uninterrupted one.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from pal.data import FORMAT, DatasetFileError, DatasetWriter, TransitionDataset, column_names
from pal.sim.env import STATE_SPEC, BabblingEnv
from pal.sim.policies import POLICIES, make_policy

__all__ = [
    "BabbleConfig",
    "BabblingSource",
    "TransitionBlock",
    "babble",
    "collect",
    "episode_seed",
    "make_source",
    "replay",
]

logger = logging.getLogger(__name__)


def episode_seed(seed: int, episode: int) -> int:
    """The ``env.reset`` seed of episode ``episode`` of a run seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, 1, episode]).generate_state(1)[0])


@dataclass(frozen=True)
class BabbleConfig:
    """A babbling run.

    Attributes:
        body: shipped body name (``"finger"``, ``"arm"``) or a path to an MJCF file.
        joints: recorded joints (default all hinge/slide joints).
        actuators: babbling actuators (default all).
        steps: number of transitions.
        seed: master seed.
        policy: ``"uniform"`` or ``"ou"``.
        policy_params: extra policy parameters (``{"theta": 1.0, "sigma": 0.5}`` for ``"ou"``).
        frame_skip: MuJoCo steps per transition (50: 0.25 s).
        reset_every: environment reset period, steps.
        reset_noise: reset noise half-width on joint positions, rad.
        chunk_size: rows per chunk file when writing to disk.
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

    def __post_init__(self) -> None:
        for key in ("steps", "reset_every", "chunk_size", "frame_skip"):
            value = getattr(self, key)
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, np.integer))
                or value < (0 if key == "steps" else 1)
            ):
                raise ValueError(
                    f"{key} must be a {'non-negative' if key == 'steps' else 'positive'} int, got {value!r}"
                )
        if self.policy not in POLICIES:
            raise ValueError(f"unknown policy {self.policy!r}; expected one of {POLICIES}")
        for key in ("joints", "actuators"):
            value = getattr(self, key)
            if isinstance(value, str):
                raise ValueError(f"{key} must be a tuple of names, got the string {value!r}")


@dataclass(frozen=True)
class TransitionBlock:
    """Consecutive transitions (n rows, J joints, U actuators, S state entries).

    Attributes:
        ctrl: (n, U) float32 applied commands.
        q_prev, q: (n, J) float64 joint positions before and after each step, rad.
        states: (n, S) float64 simulator states before each step.
        step, episode: (n,) int64 global step and episode indices.
    """

    ctrl: np.ndarray
    q_prev: np.ndarray
    q: np.ndarray
    states: np.ndarray
    step: np.ndarray
    episode: np.ndarray


class BabblingSource:
    """Generates babbling transitions from an environment and a policy.

    Args:
        env: the environment (its actuators are the policy's).
        policy: a :class:`~pal.sim.policies.Policy` over ``env.actuator_names``.
        seed: master seed (episode reset seeds derive from it).
        reset_every: reset period, steps.
    """

    def __init__(self, env: BabblingEnv, policy: Any, *, seed: int, reset_every: int) -> None:
        self.env, self.policy, self.seed, self.reset_every = env, policy, int(seed), int(reset_every)
        self.step_index = 0

    def blocks(self, steps: int, block_size: int) -> Iterator[TransitionBlock]:
        """Run ``steps`` more steps, yielding blocks of at most ``block_size`` rows."""
        end = self.step_index + steps
        while self.step_index < end:
            yield self.run(min(block_size, end - self.step_index))

    def __iter__(self) -> Iterator[dict[str, Any]]:
        """Endless single transitions: dicts with ``ctrl``, ``q_prev``, ``q``, ``state``, ``step``, ``episode``."""
        while True:
            b = self.run(1)
            yield {
                "ctrl": b.ctrl[0],
                "q_prev": b.q_prev[0],
                "q": b.q[0],
                "state": b.states[0],
                "step": int(b.step[0]),
                "episode": int(b.episode[0]),
            }

    def run(self, n: int) -> TransitionBlock:
        """The next ``n`` transitions (preallocated arrays, one ``mj_step(nstep=frame_skip)`` each)."""
        env = self.env
        m, d, fs = env.model, env.data, env.frame_skip
        qidx, aidx = env.qpos_indices, env.actuator_ids
        acts = self.policy.sample(n)
        applied = np.clip(acts.astype(np.float64), env.ctrl_low, env.ctrl_high)
        q_prev = np.empty((n, len(qidx)))
        q = np.empty((n, len(qidx)))
        states = np.empty((n, env.state_size))
        steps = np.arange(self.step_index, self.step_index + n, dtype=np.int64)
        episode = steps // self.reset_every
        qpos, ctrl = d.qpos, d.ctrl
        k, every = self.step_index, self.reset_every
        for i in range(n):
            if (k + i) % every == 0:
                env.reset(seed=episode_seed(self.seed, (k + i) // every))
            mujoco.mj_getState(m, d, states[i], STATE_SPEC)
            q_prev[i] = qpos[qidx]
            ctrl[aidx] = applied[i]
            mujoco.mj_step(m, d, fs)
            q[i] = qpos[qidx]
        self.step_index += n
        return TransitionBlock(applied.astype(np.float32), q_prev, q, states, steps, episode)

    # ------------------------------------------------------------------ resuming
    def resume_state(self) -> dict[str, Any]:
        """JSON-compatible state to continue exactly from here (see :meth:`restore`)."""
        return {
            "step": self.step_index,
            "policy": self.policy.get_state(),
            "sim_state": self.env.get_state().tolist(),
        }

    def restore(self, state: dict[str, Any]) -> None:
        """Continue from a :meth:`resume_state` (simulator, policy generator, step counter)."""
        self.step_index = int(state["step"])
        self.policy.set_state(state["policy"])
        if self.step_index % self.reset_every != 0:  # otherwise the next step resets anyway
            self.env.set_state(np.asarray(state["sim_state"], np.float64))

    # ------------------------------------------------------------------ dataset glue
    def columns(self, block: TransitionBlock) -> dict[str, np.ndarray]:
        """The per-joint ``(n, 1)`` float32 columns of a block (``dq`` from float64 positions)."""
        env, out = self.env, {}
        for c, j in enumerate(env.joint_names):
            if j in env.joint_actuators:
                a = env.actuator_names.index(env.joint_actuators[j])
                out[f"act.{j}"] = block.ctrl[:, a : a + 1].copy()
            out[f"q_prev.{j}"] = block.q_prev[:, c : c + 1].astype(np.float32)
            out[f"dq.{j}"] = (block.q[:, c : c + 1] - block.q_prev[:, c : c + 1]).astype(np.float32)
            out[f"q.{j}"] = block.q[:, c : c + 1].astype(np.float32)
        return out

    def metadata(self, config: BabbleConfig) -> dict[str, Any]:
        """Dataset metadata: body, model hash, physics settings, names, ranges, policy, seeds."""
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
            "actuator_ranges": {k: list(v) for k, v in env.actuator_ranges.items()},
            "joint_ranges": {k: (list(v) if v else None) for k, v in env.joint_ranges.items()},
            "columns": column_names(env.joint_names, list(env.joint_actuators)),
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
            "config": {
                k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(config).items() if k != "steps"
            },
        }


def make_source(config: BabbleConfig) -> BabblingSource:
    """Build the environment, policy and source of ``config``."""
    env = BabblingEnv(
        config.body,
        joints=config.joints,
        actuators=config.actuators,
        frame_skip=config.frame_skip,
        reset_noise=config.reset_noise,
    )
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0]))
    policy = make_policy(
        config.policy, env.ctrl_low, env.ctrl_high, rng, dt=env.dt, params=config.policy_params
    )
    return BabblingSource(env, policy, seed=config.seed, reset_every=config.reset_every)


def _bar(total: int, initial: int, enabled: bool) -> Any:
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, disable=not enabled, unit="step", desc="babbling")


def collect(config: BabbleConfig, *, progress_bar: bool = False) -> TransitionDataset:
    """Run ``config`` in memory and return the transitions (nothing is written)."""
    source = make_source(config)
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

    return TransitionDataset(
        cols,
        cat("ctrl"),
        cat("states"),
        cat("step"),
        cat("episode"),
        {**meta, "n_rows": config.steps, "complete": True},
    )


def babble(
    config: BabbleConfig, out_dir: str | os.PathLike[str], *, resume: bool = False, progress_bar: bool = False
) -> TransitionDataset:
    """Run ``config`` and write it to ``out_dir`` chunk by chunk (atomic ``.npz`` files).

    Args:
        config: the run.
        out_dir: dataset directory (created if needed).
        resume: continue an interrupted run in ``out_dir``: the last complete chunk's
            simulator state and policy generator state are restored, so the result equals
            an uninterrupted run. A larger ``config.steps`` extends a finished dataset.
        progress_bar: show a tqdm bar.

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
    source = make_source(config)
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
        writer.finish(config.steps)
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
