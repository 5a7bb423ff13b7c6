"""One declaration per setting: pal's configs nest the option objects of :mod:`inference`, never copy them.

**Option classes** are the dataclasses that :mod:`inference` exports whose names end in
``Options``, ``Config`` or ``Schedule`` (:class:`inference.FitSchedule`,
:class:`inference.SVIOptions`, :class:`inference.SamplingConfig`, :class:`inference.ActionOptions`,
:class:`inference.DiscoveryOptions` ...), and :class:`inference.hierarchy.LevelQuery`. **Pal
config classes** are the dataclasses defined in ``pal`` that occur in a registered entry's
default, quick or tiny config or in :class:`pal.agent.AgentConfig` (at any depth, inside
nested option objects included).

A pal config class fails when it

1. **copies** an option class: it declares two or more *value* fields named like fields of one
   option class. (A field that holds an option object is nesting, not a copy: ``sampling``
   holding a :class:`inference.SamplingConfig` in a config and in
   :class:`inference.ActionOptions` is the same object one level down.) The old
   ``PlanConfig(population=..., elites=..., iterations=..., alpha=...)`` and
   ``ModelConfig(epochs=..., batch_size=..., lr=...)`` failed here.
2. **re-declares beside** an option object it holds: a field named like a field of that object,
   or of an option object nested in it (``plan.lr`` beside ``plan.action.lr``, or
   ``plan.sampling`` beside ``plan.action.sampling``): two paths to one setting.

3. **shares a group** with another pal config class: three or more value fields (``seed``
   aside) with the same names and the same defaults in two classes, neither nested in the
   other, are one group of settings declared twice; nest one class in both instead (the goal
   geometry of C2 and the hierarchy comparison, the curiosity density of B3 and exploration).

:data:`ALLOWED` lists the (config class, option class) pairs that share names without sharing a
setting, each with its reason; an entry that no longer matches fails too, so the list stays short.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

import pytest

import inference
from inference.hierarchy import LevelQuery
from pal.agent import AgentConfig
from pal.lab import configs, registry

#: (pal config class, inference option class) -> why their shared names are not one setting.
ALLOWED = {
    ("pal.baselines.pets.BaselineConfig", "FitSchedule"): (
        "the PETS-style baseline trains its own torch ensemble (Adam with weight decay), not "
        "inference.fit: epochs, batch_size and lr are that trainer's settings"
    ),
    ("pal.experiments.structure.synthetic.Config", "DiscoveryOptions"): (
        "repeats counts seeds and gated holds the pal_gated run (GatedConfig), whose num_steps fills "
        "DiscoveryOptions.gated; neither is a field of discover()'s options"
    ),
}

#: Pairs of pal config classes -> why their shared names and defaults are not one setting.
ALLOWED_SHARED = {
    ("pal.experiments.bench.perception.Config", "pal.experiments.perception.runs.RunSet"): (
        "the benchmark's frame size and camera backend and those of the A1-A3 recordings are "
        "separate choices that start from the same sensor default (640x480, auto)"
    ),
}

OPTION_CLASSES = (
    *(
        obj
        for name in inference.__all__
        if isinstance(obj := getattr(inference, name), type)
        and dataclasses.is_dataclass(obj)
        and name.endswith(("Options", "Config", "Schedule"))
    ),
    LevelQuery,
)


def _name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _roots() -> Iterator[Any]:
    for entry in registry.entries():
        yield from (entry.default(), entry.quick, entry.tiny)
    yield AgentConfig()


def _instances() -> dict[type, list[Any]]:
    """Every pal config class of the trees, with its instances (one per distinct value)."""
    found: dict[type, list[Any]] = {}
    for root in _roots():
        for _, value in [("", root), *configs.walk(root)]:
            cls = type(value)
            if dataclasses.is_dataclass(value) and cls.__module__.startswith("pal."):
                if all(v is not value for v in found.setdefault(cls, [])):
                    found[cls].append(value)
    return found


def _is_option(value: Any) -> bool:
    return isinstance(value, OPTION_CLASSES)


def _option_fields(option: Any) -> set[str]:
    """Field names of an option object and of the option objects nested in it."""
    names = {f.name for f in dataclasses.fields(option)}
    for f in dataclasses.fields(option):
        value = getattr(option, f.name)
        if _is_option(value):
            names |= _option_fields(value)
    return names


def duplicated_settings(instances: dict[type, list[Any]]) -> list[str]:
    """The violations of rules 1 and 2 (module docstring), one line each."""
    problems = []
    used = set()
    for cls, values in sorted(instances.items(), key=lambda kv: _name(kv[0])):
        fields = [f.name for f in dataclasses.fields(cls)]
        for option in OPTION_CLASSES:
            option_names = {f.name for f in dataclasses.fields(option)}
            copied = sorted(
                n for n in fields if n in option_names and not any(_is_option(getattr(v, n)) for v in values)
            )
            key = (_name(cls), option.__name__)
            if len(copied) >= 2:
                if key in ALLOWED:
                    used.add(key)
                    continue
                problems.append(
                    f"{_name(cls)} copies {copied} of inference.{option.__name__}: nest the "
                    f"{option.__name__} object instead (e.g. schedule=, svi=, sampling=, action=)"
                )
        for value in values:
            for f in fields:
                held = getattr(value, f)
                if not _is_option(held):
                    continue
                beside = sorted(n for n in fields if n != f and n in _option_fields(held))
                if beside:
                    problems.append(
                        f"{_name(cls)} declares {beside} beside {f}: {type(held).__name__}, which holds "
                        f"them already; set {f}.<name> instead"
                    )
    problems += [f"ALLOWED entry {key} no longer matches; remove it" for key in sorted(set(ALLOWED) - used)]
    return sorted(set(problems))


def _defaults(cls: type) -> dict[str, Any]:
    """Field name -> default of ``cls`` (fields without a default left out)."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return out


