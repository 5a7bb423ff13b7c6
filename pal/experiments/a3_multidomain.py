"""``pal experiment a3``: multidomain conceptual entities (thesis §5.1.4, Table 5.5).

Each run becomes a conceptual entity (Eq. 4.23-4.25) in a space with two domains, equal
salience:

- ``visual``: the record's 54-d appearance descriptor, robustly normalised over all records
  (as in A2) — present for every record with snapshots;
- ``motion``: the 90-d motion descriptor, its translation and rotation families balanced by
  their RMS (as in A1) — present **only** for usable trajectories (≥ 80 % estimated poses, no
  long gap). The ball, whose pose cannot be estimated, stays undefined in this domain.

Comparisons run over the shared domains (``shared``), or *strictly* over both domains, which
is only defined when both entities have both (a missing required domain raises an error, so
such pairs are reported as "—"). Table 5.5 lists each entity's projections and its nearest
entity under the strict comparison. Shared-domain comparisons mix distances over different
domain sets, so they are reported within their context only (thesis §1.2.3).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pal.experiments.a1_kinematic import motion_scaler
from pal.experiments.a2_visual import visual_scaler
from pal.experiments.perception_eval import RunResult
from pal.experiments.perception_runs import RunSet, collect
from pal.experiments.timing import markdown_table
from pal.perception import KINEMATIC_DIM, VISUAL_DIM, ConceptualSpace, Domain, Entity

__all__ = ["THESIS_TABLE_5_5", "Config", "Result", "build_entities", "run"]

#: Table 5.5: (object, run, motion projection, visual projection, strict distance text).
THESIS_TABLE_5_5 = (
    ("box", "translation", True, True, "9.31 to box depth translation"),
    ("box", "depth translation", True, True, "9.31 to box translation"),
    ("boat", "translation", False, True, "—"),
    ("boat", "rotation", False, True, "—"),
    ("ball", "roll", False, True, "—"),
)
BOTH = ("motion", "visual")


@dataclass(frozen=True)
class Config(RunSet):
    """The run set (:class:`~pal.experiments.perception_runs.RunSet`); defaults: 4 runs per motion."""

    @classmethod
    def quick(cls) -> Config:
        return cls(runs=2, fps=10.0, width=320, height=240)


def conceptual_space() -> ConceptualSpace:
    """The two-domain space of A3, equal salience."""
    return ConceptualSpace(
        [
            Domain("motion", tuple(f"motion_{k}" for k in range(KINEMATIC_DIM))),
            Domain("visual", tuple(f"visual_{k}" for k in range(VISUAL_DIM))),
        ]
    )


def build_entities(records: list[RunResult], space: ConceptualSpace) -> list[Entity]:
    """One entity per record with its available projections (module docstring)."""
    vis = [r for r in records if r.visual is not None]
    mot = [r for r in records if r.usable]
    vnorm = visual_scaler().fit(np.stack([r.visual for r in vis])) if len(vis) >= 2 else None  # type: ignore[misc]
    mscale = motion_scaler().fit(np.stack([r.kinematic for r in mot])) if mot else None  # type: ignore[misc]
    out = []
    for r in records:
        points: dict[str, np.ndarray] = {}
        if r.usable and mscale is not None:
            points["motion"] = mscale.transform(r.kinematic)  # type: ignore[arg-type]
        if r.visual is not None and vnorm is not None:
            points["visual"] = vnorm.transform(r.visual)
        if points:
            out.append(space.entity(r.name, points))
    return out


@dataclass(frozen=True, eq=False)
class Result:
    """The entities, their strict nearest neighbours and shared-domain nearest neighbours."""

    records: list[RunResult]
    entities: list[Entity]
    space: ConceptualSpace
    config: Config = field(default_factory=Config)

    def _by_name(self) -> dict[str, RunResult]:
        return {r.name: r for r in self.records}

    def strict_nearest(self, e: Entity) -> tuple[str, float] | None:
        """Nearest other entity over both domains, or None when ``e`` or every other lacks one."""
        if not set(BOTH) <= e.domains:
            return None
        cands = [
            (self.space.distance(e, o, BOTH), o.name)
            for o in self.entities
            if o is not e and set(BOTH) <= o.domains
        ]
        return None if not cands else (min(cands)[1], min(cands)[0])

    def shared_nearest(self, e: Entity) -> tuple[str, float, tuple[str, ...]]:
        """Nearest other entity over the domains they share, with those domains."""
        best = min(
            (self.space.distance(e, o), o.name, self.space.compared_domains(e, o))
            for o in self.entities
            if o is not e and e.domains & o.domains
        )
        return best[1], best[0], best[2]

    def to_dict(self) -> dict[str, Any]:
        recs = self._by_name()
        ents = []
        for e in self.entities:
            r = recs[e.name]
            strict = self.strict_nearest(e)
            shared = self.shared_nearest(e) if len(self.entities) > 1 else None
            ents.append(
                {
                    "name": e.name,
                    "object": r.object,
                    "motion": r.kind,
                    "run": r.run,
                    "domains": sorted(e.domains),
                    "strict_nearest": None
                    if strict is None
                    else {"entity": strict[0], "distance": strict[1]},
                    "shared_nearest": None
                    if shared is None
                    else {
                        "entity": shared[0],
                        "distance": shared[1],
                        "domains": list(shared[2]),
                        "same_object": recs[shared[0]].object == r.object,
                    },
                }
            )
        both = [e for e in self.entities if set(BOTH) <= e.domains]
        strict_pairs = sum(1 for _ in itertools.combinations(both, 2))
        return {
            "entities": ents,
            "coverage": {
                "both": len(both),
                "visual_only": sum(e.domains == {"visual"} for e in self.entities),
                "motion_only": sum(e.domains == {"motion"} for e in self.entities),
            },
            "strict_pairs": strict_pairs,
            "salience": dict(self.space.salience),
            "thesis_table_5_5": [
                dict(
                    zip(
                        ("object", "run", "motion_projection", "visual_projection", "strict_distance"),
                        row,
                        strict=True,
                    )
                )
                for row in THESIS_TABLE_5_5
            ],
        }

    def to_markdown(self) -> str:
        d = self.to_dict()
        rows = []
        for e in d["entities"]:
            s = e["strict_nearest"]
            rows.append(
                [
                    e["object"],
                    f"{e['motion']} {e['run']}",
                    "yes" if "motion" in e["domains"] else "no",
                    "yes" if "visual" in e["domains"] else "no",
                    "—" if s is None else f"{s['distance']:.3f} to {s['entity']}",
                    "—"
                    if e["shared_nearest"] is None
                    else "{} ({})".format(
                        e["shared_nearest"]["entity"], "+".join(e["shared_nearest"]["domains"])
                    ),
                ]
            )
        ours = markdown_table(
            [
                "Object",
                "Run",
                "Motion proj.",
                "Visual proj.",
                "Strict motion-visual dist.",
                "nearest over shared domains",
            ],
            rows,
        )
        thesis = markdown_table(
            ["Object", "Run", "Motion proj.", "Visual proj.", "Strict motion-visual dist."],
            [[o, r, "yes" if m else "no", "yes" if v else "no", s] for o, r, m, v, s in THESIS_TABLE_5_5],
        )
        cov = d["coverage"]
        same = [e["shared_nearest"]["same_object"] for e in d["entities"] if e["shared_nearest"] is not None]
        return (
            "\n".join(
                [
                    "## A3: multidomain entities (thesis Table 5.5)",
                    "",
                    f"{len(self.entities)} entities: {cov['both']} with motion and visual projections, {cov['visual_only']} visual only, "
                    f"{cov['motion_only']} motion only; {d['strict_pairs']} pairs comparable strictly over both domains "
                    "(thesis: 5 entities, 2 with both, 1 strict pair at d = 9.31).",
                    "",
                    ours,
                    "",
                    "Thesis:",
                    "",
                    thesis,
                    "",
                    f"Nearest entity over shared domains is the same object for {sum(same)}/{len(same)} entities. "
                    "Strict and shared distances are computed over different domain sets and are not comparable with each other.",
                ]
            )
            + "\n"
        )

    def figures(self) -> dict[str, Any]:
        import matplotlib.pyplot as plt

        n = len(self.entities)
        if n < 2:
            return {}
        D = np.full((n, n), np.nan)
        for i, j in itertools.product(range(n), range(n)):
            if i != j and set(BOTH) <= self.entities[i].domains and set(BOTH) <= self.entities[j].domains:
                D[i, j] = self.space.distance(self.entities[i], self.entities[j], BOTH)
        fig, ax = plt.subplots(figsize=(0.28 * n + 3, 0.28 * n + 2.4))
        im = ax.imshow(D, cmap="viridis")
        names = [e.name for e in self.entities]
        ax.set_xticks(range(n), names, rotation=90, fontsize=6)
        ax.set_yticks(range(n), names, fontsize=6)
        ax.set_title("strict motion+visual distances (blank: undefined)", fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.8)
        fig.tight_layout()
        return {"strict_distances": fig}


def run(config: Config, progress_bar: bool = False) -> Result:
    """Record, perceive and build the entities of every run."""
    records = collect(config, progress_bar)
    space = conceptual_space()
    return Result(records, build_entities(records, space), space, config)
