"""The perception step of ``pal demo``: record two tabletop runs, perceive them, score them.

:func:`perception_demo_lines` records ``box-rotation`` and ``ball-roll`` (seed 0) in the
simulated tabletop, runs the perception pipeline Π on each recording, and returns report lines:
the box's estimated fraction and pose error against ground truth, the ball's flag (no usable
6-DoF trajectory, no invented orientation), and the scene descriptor's size. It writes
``perception_trajectories.png`` and ``perception.json`` to ``out_dir``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from pal.experiments.output import save_figure, write_json
from pal.experiments.perception_plots import trajectory_figure
from pal.experiments.perception_runs import RunSet, collect

__all__ = ["perception_demo_lines"]


def perception_demo_lines(out_dir: str | Path, quick: bool) -> list[str]:
    """Run the perception demo (module docstring); ``quick`` uses 320x240 at 6 frames/s (a few seconds)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    size = {"fps": 6.0, "width": 320, "height": 240} if quick else {}
    with tempfile.TemporaryDirectory(prefix="pal-demo-perception-") as tmp:
        runs = collect(RunSet(motions=("box-rotation", "ball-roll"), runs=1, data_dir=tmp, **size))  # type: ignore[arg-type]
    box, ball = (r.summary() for r in runs)
    save_figure(trajectory_figure(runs), out / "perception_trajectories.png")
    write_json(
        out / "perception.json", {"runs": [r.summary() for r in runs], "config": {"quick": quick, **size}}
    )
    w, h = size.get("width", 640), size.get("height", 480)
    return [
        f"Perception on the simulated tabletop ({w}x{h}, geometric segmentation, ORB + Kabsch-RANSAC poses)",
        f"   box turning {box['frames']} frames: estimated pose in {box['estimated_fraction']:.0%} of frames, "
        f"median error {box['trans_err_cm_median']:.2f} cm / {box['rot_err_deg_median']:.2f} deg against ground truth, "
        f"segmentation IoU {box['seg_iou_mean']:.2f}",
        f"   one-colour ball rolling: estimated in {ball['estimated_fraction']:.0%} of frames, usable 6-DoF trajectory: "
        f"{'yes' if ball['usable_trajectory'] else 'no'} (no orientation invented; position from the depth centroid, "
        f"median error {ball['centroid_err_cm_median']:.2f} cm)",
        f"   figure: {out / 'perception_trajectories.png'}",
    ]
