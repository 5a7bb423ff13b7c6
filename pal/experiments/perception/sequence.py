"""``pal experiment perception-sequence``: Π on a static RGB-D sequence against its camera truth.

Runs :func:`pal.experiments.perception.sequence_eval.evaluate_sequence` at every stride of the
config (default 1 and 3) over a TUM-layout folder (``--set sequence.path=FOLDER``, with ``sequence.camera=freiburg1`` when it has no
``calibration.json``; by default
the shipped 4-frame excerpt of TUM RGB-D freiburg1_xyz) and reports, per stride, the share of
tracked objects posed, the errors against the inverse camera motion beside the no-motion
predictor's, ids kept, wrong-but-estimated poses, and wall and CPU frames per second. Targets
(per stride): ≥ 70 % posed; median error ≤ 1.5 degrees and ≤ 1 cm; no estimated pose more than
10 degrees or 5 cm wrong; ≥ 90 % of the objects seen in both frames keep their id; at stride 1,
the rotation beats no motion on ≥ 80 % of the posed pairs and Π runs at ≥ 15 frames per CPU
second. The ``sequence`` block is the same one :mod:`pal.experiments.bench.perception` runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pal.experiments.perception.sequence_eval import SequenceConfig, evaluate_sequence, open_sequence
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target

__all__ = ["Config", "run", "sequence_results", "sequence_stage_table", "sequence_table", "sequence_targets"]

#: CPU frames per second Π should reach with pose on one core.
TARGET_CPU_FPS = 15.0


@dataclass(frozen=True)
class Config:
    """Attributes: ``seed`` (every random choice of Π); ``sequence`` (what is evaluated)."""

    seed: int = 0
    sequence: SequenceConfig = field(default_factory=SequenceConfig)


def sequence_results(config: SequenceConfig, seed: int) -> dict[int, dict[str, Any]]:
    """``{stride: evaluate_sequence(...)}`` over the folder of ``config``."""
    seq = open_sequence(config.path, config.camera, config.undistort)
    return {s: evaluate_sequence(seq, s, config, seed=seed) for s in config.strides}


def sequence_targets(results: dict[int, dict[str, Any]]) -> list[Target]:
    """The targets of the module docstring, per stride."""
    out = []
    for s, r in results.items():
        posed = Precondition(r["with_pose"] > 0, "at least one posed pair")
        seen = Precondition(r["seen_in_both"] > 0, "at least one object seen in both frames")
        out += [
            Target(
                f"seq_s{s}_pose_fraction",
                r["pose_fraction"],
                0.7,
                ">=",
                f"stride {s}: kept objects posed",
                seen,
            ),
            Target(
                f"seq_s{s}_rot_err_deg",
                r["rot_err_deg_median"],
                1.5,
                "<=",
                f"stride {s}: median rotation error, deg",
                posed,
            ),
            Target(
                f"seq_s{s}_trans_err_m",
                r["trans_err_m_median"],
                0.01,
                "<=",
                f"stride {s}: median translation error, m",
                posed,
            ),
            Target(
                f"seq_s{s}_wrong_estimated",
                r["wrong_estimated"],
                0,
                "<=",
                f"stride {s}: estimated poses > 10 deg or > 5 cm wrong",
                posed,
            ),
            Target(
                f"seq_s{s}_ids_kept",
                r["kept_fraction"],
                0.9,
                ">=",
                f"stride {s}: objects seen in both frames keeping their id",
                seen,
            ),
        ]
        if s == 1:
            out += [
                Target(
                    "seq_s1_rot_beats_still",
                    r["rot_better_than_still"],
                    0.8,
                    ">=",
                    "stride 1: posed pairs whose rotation error is below no motion's",
                    posed,
                ),
                Target(
                    "seq_s1_fps_cpu",
                    r["fps_cpu"],
                    TARGET_CPU_FPS,
                    ">=",
                    "stride 1: frames per CPU second of the process, with pose",
                ),
            ]
    return out


def sequence_table(results: dict[int, dict[str, Any]]) -> Table:
    """One row per stride: coverage, errors beside no motion's, ids, speed."""
    cols = [
        "stride",
        "frames",
        "ids",
        "seen in both",
        "kept id",
        "posed",
        "posed 1st / 2nd half",
        "mask area change",
        "camera rot. err. [deg]",
        "truth clock offset [s] (camera rot. err.)",
        "rot. err. [deg]",
        "trans. err. [m]",
        "still rot. [deg]",
        "still trans. [m]",
        "rot. beats still",
        "wrong",
        "rejected",
        "fps wall",
        "fps CPU",
    ]
    rows = [
        [
            s,
            r["frames"],
            r["ids"],
            r["seen_in_both"],
            r["kept_fraction"],
            r["pose_fraction"],
            " / ".join("n/a" if v is None else f"{v:.3f}" for v in r["pose_fraction_halves"]),
            r["area_change_median"],
            r["camera_rot_err_deg_median"],
            _offset(r),
            r["rot_err_deg_median"],
            r["trans_err_m_median"],
            r["rot_err_still_deg_median"],
            r["trans_err_still_m_median"],
            r["rot_better_than_still"],
            r["wrong_estimated"],
            r["rejected"],
            r["fps_wall"],
            r["fps_cpu"],
        ]
        for s, r in results.items()
    ]
    return Table(
        "Static sequence: poses against the inverse camera motion, and the no-motion predictor",
        cols,
        rows,
        "Errors are medians over posed pairs; still: the no-motion predictor on the same pairs. Wrong: more "
        "than 10 deg or 5 cm off while marked estimated. Mask area change: median |log(area_j / area_i)| of "
        "the objects keeping their id. Camera rot. err.: Pi's own camera motion against the truth. Truth clock "
        "offset: the shift of the truth's time, -40 to +40 ms, at which Pi's camera motion fits it best (a "
        "diagnostic; the scores read the truth at the frame times plus sequence.truth_offset_s).",
    )


