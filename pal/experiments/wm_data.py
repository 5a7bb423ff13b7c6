"""Babbling data of the world-model experiments (B1-B3, explore): body choice, cache, replay.

- :class:`BodyChoice`: which body (shipped name or MJCF path), which joint is analysed and
  which actuators babble. The ``pal experiment`` flags ``--body/--mjcf/--joint/--actuator``
  set its fields.
- :func:`babble_or_load`: i.i.d. uniform motor babbling (thesis §5.2.1), cached on disk by
  (body file hash, actuators, steps, seed), so B1, B2 and B3 share one dataset.
- :class:`JointData`: the analysed joint's columns ``act.J, q_prev.J, dq.J, q.J``.
- :class:`Realizer`: realized evaluation. It restores the recorded simulator state before a
  transition, executes a given command for the analysed actuator (the other actuators keep
  their recorded commands) for one environment step, and returns the joint angle reached.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pal.checks import check_int
from pal.data import FORMAT, METADATA, DatasetFileError, TransitionDataset
from pal.sim.babbling import BabbleConfig, babble, collect, replay
from pal.sim.bodies import BODIES, load_model
from pal.sim.env import BabblingEnv

__all__ = [
    "BodyChoice",
    "DataConfig",
    "JointData",
    "Realizer",
    "babble_or_load",
    "default_cache_dir",
    "pick_rows",
]

log = logging.getLogger(__name__)

#: The analysed joint when none is named and the body has one called so (both shipped bodies).
DEFAULT_JOINT = "finger"


def _one_name(value: Any, what: str) -> str | None:
    """``None``, a name, or a 1-tuple of a name (``--joint`` is repeatable) -> name or None."""
    if value is None or isinstance(value, str):
        return value
    names = list(value)
    if len(names) != 1 or not isinstance(names[0], str):
        raise ValueError(f"{what} must be one name, got {value!r}; the experiments analyse one joint")
    return names[0]


@dataclass(frozen=True)
class BodyChoice:
    """The body, the analysed joint and the babbling actuators.

    Attributes:
        body: shipped body, one of ``pal.sim.BODIES`` (``"finger"``, ``"arm"``).
        mjcf: path to any MJCF file; when given it replaces ``body``.
        joint: the analysed joint (default ``"finger"``, or the only joint of the model).
        actuator: the actuators that babble (default all). The analysed action is the
            selected actuator whose transmission is ``joint``.
    """

    body: str = "finger"
    mjcf: str | None = None
    joint: str | None = None
    actuator: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if self.mjcf is None and self.body not in BODIES:
            raise ValueError(
                f"unknown body {self.body!r}; expected one of {list(BODIES)}, or give mjcf=PATH (--mjcf)"
            )
        object.__setattr__(self, "joint", _one_name(self.joint, "joint"))
        if self.actuator is not None:
            if isinstance(self.actuator, str):
                object.__setattr__(self, "actuator", (self.actuator,))
            object.__setattr__(self, "actuator", tuple(self.actuator))

    @property
    def source(self) -> str:
        """What :class:`~pal.sim.env.BabblingEnv` loads: the MJCF path or the body name."""
        return self.mjcf if self.mjcf is not None else self.body


@dataclass(frozen=True)
class DataConfig:
    """A uniform-babbling dataset (thesis §5.2.1); its seed is the experiment's.

    Attributes:
        body: the body, analysed joint and babbling actuators.
        steps: transitions (thesis: 100 000).
        cache: keep the dataset on disk and reuse it.
        cache_dir: cache root; default ``$PAL_CACHE_DIR`` or ``~/.cache/pal``.
    """

    body: BodyChoice = BodyChoice()
    steps: int = 100_000
    cache: bool = True
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        check_int("steps", self.steps, minimum=10)


def default_cache_dir() -> Path:
    """``$PAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/pal``, else ``~/.cache/pal``."""
    if os.environ.get("PAL_CACHE_DIR"):
        return Path(os.environ["PAL_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "pal"


def _babble_config(config: DataConfig, seed: int) -> BabbleConfig:
    return BabbleConfig(
        body=config.body.source,
        actuators=config.body.actuator,
        steps=config.steps,
        seed=seed,
        chunk_size=min(10_000, config.steps),
    )


def babble_or_load(config: DataConfig, seed: int, progress_bar: bool = False) -> TransitionDataset:
    """The uniform-babbling dataset of ``config``: from the cache, else babbled (and cached).

    The cache directory is ``<cache_dir>/babble/<body>-n<steps>-s<seed>-<hash>``; the hash
    covers the MJCF file's bytes, the babbling actuators and the babbling settings, so an
    edited body file never reuses stale data. An interrupted run resumes.

    Returns:
        All recorded joints; ``(steps, 1)`` float32 columns and the state before every step.
    """
    bcfg = _babble_config(config, seed)
    if not config.cache:
        return collect(bcfg, progress_bar=progress_bar)
    loaded = load_model(config.body.source)
    spec = {
        "mjcf_sha256": loaded.sha256,
        "actuators": list(config.body.actuator) if config.body.actuator else None,
        "steps": bcfg.steps,
        "seed": bcfg.seed,
        "policy": bcfg.policy,
        "frame_skip": bcfg.frame_skip,
        "reset_every": bcfg.reset_every,
        "chunk_size": bcfg.chunk_size,
    }
    digest = hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:12]
    root = Path(config.cache_dir) if config.cache_dir else default_cache_dir()
    path = root / "babble" / f"{loaded.name}-n{config.steps}-s{seed}-{digest}"
    meta_path = path / METADATA
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
            if meta.get("complete") and meta.get("n_rows") == config.steps:
                log.info("loading cached babbling data %s", path)
                return TransitionDataset.load(path)
            if meta.get("format") != FORMAT:
                raise DatasetFileError(f"{meta_path}: format {meta.get('format')!r}, expected {FORMAT!r}")
        except (json.JSONDecodeError, UnicodeDecodeError, DatasetFileError) as err:
            # the cache is ours: a stale or damaged entry is babbled again, not repaired
            log.warning("discarding the cached dataset %s (%s)", path, err)
            shutil.rmtree(path)
    return babble(bcfg, path, resume=meta_path.is_file(), progress_bar=progress_bar)


@dataclass(frozen=True)
class JointData:
    """The analysed joint of a dataset.

    Attributes:
        joint: joint name J; variables are ``act.J``, ``q_prev.J``, ``dq.J``, ``q.J``.
        actuator: name of the actuator driving J (its command is ``act.J``).
        actuator_index: column of that actuator in ``dataset.ctrl``.
        joint_index: position of J in ``dataset.joints``.
        action_range: ``(low, high)`` ctrl range X_a of the actuator (dimensionless).
    """

    joint: str
    actuator: str
    actuator_index: int
    joint_index: int
    action_range: tuple[float, float]

    @classmethod
    def select(cls, dataset: TransitionDataset, joint: str | None = None) -> JointData:
        """Pick the analysed joint of a dataset (default ``"finger"`` or the only joint) and its actuator.

        Raises:
            ValueError: unknown joint, several joints and none named, no babbling actuator
                drives the joint, or the actuator's ctrl range is unbounded.
        """
        meta = dataset.metadata
        return cls._pick(
            dataset.joints, dataset.actuators, meta.get("joint_actuators", {}), meta["actuator_ranges"], joint
        )

    @classmethod
    def from_env(cls, env: BabblingEnv, joint: str | None = None) -> JointData:
        """The same as :meth:`select` for an environment's joints and actuators."""
        return cls._pick(
            list(env.joint_names), list(env.actuator_names), env.joint_actuators, env.actuator_ranges, joint
        )

    @classmethod
    def _pick(
        cls,
        joints: list[str],
        actuators: list[str],
        driving: dict[str, str],
        ranges: dict[str, Any],
        joint: str | None,
    ) -> JointData:
        if joint is None:
            if DEFAULT_JOINT in joints:
                joint = DEFAULT_JOINT
            elif len(joints) == 1:
                joint = joints[0]
            else:
                raise ValueError(f"the body has joints {joints}; name the one to analyse (--joint NAME)")
        if joint not in joints:
            raise ValueError(f"unknown joint {joint!r}; the body's joints are {joints}")
        if joint not in driving:
            raise ValueError(
                f"no babbling actuator drives joint {joint!r} (actuators {actuators}); "
                "select one whose transmission is this joint (--actuator NAME)"
            )
        actuator = driving[joint]
        low, high = (float(v) for v in ranges[actuator])
        if not (np.isfinite(low) and np.isfinite(high)):
            raise ValueError(
                f"actuator {actuator!r} has ctrl range [{low}, {high}]; the action needs a finite range"
            )
        return cls(joint, actuator, actuators.index(actuator), joints.index(joint), (low, high))

    @property
    def names(self) -> tuple[str, str, str, str]:
        """``(act.J, q_prev.J, dq.J, q.J)``."""
        j = self.joint
        return f"act.{j}", f"q_prev.{j}", f"dq.{j}", f"q.{j}"

    def columns(self, dataset: TransitionDataset) -> dict[str, np.ndarray]:
        """The joint's columns, name -> ``(N, 1)`` float32.

        They are ``act.J`` (the command), ``q_prev.J``, ``dq.J`` and ``q.J`` (rad).
        """
        act, q_prev, dq, q = self.names
        cols = dataset.columns
        return {
            act: dataset.ctrl[:, self.actuator_index : self.actuator_index + 1].astype(np.float32),
            q_prev: cols[q_prev].copy(),
            dq: cols[dq].copy(),
            q: cols[q].copy(),
        }

    def q_range(self, dataset: TransitionDataset) -> tuple[float, float]:
        """Observed range X_q of the post-action angle q.J in ``dataset``, rad."""
        q = dataset.columns[f"q.{self.joint}"]
        return float(q.min()), float(q.max())


