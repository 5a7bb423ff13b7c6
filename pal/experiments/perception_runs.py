"""The set of recorded tabletop runs that experiments A1-A3 share, and its evaluation.

:class:`RunSet` (the base of the experiments' ``Config``) names the motions of Table 5.1, the
number of runs per motion and the recording and pipeline settings. :func:`collect` records
every run with :func:`pal.sim.recording.record` (run ``r`` of a motion uses seed
``seed + r``) and scores it with :func:`pal.experiments.perception_eval.evaluate_sequence`.

Recordings go to ``data_dir/<motion>/seed-<s>``. A recording already there is reused when its
recording settings match (so ``pal experiment a1 --set data_dir=DIR`` followed by ``a2`` and
``a3`` with the same ``DIR`` renders each run once). Without ``data_dir`` they go to a
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

from pal.experiments.perception_eval import RunResult, evaluate_sequence
from pal.perception import PipelineConfig, RecordedSequence, SequenceError
from pal.perception.features import FeatureConfig
from pal.perception.pose import PoseConfig
from pal.sim.motions import MOTIONS
from pal.sim.recording import RecordConfig, record
from pal.sim.tabletop import scene_digest

__all__ = ["RunSet", "collect", "ensure_recording"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunSet:
    """Which runs to record and how to perceive them.

    Attributes:
        motions: motions of Table 5.1 (keys of :data:`pal.sim.motions.MOTIONS`).
        runs: runs per motion (seeds ``seed``, ``seed + 1``, ...).
        seed: first run seed.
        fps: recording frame rate, frames/s.
        width, height: image size, pixels.
        depth_noise: depth noise std at 1 m, metres (see :mod:`pal.sim.recording`).
        rgb_noise: colour noise std, grey levels.
        data_dir: where recordings are kept and reused; None: a temporary directory.
        segmenter: ``"geometric"`` (default) or ``"oracle"`` (ground-truth masks, an ablation).
        features: ``"orb"`` (default) or ``"sift"``.
        backend: camera backend.
    """

    motions: tuple[str, ...] = tuple(MOTIONS)
    runs: int = 4
    seed: int = 0
    fps: float = 15.0
    width: int = 640
    height: int = 480
    depth_noise: float = 0.002
    rgb_noise: float = 2.0
    data_dir: str | None = None
    segmenter: str = "geometric"
    features: str = "orb"
    backend: str = "auto"

    def __post_init__(self) -> None:
        motions = (self.motions,) if isinstance(self.motions, str) else tuple(self.motions)
        unknown = [m for m in motions if m not in MOTIONS]
        if not motions or unknown:
            raise ValueError(f"motions {list(motions)} must be a non-empty list of {sorted(MOTIONS)}")
        object.__setattr__(self, "motions", motions)
        if isinstance(self.runs, bool) or int(self.runs) < 1:
            raise ValueError(f"runs is {self.runs!r}, expected an int >= 1 (runs per motion)")
        if self.segmenter not in ("geometric", "oracle"):
            raise ValueError(f"segmenter {self.segmenter!r} unknown; expected 'geometric' or 'oracle'")

    def record_config(self, motion: str, run: int) -> RecordConfig:
        return RecordConfig(
            motion,
            seed=self.seed + run,
            fps=self.fps,
            width=self.width,
            height=self.height,
            depth_noise=self.depth_noise,
            rgb_noise=self.rgb_noise,
            backend=self.backend,
        )

    def pipeline_config(self) -> PipelineConfig:
        """Π as the experiments run it: defaults, plus the chosen segmenter and features."""
        return PipelineConfig(
            segmenter=self.segmenter, pose=PoseConfig(features=FeatureConfig(kind=self.features))
        )  # type: ignore[arg-type]

    @property
    def min_area(self) -> int:
        """Pixels of true mask for an object to count as in view (150 at 640x480, scaled)."""
        return max(20, round(150 * self.width * self.height / (640 * 480)))


def ensure_recording(config: RecordConfig, path: Path) -> RecordedSequence:
    """The recording of ``config`` at ``path``: reused if it exists with the same settings and the
    same scene (MJCF and assets), else (re)recorded."""
    want = json.loads(json.dumps(asdict(config)))
    if (path / "sequence.json").is_file():
        try:
            seq = RecordedSequence(path)
            meta = seq.metadata
            if meta.get("config") == want and meta.get("scene_sha256") == scene_digest(config.texture_seed):
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


def collect(config: RunSet, progress_bar: bool = False) -> list[RunResult]:
    """Record (or reuse) and evaluate every run of ``config``, in motion order then run order."""
    jobs = [(m, r) for m in config.motions for r in range(config.runs)]
    pipe = config.pipeline_config()
    results = []
    with _workdir(config.data_dir) as (root, keep):
        it = jobs
        if progress_bar:
            from tqdm import tqdm

            it = tqdm(jobs, desc="runs", unit="run")
        for motion, run in it:
            rc = config.record_config(motion, run)
            path = root / motion / f"seed-{rc.seed}"
            seq = ensure_recording(rc, path)
            res = evaluate_sequence(seq, pipe, run=run, min_area=config.min_area)
            log.info("%s: %d/%d estimated, %.1f frames/s", res.name, res.valid, res.in_view, res.fps)
            results.append(res)
            if not keep:
                shutil.rmtree(path)
    return results
