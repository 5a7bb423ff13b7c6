"""The set of recorded tabletop runs that experiments A1-A3 share, and its evaluation.

:class:`RunSet` (the ``runs`` sub-config of the experiments' :class:`Config`) names the motions of
Table 5.1, the number of runs per motion and the recording and pipeline settings.
:func:`collect` records every run with :func:`pal.sim.recording.record` (run ``r`` of a
motion uses seed ``seed + r``) and scores it with
:func:`pal.experiments.perception.evaluation.evaluate_sequence`.

Recordings go to ``data_dir/<motion>/seed-<s>``. A recording already there is reused when its
recording settings match (so ``pal experiment a1 --set runs.data_dir=DIR`` followed by ``a2``
and ``a3`` with the same ``DIR`` renders each run once). Without ``data_dir`` they go to a
temporary directory, each one deleted as soon as it has been scored.
"""

from __future__ import annotations

import json
import logging
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

from pal.checks import check_choice, check_float, check_int
from pal.experiments.perception.evaluation import RunResult, evaluate_sequence
from pal.perception import PipelineConfig, RecordedSequence, SequenceError
from pal.perception.features import FeatureConfig
from pal.perception.pose import PoseConfig
from pal.sim.camera import BACKENDS
from pal.sim.motions import MOTIONS
from pal.sim.recording import Realism, RecordConfig, record
from pal.sim.tabletop import scene_digest

__all__ = ["QUICK_RUNS", "TINY_RUNS", "Config", "RunSet", "collect", "ensure_recording", "names"]

log = logging.getLogger(__name__)


#: The fields of a run set that are fields of its recordings.
_RECORDING = ("fps", "width", "height", "depth_noise", "rgb_noise", "backend", "realism")


def names(name: str, value: str | tuple[str, ...], known: list[str]) -> tuple[str, ...]:
    """``value`` (one name or several) as a non-empty tuple of names from ``known``.

    Raises:
        ValueError: empty, or a name not in ``known`` (the field ``name`` and the choices named).
    """
    chosen = (value,) if isinstance(value, str) else tuple(value)
    if not chosen or [v for v in chosen if v not in known]:
        raise ValueError(f"{name} {list(chosen)} must be a non-empty list of {known}")
    return chosen


@dataclass(frozen=True)
class RunSet:
    """Which runs to record and how to perceive them.

    Attributes:
        motions: motions of Table 5.1 (keys of :data:`pal.sim.motions.MOTIONS`).
        per_motion: runs per motion (seeds ``seed``, ``seed + 1``, ...).
        fps: recording frame rate, frames/s.
        width, height: image size, pixels.
        segmenter: ``"geometric"`` (default) or ``"oracle"`` (ground-truth masks, an ablation).
        features: ``"orb"`` (default) or ``"sift"``.
        depth_noise: depth noise std at 1 m, metres (see :mod:`pal.sim.recording`).
        rgb_noise: colour noise std, grey levels.
        data_dir: where recordings are kept and reused; None: a temporary directory.
        backend: camera backend (:data:`pal.sim.camera.BACKENDS`).
        realism: the harder tabletop (occluding hand, a real sensor's depth quantisation and
            holes, motion blur, lighting changes; :class:`pal.sim.recording.Realism`), or None
            for the clean scene the earlier numbers were measured on (``--set runs.realism=null``).
    """

    motions: tuple[str, ...] = tuple(MOTIONS)
    per_motion: int = 4
    fps: float = 15.0
    width: int = 640
    height: int = 480
    segmenter: Literal["geometric", "oracle"] = "geometric"
    features: Literal["orb", "sift"] = "orb"
    depth_noise: float = 0.002
    rgb_noise: float = 2.0
    data_dir: str | None = None
    backend: str = "auto"
    realism: Realism | None = Realism()

    def __post_init__(self) -> None:
        object.__setattr__(self, "motions", names("motions", self.motions, sorted(MOTIONS)))
        check_int("per_motion", self.per_motion)
        check_float("fps", self.fps, 0.0, open_low=True)
        check_int("width", self.width, minimum=16)
        check_int("height", self.height, minimum=16)
        check_float("depth_noise", self.depth_noise, 0.0)
        check_float("rgb_noise", self.rgb_noise, 0.0)
        check_choice("segmenter", self.segmenter, ("geometric", "oracle"))
        check_choice("features", self.features, ("orb", "sift"))
        check_choice("backend", self.backend, BACKENDS)

    def record_config(self, motion: str, run: int, seed: int) -> RecordConfig:
        """The recording of run ``run`` (0-based) of ``motion``: seed ``seed + run``."""
        return RecordConfig(motion, seed=seed + run, **{k: getattr(self, k) for k in _RECORDING})

    def pipeline_config(self) -> PipelineConfig:
        """Π as the experiments run it: defaults, plus the chosen segmenter and features."""
        return PipelineConfig(
            segmenter=self.segmenter, pose=PoseConfig(features=FeatureConfig(kind=self.features))
        )

    @property
    def min_area(self) -> int:
        """Pixels of true mask for an object to count as in view (150 at 640x480, scaled)."""
        return max(20, round(150 * self.width * self.height / (640 * 480)))

    def note(self, seed: int) -> str:
        """One sentence describing the run set, for a report's notes."""
        scene = (
            "the clean tabletop"
            if self.realism is None
            else "the harder tabletop (an occluding hand, quantised depth with holes, motion blur, lighting changes)"
        )
        return (
            f"{len(self.motions) * self.per_motion} simulated runs on {scene} ({self.per_motion} per motion, seeds from {seed}) "
            f"at {self.width}x{self.height} and {self.fps:g} frames/s, depth noise {self.depth_noise * 1000:g} mm at 1 m, "
            f"segmenter {self.segmenter}, features {self.features}."
        )


