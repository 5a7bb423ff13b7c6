"""``pal experiment a3``: multidomain conceptual entities (thesis §5.1.4, Table 5.5).

Each run becomes a conceptual entity (Eq. 4.23-4.25) in a space with two domains, equal
salience:

- ``visual``: the record's 54-d appearance descriptor, robustly normalised over all records
  (as in A2), present for every record with snapshots;
- ``motion``: the 90-d motion descriptor, its translation and rotation families balanced by
  their RMS (as in A1), present **only** for usable trajectories (≥ 80 % estimated poses, no
  long gap). The ball, whose pose cannot be estimated, stays undefined in this domain.

Comparisons run over the shared domains (``shared``), or *strictly* over both domains, which
is only defined when both entities have both (a missing required domain raises an error, so
such pairs have no strict distance). Table 5.5 lists each entity's projections and its nearest
entity under the strict comparison. Shared-domain comparisons mix distances over different
domain sets, so they are reported within their context only (thesis §1.2.3).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pal.experiments.perception.a1_kinematic import motion_scaler
from pal.experiments.perception.a2_visual import visual_scaler
from pal.experiments.perception.evaluation import RunResult
from pal.experiments.perception.runs import QUICK_RUNS, TINY_RUNS, Config, RunSet, collect
from pal.lab.registry import register
from pal.lab.report import Report, Table, Target
from pal.perception import KINEMATIC_DIM, VISUAL_DIM, ConceptualSpace, Domain, Entity

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["THESIS_TABLE_5_5", "Config", "build_entities", "conceptual_space", "report", "run"]

#: Table 5.5: (object, run, motion projection, visual projection, strict distance text).
THESIS_TABLE_5_5 = (
    ("box", "translation", True, True, "9.31 to box depth translation"),
    ("box", "depth translation", True, True, "9.31 to box translation"),
    ("boat", "translation", False, True, None),
    ("boat", "rotation", False, True, None),
    ("ball", "roll", False, True, None),
)
#: Table 5.5's counts: entities, with both projections, visual only, motion only, strict pairs.
THESIS_COVERAGE = {"entities": 5, "both": 2, "visual_only": 3, "motion_only": 0, "strict_pairs": 1}
BOTH = ("motion", "visual")


def conceptual_space() -> ConceptualSpace:
    """The two-domain space of A3, equal salience."""
    return ConceptualSpace(
        [
            Domain("motion", tuple(f"motion_{k}" for k in range(KINEMATIC_DIM))),
            Domain("visual", tuple(f"visual_{k}" for k in range(VISUAL_DIM))),
        ]
    )


def build_entities(records: Sequence[RunResult], space: ConceptualSpace) -> list[Entity]:
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


def _strict(entities: Sequence[Entity]) -> list[Entity]:
    return [e for e in entities if set(BOTH) <= e.domains]


def strict_nearest(e: Entity, entities: Sequence[Entity], space: ConceptualSpace) -> tuple[str, float] | None:
    """Nearest other entity over both domains, or None when ``e`` or every other lacks one."""
    if not set(BOTH) <= e.domains:
        return None
    cands = [(space.distance(e, o, BOTH), o.name) for o in _strict(entities) if o is not e]
    return None if not cands else (min(cands)[1], min(cands)[0])


def shared_nearest(
    e: Entity, entities: Sequence[Entity], space: ConceptualSpace
) -> tuple[str, float, tuple[str, ...]] | None:
    """Nearest other entity over the domains they share, with those domains (None: no other shares one)."""
    cands = [
        (space.distance(e, o), o.name, space.compared_domains(e, o))
        for o in entities
        if o is not e and e.domains & o.domains
    ]
    if not cands:
        return None
    d, name, domains = min(cands)
    return name, d, domains


def metrics(
    records: Sequence[RunResult], entities: Sequence[Entity], space: ConceptualSpace
) -> dict[str, Any]:
    """Every entity's domains and nearest neighbours, the domain coverage and the strict pairs."""
    recs = {r.name: r for r in records}
    ents = []
    for e in entities:
        r = recs[e.name]
        strict = strict_nearest(e, entities, space)
        shared = shared_nearest(e, entities, space)
        ents.append(
            {
                "name": e.name,
                "object": r.object,
                "motion": r.kind,
                "run": r.run,
                "domains": sorted(e.domains),
                "strict_nearest": None if strict is None else {"entity": strict[0], "distance": strict[1]},
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
    same = [e["shared_nearest"]["same_object"] for e in ents if e["shared_nearest"] is not None]
    both = _strict(entities)
    return {
        "entities": ents,
        "coverage": {
            "entities": len(entities),
            "both": len(both),
            "visual_only": sum(e.domains == {"visual"} for e in entities),
            "motion_only": sum(e.domains == {"motion"} for e in entities),
            "strict_pairs": sum(1 for _ in itertools.combinations(both, 2)),
        },
        "shared_nearest_same_object": [sum(same), len(same)],
        "salience": dict(space.salience),
    }


def tables(m: dict[str, Any]) -> list[Table]:
    """Our entities in the format of Table 5.5, the thesis's table, and the coverage beside the thesis's."""
    rows = []
    for e in m["entities"]:
        s, sh = e["strict_nearest"], e["shared_nearest"]
        strict = None if s is None else f"{s['distance']:.3f} to {s['entity']}"
        shared = None if sh is None else f"{sh['entity']} ({'+'.join(sh['domains'])})"
        rows.append(
            [
                e["object"],
                f"{e['motion']} {e['run']}",
                "motion" in e["domains"],
                "visual" in e["domains"],
                strict,
                shared,
            ]
        )
    columns = ["Object", "Run", "Motion proj.", "Visual proj.", "Strict motion-visual dist."]
    cov = m["coverage"]
    labels = {
        "entities": "entities",
        "both": "with motion and visual projections",
        "visual_only": "visual only",
        "motion_only": "motion only",
        "strict_pairs": "pairs comparable strictly over both domains",
    }
    return [
        Table(
            "Multidomain entities (thesis Table 5.5 format)",
            [*columns, "nearest over shared domains"],
            rows,
            "Strict and shared distances are computed over different domain sets and do not compare with each other.",
        ),
        Table("Thesis Table 5.5", columns, THESIS_TABLE_5_5),
        Table(
            "A3 against the thesis",
            ["quantity", "thesis", "pal"],
            [[text, THESIS_COVERAGE[k], cov[k]] for k, text in labels.items()]
            + [
                [
                    "entities whose nearest over shared domains is the same object",
                    None,
                    "{} of {}".format(*m["shared_nearest_same_object"]),
                ]
            ],
        ),
    ]


def strict_figure(entities: Sequence[Entity], space: ConceptualSpace) -> Figure:
    """Heat map of the strict motion+visual distances between entities (blank: undefined)."""
    import matplotlib.pyplot as plt

    n = len(entities)
    D = np.full((n, n), np.nan)
    for i, j in itertools.product(range(n), range(n)):
        if i != j and set(BOTH) <= entities[i].domains and set(BOTH) <= entities[j].domains:
            D[i, j] = space.distance(entities[i], entities[j], BOTH)
    fig, ax = plt.subplots(figsize=(0.28 * n + 3, 0.28 * n + 2.4))
    im = ax.imshow(D, cmap="viridis")
    names = [e.name for e in entities]
    ax.set_xticks(range(n), names, rotation=90, fontsize=6)
    ax.set_yticks(range(n), names, fontsize=6)
    ax.set_title("strict motion+visual distances (blank: undefined)", fontsize=9)
    fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    return fig


def report(records: Sequence[RunResult], run_set: RunSet, seed: int) -> Report:
    """The A3 report of already scored runs."""
    space = conceptual_space()
    entities = build_entities(records, space)
    m = metrics(records, entities, space)
    same, total = m["shared_nearest_same_object"]
    return Report(
        title="A3: multidomain entities (thesis Table 5.5)",
        metrics=m,
        tables=tables(m),
        targets=[
            Target(
                "shared_nearest_same_object",
                same / total if total else None,
                0.9,
                ">=",
                "share of entities whose nearest entity over shared domains shows the same object",
            )
        ],
        notes=[
            run_set.note(seed),
            "The motion domain is defined only for usable trajectories and the visual domain for records with "
            "snapshots, both domains with equal salience; a strict comparison needs both domains in both entities.",
        ],
        figures={"strict_distances": strict_figure(entities, space)} if len(entities) >= 2 else {},
    )


@register("a3", config=Config, quick=Config(runs=QUICK_RUNS), tiny=Config(runs=TINY_RUNS))
def run(config: Config, progress_bar: bool = False) -> Report:
    """A3: entities with motion and visual projections, compared strictly and over shared domains (Table 5.5)."""
    return report(collect(config.runs, config.seed, progress_bar), config.runs, config.seed)