def pick_rows(n_rows: int, n: int, seed: int) -> np.ndarray:
    """``min(n, n_rows)`` distinct row indices drawn with ``default_rng(seed)``, sorted."""
    if n < 1:
        raise ValueError(f"the number of test rows must be >= 1, got {n}")
    rows = np.random.default_rng(seed).choice(n_rows, size=min(n, n_rows), replace=False)
    return np.sort(rows)


class Realizer:
    """Executes actions from recorded simulator states (realized evaluation).

    Args:
        dataset: the recording; its body file, joints, actuators and frame skip are reused.
        joint: the analysed joint.
        source: the body name or MJCF path the dataset was recorded from.

    Raises:
        ValueError: the body file changed since the recording (hash mismatch).
    """

    def __init__(self, dataset: TransitionDataset, joint: JointData, source: str) -> None:
        meta = dataset.metadata
        self.env = BabblingEnv(
            source, joints=dataset.joints, actuators=dataset.actuators, frame_skip=int(meta["frame_skip"])
        )
        if meta.get("mjcf_sha256") not in (None, self.env.loaded.sha256):
            raise ValueError(
                f"{self.env.loaded.path} differs from the file the dataset was recorded with "
                f"(sha256 {meta['mjcf_sha256'][:12]}...); babble again"
            )
        self.dataset, self.joint = dataset, joint

    def outcomes(self, rows: Sequence[int] | np.ndarray, actions: Any) -> np.ndarray:
        """Angles q.J reached when row i's command for the analysed actuator is replaced.

        Args:
            rows: ``(n,)`` row indices of the dataset.
            actions: ``(n,)`` or ``(n, 1)`` commands for the analysed actuator.

        Returns:
            ``(n,)`` float64 joint angles after one environment step, rad.
        """
        rows = np.asarray(rows, dtype=np.intp).reshape(-1)
        a = np.asarray(actions, dtype=np.float64).reshape(-1)
        if a.shape != rows.shape:
            raise ValueError(f"actions has {a.size} entries, expected one per row ({rows.size})")
        out = np.empty(len(rows))
        for k, (i, ai) in enumerate(zip(rows, a, strict=True)):
            ctrl = self.dataset.ctrl[i].astype(np.float64)
            ctrl[self.joint.actuator_index] = ai
            out[k] = replay(self.env, self.dataset.states[i], ctrl)[self.joint.joint_index]
        return out