def shared_groups(classes: list[type]) -> list[str]:
    """The violations of rule 3 (module docstring), one line each."""
    problems, used = [], set()
    ordered = sorted(classes, key=_name)
    for i, a in enumerate(ordered):
        for b in ordered[i + 1 :]:
            da, db = _defaults(a), _defaults(b)
            shared = sorted(
                n
                for n in set(da) & set(db)
                if n != "seed" and not dataclasses.is_dataclass(da[n]) and da[n] == db[n]
            )
            if len(shared) < 3:
                continue
            key = (_name(a), _name(b))
            if key in ALLOWED_SHARED:
                used.add(key)
                continue
            problems.append(f"{key[0]} and {key[1]} both declare {shared}: nest one config class in both")
    problems += [f"ALLOWED_SHARED entry {k} no longer matches; remove it" for k in sorted(set(ALLOWED_SHARED) - used)]
    return problems


def test_no_group_of_settings_is_declared_in_two_config_classes():
    problems = shared_groups(list(_instances()))
    assert not problems, "\n".join(problems)


def test_the_group_rule_catches_a_copied_group():
    @dataclasses.dataclass(frozen=True)
    class GoalsA:
        seed: int = 0
        radius: float = 0.2
        bearing: float = 25.0
        cone: tuple[float, float] = (-60.0, 15.0)

    @dataclasses.dataclass(frozen=True)
    class GoalsB:
        seed: int = 1
        radius: float = 0.2
        bearing: float = 25.0
        cone: tuple[float, float] = (-60.0, 15.0)
        steps: int = 3

    problems = [p for p in shared_groups([GoalsA, GoalsB]) if "GoalsA" in p]
    assert len(problems) == 1 and "['bearing', 'cone', 'radius']" in problems[0]


def test_option_classes_are_found_and_frozen():
    names = {c.__name__ for c in OPTION_CLASSES}
    assert {"FitSchedule", "SVIOptions", "SamplingConfig", "ActionOptions"} <= names
    for cls in OPTION_CLASSES:
        assert cls.__dataclass_params__.frozen, cls  # type: ignore[attr-defined]


def test_every_setting_is_declared_once():
    instances = _instances()
    assert len(instances) > 20  # the trees were walked
    problems = duplicated_settings(instances)
    assert not problems, "\n".join(problems)


def test_the_rule_catches_a_copied_and_a_beside_setting():
    @dataclasses.dataclass(frozen=True)
    class CopiedPlan:
        population: int = 64
        elites: int = 8

    @dataclasses.dataclass(frozen=True)
    class BesidePlan:
        lr: float = 0.05
        action: inference.ActionOptions = inference.ActionOptions()

    for cls in (CopiedPlan, BesidePlan):
        cls.__module__ = "pal.fake"
    problems = duplicated_settings({CopiedPlan: [CopiedPlan()], BesidePlan: [BesidePlan()]})
    text = "\n".join(problems)
    assert "CopiedPlan copies ['elites', 'population'] of inference.SamplingConfig" in text
    assert "BesidePlan declares ['lr'] beside action: ActionOptions" in text


@pytest.mark.parametrize(
    ("path", "value", "read"),
    [
        ("plan.action.sampling.population", 128, lambda c: c.plan.action.sampling.population),
        ("plan.action.horizon", 5, lambda c: c.plan.action.horizon),
        ("plan.action.risk", ["disagreement", 0.5], lambda c: c.plan.action.risk),
        ("model.schedule.epochs", 7, lambda c: c.model.schedule.epochs),
        ("estimate.svi.lr", 0.05, lambda c: c.estimate.svi.lr),
        ("curiosity.sampling.elites", 4, lambda c: c.curiosity.sampling.elites),
    ],
)
def test_dotted_paths_reach_the_nested_options(path, value, read):
    expected = tuple(value) if isinstance(value, list) else value
    assert read(configs.override(AgentConfig(), path, value)) == expected


def test_a_none_option_group_starts_from_its_defaults_and_a_bare_word_is_a_one_entry_tuple():
    b2 = registry.get("experiment", "b2")
    thesis = configs.override(b2.default(), "action.options.sampling", None)
    assert thesis.action.options.sampling is None
    sampled = configs.override(thesis, "action.options.sampling.population", 64)
    assert sampled.action.options.sampling == inference.SamplingConfig(population=64)
    assert configs.override(b2.default(), "protocol.graphs", "state").protocol.graphs == ("state",)