#: The run set of A2 and A3 under ``--quick``: every motion twice, 320x240 at 10 frames/s.
QUICK_RUNS = RunSet(per_motion=2, fps=10.0, width=320, height=240)
#: The smallest run set that reaches every code path: a translation, a rotation and the ball.
TINY_RUNS = RunSet(
    motions=("box-translation", "box-rotation", "ball-roll"), per_motion=1, fps=3.0, width=160, height=120
)


@dataclass(frozen=True)
class Config:
    """Experiments A1-A3: which runs to record and perceive (defaults: every motion 4 times at 640x480).

    Attributes:
        seed: seed of each motion's first run (run ``r`` uses ``seed + r``).
        runs: the run set.
    """

    seed: int = 0
    runs: RunSet = RunSet()


def ensure_recording(config: RecordConfig, path: Path) -> RecordedSequence:
    """The recording of ``config`` at ``path``, reused or (re)recorded.

    An existing recording is reused if it has the same settings and the same scene (MJCF and
    assets).
    """
    want = json.loads(json.dumps(asdict(config)))
    if (path / "sequence.json").is_file():
        try:
            seq = RecordedSequence(path)
            meta = seq.metadata
            occluder = config.realism is not None and config.realism.occluder
            if meta.get("config") == want and meta.get("scene_sha256") == scene_digest(
                config.texture_seed, occluder
            ):
                return seq
            log.info("%s was recorded with other settings; recording it again", path)
        except SequenceError as err:
            log.warning("%s is unreadable (%s); recording it again", path, err)
    record(config, path, overwrite=True)
    return RecordedSequence(path)


@contextmanager
def _workdir(data_dir: str | None) -> Iterator[tuple[Path, bool]]:
    if data_dir is not None:
        yield Path(data_dir), True
        return
    with tempfile.TemporaryDirectory(prefix="pal-perception-") as tmp:
        yield Path(tmp), False


def collect(runs: RunSet, seed: int, progress_bar: bool = False) -> list[RunResult]:
    """Record (or reuse) and evaluate every run of ``runs``, in motion order then run order.

    Args:
        runs: the run set.
        seed: seed of each motion's first run (run ``r`` uses ``seed + r``).
        progress_bar: show a progress bar over the runs.
    """
    jobs = [(m, r) for m in runs.motions for r in range(runs.per_motion)]
    pipe = runs.pipeline_config()
    results = []
    with _workdir(runs.data_dir) as (root, keep):
        it = jobs
        if progress_bar:
            from tqdm import tqdm

            it = tqdm(jobs, desc="runs", unit="run")
        for motion, run in it:
            rc = runs.record_config(motion, run, seed)
            path = root / motion / f"seed-{rc.seed}"
            seq = ensure_recording(rc, path)
            res = evaluate_sequence(seq, pipe, run=run, min_area=runs.min_area)
            log.info(
                "%s: %d/%d estimated, %s frames/s",
                res.name,
                res.valid,
                res.in_view,
                res.fps and round(res.fps, 1),
            )
            results.append(res)
            if not keep:
                shutil.rmtree(path)
    return results