def _offset(r: dict[str, Any]) -> str:
    """``"+0.005 (0.15)"``: the best clock offset of the truth and Π's camera rotation error there."""
    if r.get("truth_offset_best_s") is None:
        return "n/a"
    return f"{r['truth_offset_best_s']:+.3f} ({r['camera_rot_err_deg_at_best']:.3f})"


def sequence_stage_table(results: dict[int, dict[str, Any]]) -> Table:
    """Median milliseconds per frame of every stage Π reports, one column per stride."""
    stages = sorted({k for r in results.values() for k in r["stage_ms"]})
    return Table(
        "Static sequence: median milliseconds per frame by stage",
        ["stage", *(f"stride {s}" for s in results)],
        [[k, *(r["stage_ms"].get(k) for r in results.values())] for k in stages]
        + [
            [
                "all (CPU time of the process)",
                *(1000.0 * r["seconds_cpu"] / r["frames"] for r in results.values()),
            ]
        ],
        "Stage times are wall-clock medians over the run's frames (a shared machine inflates them); "
        "the last row is the process's CPU seconds per frame over the whole run.",
    )


def sequence_metrics(results: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """The results without their per-object rows, keyed ``"stride_S"``."""
    return {f"stride_{s}": {k: v for k, v in r.items() if k != "rows"} for s, r in results.items()}


@register(
    "perception-sequence",
    config=Config,
    quick=Config(),
    tiny=Config(sequence=SequenceConfig(strides=(1, 3))),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Π on a static RGB-D sequence at each stride, scored against the inverse camera motion."""
    results = sequence_results(config.sequence, config.seed)
    where = config.sequence.path or "the shipped 4-frame excerpt of TUM RGB-D freiburg1_xyz"
    return Report(
        title="Perception on a static RGB-D sequence against its camera truth",
        metrics=sequence_metrics(results),
        tables=[sequence_table(results), sequence_stage_table(results)],
        targets=sequence_targets(results),
        notes=[
            f"Sequence: {where}; strides {list(config.sequence.strides)}; seed {config.seed}.",
            "TUM RGB-D data: J. Sturm et al., IROS 2012, CC BY 4.0 (sample_data/README.md).",
        ],
    )
