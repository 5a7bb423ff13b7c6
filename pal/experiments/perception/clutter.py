"""``pal experiment clutter``: touching objects kept apart on the simulated cluttered tabletop.

``scenes`` seeded scenes of :mod:`pal.sim.clutter` (seeds ``seed .. seed + scenes - 1``: 6-9
boxes, cans, short cans, short boxes and flat objects, in clusters whose members touch, half
of them printed, 640x480 with a real sensor's depth noise, quantisation and holes) are
segmented by the geometric segmenter Σ, and every visible object (at least ``min_visible`` of
the image) is scored against its known mask (:mod:`pal.experiments.perception.mask_scores`):
clean (a mask with IoU >= 0.7), merged, split, missed or partial.

The same frames are segmented by a **baseline**: Σ without the cuts at concave creases,
without widening the cuts, without the smaller size for pieces standing on the support and
without the support's smallest footprint (``SegmentationConfig(crease_tau=0, cut_width=0,
grounded_size=min_size, support=SupportConfig(min_area=0))``), which cuts only at depth jumps
and at colour edges with depth evidence.

Target: >= 80 % of the objects as one clean mask, over at least 20 objects.
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from pal.checks import check_float, check_int
from pal.experiments.perception.mask_scores import OUTCOMES, ObjectScore, score_masks
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.perception.segmentation import GeometricSegmenter, SegmentationConfig
from pal.sim.clutter import ClutterConfig, render_clutter
from pal.sim.clutter_layout import KINDS

__all__ = ["QUICK", "TINY", "Config", "baseline_segmentation", "run"]

#: Share of the objects with a clean mask that the segmenter should reach.
TARGET_CLEAN = 0.8
#: Objects the target needs before it is evaluated.
MIN_OBJECTS = 20


@dataclass(frozen=True)
class Config:
    """Settings of the clutter evaluation.

    Attributes:
        seed: the first scene's seed.
        scenes: number of scenes.
        scene: how scenes are drawn and rendered.
        segmentation: the segmenter evaluated.
        clean_iou: IoU at which a mask is the object's clean mask.
        min_visible: objects covering less than this fraction of the image are not scored.
        baseline: also score the baseline segmenter (module docstring).
    """

    seed: int = 100
    scenes: int = 20
    scene: ClutterConfig = field(default_factory=ClutterConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    clean_iou: float = 0.7
    min_visible: float = 0.001
    baseline: bool = True

    def __post_init__(self) -> None:
        check_int("scenes", self.scenes)
        check_float("clean_iou", self.clean_iou, 0.0, 1.0, open_low=True)
        check_float("min_visible", self.min_visible, 0.0, 1.0)


def baseline_segmentation(config: SegmentationConfig) -> SegmentationConfig:
    """``config`` without the crease cuts, cut widening, grounded size and support footprint rule."""
    return dataclasses.replace(
        config,
        crease_tau=0.0,
        cut_width=0.0,
        grounded_size=config.min_size,
        support=dataclasses.replace(config.support, min_area=0.0),
    )


def _tally(scores: list[ObjectScore]) -> dict[str, Any]:
    counts = Counter(s.outcome for s in scores)
    n = len(scores)
    return {
        "objects": n,
        **{k: int(counts.get(k, 0)) for k in OUTCOMES},
        "share_clean": counts.get("clean", 0) / n if n else None,
    }


def _evaluate(config: Config) -> dict[str, Any]:
    """Render every scene and score the segmenter (and the baseline) on it."""
    contenders = {"pal": config.segmentation}
    if config.baseline:
        contenders["baseline"] = baseline_segmentation(config.segmentation)
    scores: dict[str, list[tuple[int, str, bool, ObjectScore]]] = {k: [] for k in contenders}
    cpu = {k: 0.0 for k in contenders}
    backend = ""
    for s in range(config.seed, config.seed + config.scenes):
        scene = render_clutter(s, config.scene)
        backend = scene.backend
        frame = scene.frame
        assert frame.labels is not None  # render_clutter always writes labels
        min_pixels = max(1, round(config.min_visible * frame.labels.size))
        for name, seg_config in contenders.items():
            start = time.process_time()
            candidates = GeometricSegmenter(seg_config, rng=s)(frame)
            cpu[name] += time.process_time() - start
            for sc in score_masks(
                frame.labels, [c.mask for c in candidates], clean_iou=config.clean_iou, min_pixels=min_pixels
            ):
                obj = scene.objects[sc.label - 1]
                scores[name].append((s, obj.kind, obj.texture is not None, sc))
    return {"scores": scores, "cpu": cpu, "backend": backend}


def _tables(config: Config, scores: dict[str, list[tuple[int, str, bool, ObjectScore]]]) -> list[Table]:
    names = list(scores)
    by_kind = []
    for kind in (*KINDS, "printed", "plain"):
        row: list[Any] = [kind]
        for name in names:
            sel = [
                sc
                for _, k, printed, sc in scores[name]
                if k == kind or (kind == "printed" and printed) or (kind == "plain" and not printed)
            ]
            t = _tally(sel)
            row += [t["objects"], t["share_clean"]]
        by_kind.append(row)
    per_scene = []
    for s in range(config.seed, config.seed + config.scenes):
        row = [s]
        for name in names:
            t = _tally([sc for seed, _, _, sc in scores[name] if seed == s])
            row += [t["objects"], t["clean"], t["merged"], t["split"], t["missed"]]
        per_scene.append(row)
    return [
        Table(
            "Clean masks by kind of object",
            ["kind", *[f"{n} {c}" for n in names for c in ("objects", "clean share")]],
            by_kind,
            "Printed: a random print on every face; plain: one colour.",
        ),
        Table(
            "Outcomes per scene",
            ["seed", *[f"{n} {c}" for n in names for c in ("objects", "clean", "merged", "split", "missed")]],
            per_scene,
        ),
    ]


def report(config: Config, result: dict[str, Any]) -> Report:
    """The report of an evaluation (module docstring)."""
    scores = result["scores"]
    tallies = {name: _tally([sc for *_, sc in rows]) for name, rows in scores.items()}
    pal = tallies["pal"]
    metrics: dict[str, Any] = {
        "scenes": config.scenes,
        **pal,
        "segmentation_cpu_s_per_frame": result["cpu"]["pal"] / config.scenes,
        "backend": result["backend"],
    }
    if "baseline" in tallies:
        metrics["baseline"] = tallies["baseline"]
        metrics["baseline_cpu_s_per_frame"] = result["cpu"]["baseline"] / config.scenes
    enough = Precondition(pal["objects"] >= MIN_OBJECTS, f"at least {MIN_OBJECTS} visible objects scored")
    notes = [
        f"{config.scenes} scenes (seeds {config.seed}-{config.seed + config.scenes - 1}) at "
        f"{config.scene.image[0]}x{config.scene.image[1]}, camera backend {result['backend']}; "
        f"{pal['objects']} visible objects (at least {config.min_visible:.2%} of the image).",
    ]
    if "baseline" in tallies:
        b = tallies["baseline"]
        notes.append(
            f"Baseline (depth jumps and colour edges with depth evidence only): {b['clean']}/{b['objects']} clean, "
            f"{b['merged']} merged, {b['split']} split, {b['missed']} missed."
        )
    return Report(
        title="Touching objects kept apart: clean masks on the simulated cluttered tabletop",
        metrics=metrics,
        tables=_tables(config, scores),
        targets=[
            Target(
                "share_clean",
                pal["share_clean"],
                TARGET_CLEAN,
                ">=",
                f"visible objects with one clean mask (IoU >= {config.clean_iou})",
                enough,
            )
        ],
        notes=notes,
    )


#: ``--quick``: 6 scenes.
QUICK = Config(scenes=6)
#: The contract test's run: one small scene.
TINY = Config(scenes=1, scene=ClutterConfig(image=(160, 120)))


@register("clutter", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Touching objects kept apart: clean masks of the geometric segmenter on simulated clutter."""
    return report(config, _evaluate(config))
