"""The typed signature Σ = ⟨O, P, A, R⟩ of the query language (thesis Eq. 6.8), and its errors.

- O, the constants: objects, body parts and events, each bound to the named world-model or
  perception variables that ground it (``Constant.variables``: role -> variable name, e.g.
  ``{"position": "ee"}`` for the hand, ``{"position": "pos.box", "contact": "contact.box"}``).
- P, the predicates: a name, the sorts of its arguments, its support S_P (the variables it reads,
  from its arguments' bindings) and its grounding map g_P (Eq. 6.9), defined in
  :mod:`pal.language.predicates`.
- A, the action terms: a name, argument sorts, the action variables they set and the variables
  they aim at (so a rule schema can be licensed by graph paths), and how they compile to actions.
- R, typed relations among variables: the directed mechanisms of the world model's graph between
  the constants' variables (:meth:`Signature.relations`).

Every lookup is checked and fails with its own error type, naming the value and what exists.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from pal.language.terms import Atom, Query, Rule

__all__ = [
    "SORTS",
    "ActionTermDef",
    "ArityError",
    "Constant",
    "GroundingRangeError",
    "LanguageError",
    "NotAnActionError",
    "PredicateDef",
    "Signature",
    "SortError",
    "UnknownConstantError",
    "UnknownPredicateError",
]

#: The sorts of constants.
SORTS: tuple[str, ...] = ("object", "body_part", "event")


class LanguageError(ValueError):
    """A query, rule or signature entry that does not fit the signature."""


class UnknownPredicateError(LanguageError):
    """A predicate (or action term) name the signature does not hold."""


class UnknownConstantError(LanguageError):
    """An object, body part or event name the signature does not hold."""


class ArityError(LanguageError):
    """A predicate or action term applied to the wrong number of arguments."""


class SortError(LanguageError):
    """An argument of the wrong sort (e.g. an object where a body part is expected)."""


class NotAnActionError(LanguageError):
    """A ``do`` term on a predicate, or an action term used as a predicate."""


class GroundingRangeError(LanguageError):
    """A grounding map that returned values outside [0, 1] or NaN."""


@dataclass(frozen=True)
class Constant:
    """An element of O: an object, body part or event token and the variables that ground it.

    Attributes:
        name: identifier used in queries (``hand``, ``box``).
        sort: one of :data:`SORTS`.
        variables: role -> variable name (``position``, ``contact``, ``velocity``, ...).
        attributes: fixed numbers of the constant (e.g. ``radius`` in metres, ``reach`` of a hand).
    """

    name: str
    sort: str
    variables: Mapping[str, str] = field(default_factory=dict)
    attributes: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise LanguageError(f"a constant's name must be an identifier, got {self.name!r}")
        if self.sort not in SORTS:
            raise SortError(f"constant {self.name!r}: sort must be one of {SORTS}, got {self.sort!r}")
        object.__setattr__(self, "variables", MappingProxyType(dict(self.variables)))
        object.__setattr__(
            self, "attributes", MappingProxyType({k: float(v) for k, v in self.attributes.items()})
        )

    def variable(self, role: str, what: str = "") -> str:
        """The variable bound to ``role``.

        Raises:
            LanguageError: naming the constant, the role and the roles it has.
        """
        if role not in self.variables:
            raise LanguageError(
                f"{what + ': ' if what else ''}{self.sort} {self.name!r} has no {role!r} variable; "
                f"it binds {sorted(self.variables)}"
            )
        return self.variables[role]


def _check_sorts(name: str, sorts: tuple[str, ...]) -> tuple[str, ...]:
    if not isinstance(sorts, tuple):
        raise LanguageError(f"{name}: argument sorts must be a tuple, got {sorts!r}")
    for s in sorts:
        options = s.split("|")
        if not options or any(o not in SORTS for o in options):
            raise SortError(f"{name}: argument sort {s!r} is not one of {SORTS} (alternatives joined by '|')")
    return sorts


def sort_error(a: Atom, index: int, constant: Constant, expected: str) -> SortError:
    """The error for argument ``index`` (0-based) of ``a``, a ``constant`` not of sort ``expected``."""
    article = "an" if constant.sort[0] in "aeiou" else "a"
    return SortError(
        f"{a} at position {a.position}: argument {index + 1} {constant.name!r} is {article} "
        f"{constant.sort}, expected {expected}"
    )


@dataclass(frozen=True)
class PredicateDef:
    """An element of P.

    Attributes:
        name: the predicate's name.
        sorts: one sort per argument; ``"object|body_part"`` allows either.
        support: constants -> the variable names S_P it reads.
        ground: ``ground(values, constants) -> grade``: values[v] is (..., d_v) for every v in
            the support (``(..., T + 1, d_v)`` paths when ``window`` > 0), grade (...,) in [0, 1].
        window: steps of history it needs (0: the values at one time).
        doc: one line for listings.
    """

    name: str
    sorts: tuple[str, ...]
    support: Callable[[tuple[Constant, ...]], tuple[str, ...]]
    ground: Callable[[Mapping[str, Any], tuple[Constant, ...]], Any]
    window: int = 0
    doc: str = ""

    def __post_init__(self) -> None:
        _check_sorts(self.name, self.sorts)

    @property
    def arity(self) -> int:
        """Number of arguments."""
        return len(self.sorts)


@dataclass(frozen=True)
class ActionTermDef:
    """An element of A.

    Attributes:
        name: the action term's name.
        sorts: one sort per argument.
        actions: constants -> the action variables it sets.
        aims: constants -> the variables it aims at (what the compiled action brings about).
        compile: how it becomes actions (see :mod:`pal.language.actions`); ``None`` until bound.
        doc: one line for listings.
    """

    name: str
    sorts: tuple[str, ...]
    actions: Callable[[tuple[Constant, ...]], tuple[str, ...]]
    aims: Callable[[tuple[Constant, ...]], tuple[str, ...]] = lambda constants: ()
    compile: Callable[..., Any] | None = None
    doc: str = ""

    def __post_init__(self) -> None:
        _check_sorts(self.name, self.sorts)

    @property
    def arity(self) -> int:
        """Number of arguments."""
        return len(self.sorts)


class Signature:
    """Σ = ⟨O, P, A, R⟩ (Eq. 6.8): constants, predicates and action terms, checked on use.

    Args:
        constants: the objects, body parts and events.
        predicates: the predicates (e.g. :func:`pal.language.builtins.builtin_predicates`).
        actions: the action terms.
    """

    def __init__(
        self,
        constants: Iterable[Constant] = (),
        predicates: Iterable[PredicateDef] = (),
        actions: Iterable[ActionTermDef] = (),
    ) -> None:
        self._constants: dict[str, Constant] = {}
        self._predicates: dict[str, PredicateDef] = {}
        self._actions: dict[str, ActionTermDef] = {}
        for c in constants:
            self.add_constant(c)
        for p in predicates:
            self.add_predicate(p)
        for a in actions:
            self.add_action(a)

    # ------------------------------------------------------------------ building
    def add_constant(self, constant: Constant) -> Constant:
        """Add (or replace) a constant."""
        if not isinstance(constant, Constant):
            raise TypeError(f"expected a Constant, got {type(constant).__name__}")
        self._constants[constant.name] = constant
        return constant

    def add_predicate(self, predicate: PredicateDef) -> PredicateDef:
        """Add (or replace) a predicate; its name may not be an action term's."""
        if not isinstance(predicate, PredicateDef):
            raise TypeError(f"expected a PredicateDef, got {type(predicate).__name__}")
        if predicate.name in self._actions:
            raise LanguageError(
                f"{predicate.name!r} is already an action term; predicates and actions need distinct names"
            )
        self._predicates[predicate.name] = predicate
        return predicate

    def add_action(self, action: ActionTermDef) -> ActionTermDef:
        """Add (or replace) an action term; its name may not be a predicate's."""
        if not isinstance(action, ActionTermDef):
            raise TypeError(f"expected an ActionTermDef, got {type(action).__name__}")
        if action.name in self._predicates:
            raise LanguageError(
                f"{action.name!r} is already a predicate; predicates and actions need distinct names"
            )
        self._actions[action.name] = action
        return action

    # ------------------------------------------------------------------ reading
    @property
    def constants(self) -> Mapping[str, Constant]:
        """O: name -> constant."""
        return MappingProxyType(self._constants)

    @property
    def predicates(self) -> Mapping[str, PredicateDef]:
        """P: name -> predicate."""
        return MappingProxyType(self._predicates)

    @property
    def actions(self) -> Mapping[str, ActionTermDef]:
        """A: name -> action term."""
        return MappingProxyType(self._actions)

    def constant(self, name: str) -> Constant:
        """The constant ``name``.

        Raises:
            UnknownConstantError: naming it and the known constants.
        """
        if name not in self._constants:
            raise UnknownConstantError(
                f"unknown object {name!r}; the signature knows {sorted(self._constants)}"
            )
        return self._constants[name]

    def _arguments(self, a: Atom, sorts: tuple[str, ...], kind: str) -> tuple[Constant, ...]:
        if len(a.args) != len(sorts):
            raise ArityError(
                f"{kind} {a.name} takes {len(sorts)} argument{'s' if len(sorts) != 1 else ''} "
                f"({', '.join(sorts)}), got {len(a.args)} in {a} at position {a.position}"
            )
        constants = tuple(self.constant(n) for n in a.args)
        for i, (c, s) in enumerate(zip(constants, sorts, strict=True)):
            if c.sort not in s.split("|"):
                raise sort_error(a, i, c, s)
        return constants

    def predicate(self, a: Atom) -> tuple[PredicateDef, tuple[Constant, ...]]:
        """The predicate of atom ``a`` and its argument constants, checked.

        Raises:
            NotAnActionError: ``a`` names an action term.
            UnknownPredicateError, ArityError, UnknownConstantError, SortError.
        """
        if a.name in self._actions:
            raise NotAnActionError(f"{a} at position {a.position} is an action term; use it inside do(...)")
        if a.name not in self._predicates:
            raise UnknownPredicateError(
                f"unknown predicate {a.name!r} at position {a.position}; the signature knows {sorted(self._predicates)}"
            )
        p = self._predicates[a.name]
        return p, self._arguments(a, p.sorts, "predicate")

    def action(self, a: Atom) -> tuple[ActionTermDef, tuple[Constant, ...]]:
        """The action term of atom ``a`` (inside ``do``) and its argument constants, checked.

        Raises:
            NotAnActionError: ``a`` names a predicate (or nothing this signature knows).
            ArityError, UnknownConstantError, SortError.
        """
        if a.name not in self._actions:
            known = "a predicate" if a.name in self._predicates else "not an action term"
            raise NotAnActionError(
                f"do({a}) at position {a.position}: {a.name!r} is {known}; "
                f"the action terms are {sorted(self._actions)}"
            )
        t = self._actions[a.name]
        return t, self._arguments(a, t.sorts, "action term")

    def support(self, a: Atom) -> tuple[str, ...]:
        """S_P of a predicate atom: the variables it reads."""
        p, constants = self.predicate(a)
        return tuple(p.support(constants))

    def check(self, item: Query | Rule) -> Query | Rule:
        """Check every atom of a query or rule against the signature; returns it unchanged."""
        if isinstance(item, Rule):
            self.check(item.query())
            return item
        if not isinstance(item, Query):
            raise TypeError(f"expected a Query or Rule, got {type(item).__name__}")
        for lit in item.outcome + item.evidence:
            self.predicate(lit.atom)
        for a in item.interventions + (item.counterfactual or ()):
            self.action(a)
        return item

    def relations(self, graph: Any) -> tuple[tuple[str, str], ...]:
        """R: the graph's directed mechanisms (parent, child) between variables bound by constants."""
        bound = {v for c in self._constants.values() for v in c.variables.values()}
        return tuple((p, c) for p, c in graph.edges if p in bound and c in bound)

    def __repr__(self) -> str:
        return (
            f"Signature(constants={sorted(self._constants)}, predicates={sorted(self._predicates)}, "
            f"actions={sorted(self._actions)})"
        )
