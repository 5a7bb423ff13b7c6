"""Babbling data of the world-model experiments (B1-B3, explore): dataset, cache, replay.

- :class:`BodyChoice` (in :mod:`pal.experiments.world_model.body`, re-exported here): the body, the
  analysed joint and how its actuators babble.
- :class:`DataConfig`: the dataset: babbled (and cached) or an existing directory
  (``--dataset``), which must have been recorded for the same body, actuators and frame skip.
- :func:`babble_or_load`: i.i.d. uniform motor babbling (thesis §5.2.1), cached on disk by
  body, babbling settings, steps and seed, so B1, B2 and B3 share one dataset.
- :class:`JointData`: the analysed joint's columns ``act.J, q_prev.J, dq_prev.J, dq.J, q.J``.
- :class:`Realizer`: realized evaluation. It restores the recorded simulator state before a
  transition, executes a given command for the analysed actuator (the other actuators keep
  their recorded commands) for one environment step, and returns the joint angle reached;
  many rows at once in one ``mujoco.rollout`` batch, equal bit for bit to the one-by-one replay.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pal.checks import MAX_STEPS, check_int
from pal.experiments.world_model.body import DEFAULT_JOINT as DEFAULT_JOINT
from pal.experiments.world_model.body import BodyChoice, _resolve_joint
from pal.experiments.world_model.body import _action_range as _action_range
from pal.experiments.world_model.body import _one_name as _one_name
from pal.io.dataset import FORMAT, METADATA, DatasetFileError, TransitionDataset
from pal.io.dataset_files import read_metadata
from pal.sim.babbling import babble, collect, replay
from pal.sim.batched import BatchReplayer
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


@dataclass(frozen=True)
class DataConfig:
    """A uniform-babbling dataset (thesis §5.2.1); its seed is the experiment's.

    Attributes:
        body: the body, analysed joint and babbling actuators.
        steps: transitions (thesis: 100 000), at most ``pal.checks.MAX_STEPS``; ignored
            with ``dataset``.
        cache: keep the dataset on disk and reuse it.
        cache_dir: cache root; default ``$PAL_CACHE_DIR`` or ``~/.cache/pal``.
        dataset: an existing dataset directory (``pal babble --out DIR``) used instead of
            babbling; it must be complete and recorded for ``body``'s MJCF file (hash),
            actuators, frame skip and command ranges.

    Raises:
        ValueError: ``steps`` < 10 or > ``MAX_STEPS``, or a ``dataset`` that is missing,
            unreadable, incomplete or recorded for another body, actuator set, frame skip or
            command range.
    """

    body: BodyChoice = BodyChoice()
    steps: int = 100_000
    cache: bool = True
    cache_dir: str | None = None
    dataset: str | None = None

    def __post_init__(self) -> None:
        check_int("steps", self.steps, minimum=10, maximum=MAX_STEPS)
        if self.dataset is not None:
            self._check_dataset()

    def _check_dataset(self) -> dict[str, Any]:
        root = Path(str(self.dataset))
        if not root.is_dir():
            raise ValueError(
                f"dataset {str(root)!r} is not a directory; give a directory written by pal babble --out"
            )
        meta = read_metadata(root)
        if not meta.get("complete"):
            raise ValueError(
                f"dataset {root} is incomplete ({meta.get('n_rows', 'unknown')} of {meta.get('steps')} rows); "
                "finish it with pal babble --resume"
            )
        reason = self.body.dataset_mismatch(meta, root)
        if reason:
            raise ValueError(reason)
        return meta

    def check(self) -> None:
        """Refuse, before any babbling, a choice that cannot be analysed (see :meth:`BodyChoice.analysed`).

        Raises:
            ValueError: no analysable joint, or a ``dataset`` that does not record it.
        """
        joint, _ = self.body.analysed()
        if self.dataset is not None:
            meta = self._check_dataset()
            if joint not in meta.get("joints", ()):
                raise ValueError(
                    f"dataset {self.dataset} does not record joint {joint!r}; its joints are {meta.get('joints')}"
                )


def default_cache_dir() -> Path:
    """``$PAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/pal``, else ``~/.cache/pal``."""
    if os.environ.get("PAL_CACHE_DIR"):
        return Path(os.environ["PAL_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "pal"


def _slug(name: str) -> str:
    """A directory-safe form of a body name (the cache key's hash keeps entries apart)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "body"


def cache_path(config: DataConfig, seed: int) -> Path:
    """The cache directory of ``config`` and ``seed``: ``<root>/babble/<body>-n<steps>-s<seed>-<hash>``.

    The hash covers the MJCF file's bytes, the body name, the babbling actuators, the frame
    skip, the command ranges (override or effective), the babbling settings and the dataset
    format, so an edited body file or another choice never reuses stale data.
    """
    bcfg = config.body.babble_config(config.steps, seed, chunk_size=min(10_000, config.steps))
    info = config.body.info()
    name = config.body.name or info.name
    spec = {
        "format": FORMAT,
        "mjcf_sha256": info.sha256,
        "name": name,
        "actuators": list(bcfg.actuators) if bcfg.actuators else None,
        "steps": bcfg.steps,
        "seed": bcfg.seed,
        "policy": bcfg.policy,
        "frame_skip": bcfg.frame_skip,
        "action_ranges": [list(r) for r in bcfg.action_ranges],
        "effective_range": bcfg.effective_range,
        "probe_steps": bcfg.probe_steps if bcfg.effective_range else None,
        "reset_every": bcfg.reset_every,
        "chunk_size": bcfg.chunk_size,
        "columns": "v_prev, v",  # datasets record the joint velocities
    }
    digest = hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:12]
    root = Path(config.cache_dir) if config.cache_dir else default_cache_dir()
    return root / "babble" / f"{_slug(name)}-n{config.steps}-s{seed}-{digest}"


def babble_or_load(config: DataConfig, seed: int, progress_bar: bool = False) -> TransitionDataset:
    """The dataset of ``config``: the given directory, else from the cache, else babbled (and cached).

    Everything is checked before any stepping (:meth:`DataConfig.check`). The cache
    directory is :func:`cache_path`; an interrupted run resumes, and a stale entry (another
    format, damaged) is babbled again.

    Returns:
        All recorded joints; ``(N, 1)`` float32 columns and the state before every step.

    Raises:
        ValueError: see :meth:`DataConfig.check`; the dataset changed since the config was built.
    """
    config.check()
    if config.dataset is not None:
        dataset = TransitionDataset.load(config.dataset)
        reason = config.body.dataset_mismatch(dataset.metadata, config.dataset)
        if reason:  # pragma: no cover - the directory changed since the check
            raise ValueError(reason)
        log.info("using the dataset %s (%d rows)", config.dataset, len(dataset))
        return dataset
    bcfg = config.body.babble_config(config.steps, seed, chunk_size=min(10_000, config.steps))
    if not config.cache:
        return collect(bcfg, progress_bar=progress_bar)
    path = cache_path(config, seed)
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
        joint: joint name J; variables are ``act.J``, ``q_prev.J``, ``dq_prev.J``, ``dq.J``, ``q.J``.
        actuator: name of the actuator driving J (its command is ``act.J``).
        actuator_index: column of that actuator in ``dataset.ctrl``.
        joint_index: position of J in ``dataset.joints``.
        action_range: ``(low, high)`` command range X_a the actuator babbled over (its
            ctrlrange unless overridden), dimensionless.
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
        ranges = meta.get("action_ranges") or meta["actuator_ranges"]
        return cls._pick(dataset.joints, dataset.actuators, meta.get("joint_actuators", {}), ranges, joint)

    @classmethod
    def from_env(
        cls,
        env: BabblingEnv,
        joint: str | None = None,
        action_ranges: Mapping[str, tuple[float, float]] | None = None,
    ) -> JointData:
        """The same as :meth:`select` for an environment's joints and actuators.

        Args:
            env: the environment.
            joint: the analysed joint (default as in :meth:`select`).
            action_ranges: the babbled command ranges (default the ctrl ranges), e.g.
                :attr:`pal.sim.babbling.BabblingSource.action_ranges`.
        """
        ranges = dict(env.actuator_ranges) if action_ranges is None else dict(action_ranges)
        return cls._pick(list(env.joint_names), list(env.actuator_names), env.joint_actuators, ranges, joint)

    @classmethod
    def _pick(
        cls,
        joints: list[str],
        actuators: list[str],
        driving: dict[str, str],
        ranges: Mapping[str, Any],
        joint: str | None,
    ) -> JointData:
        joint = _resolve_joint(joints, joint)
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

        They are ``act.J`` (the command), ``q_prev.J``, ``dq_prev.J`` (the previous step's
        displacement), ``dq.J`` and ``q.J`` (rad), and when recorded ``v_prev.J`` and ``v.J``
        (MuJoCo's joint velocity before and after the step, rad/s).
        """
        act, q_prev, dq, q = self.names
        dq_prev = f"dq_prev.{self.joint}"
        cols = dataset.columns
        out = {
            act: dataset.ctrl[:, self.actuator_index : self.actuator_index + 1].astype(np.float32),
            q_prev: cols[q_prev].copy(),
            dq_prev: cols[dq_prev].copy(),
            dq: cols[dq].copy(),
            q: cols[q].copy(),
        }
        for name in (f"v_prev.{self.joint}", f"v.{self.joint}"):
            if name in cols:
                out[name] = cols[name].copy()
        return out

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
        self._replayer: BatchReplayer | None = None

    def outcomes(self, rows: Sequence[int] | np.ndarray, actions: Any, *, batched: bool = True) -> np.ndarray:
        """Angles q.J reached when row i's command for the analysed actuator is replaced.

        Args:
            rows: ``(n,)`` row indices of the dataset.
            actions: ``(n,)`` or ``(n, 1)`` commands for the analysed actuator.
            batched: all rows in one ``mujoco.rollout`` call (:class:`~pal.sim.batched.BatchReplayer`);
                False replays them one by one with :func:`~pal.sim.babbling.replay`. Both give the
                same angles bit for bit.

        Returns:
            ``(n,)`` float64 joint angles after one environment step, rad.
        """
        rows = np.asarray(rows, dtype=np.intp).reshape(-1)
        a = np.asarray(actions, dtype=np.float64).reshape(-1)
        if a.shape != rows.shape:
            raise ValueError(f"actions has {a.size} entries, expected one per row ({rows.size})")
        ctrls = self.dataset.ctrl[rows].astype(np.float64)
        ctrls[:, self.joint.actuator_index] = a
        if batched:
            if self._replayer is None:
                self._replayer = BatchReplayer(self.env)
            return self._replayer.step(self.dataset.states[rows], ctrls)[:, self.joint.joint_index]
        out = np.empty(len(rows))
        for k, (i, ctrl) in enumerate(zip(rows, ctrls, strict=True)):
            out[k] = replay(self.env, self.dataset.states[i], ctrl)[self.joint.joint_index]
        return out
