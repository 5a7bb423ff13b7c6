"""The terms of the query language: atoms, literals, queries and rule schemas (thesis Eq. 6.8-6.11).

An atom ``P(o_1, ..., o_n)`` names a predicate or an action term and its argument constants.
A literal is an atom, possibly negated, read at one time of the situation: ``start`` (the
current situation, before any intervention) or ``end`` (the outcome, after the intervention).
A query

    Pr[ outcome [do(cf ...)] | do(a_1), ..., e_1, ..., e_m ]                          (6.10)

asks for the probability that every outcome literal holds (their grades multiplied), given the
evidence literals e_j, in the world where the action terms a_k are executed. With
``counterfactual`` action terms the outcome is read in a second world that shares the first
world's exogenous noise (a twin network): the evidence (factual, ``start`` or ``end``) weighs the
pairs, the outcome is graded in the counterfactual world.

A rule schema (Eq. 6.11) ``premise_1 ∧ ... ∧ do[a] ⇒ Pr[conclusion] > κ`` abbreviates the query
``Pr[conclusion | do(a), premises] > κ``.

These are plain frozen values: the parser (:mod:`pal.language.syntax`) and the Python API build
them, the signature checks them, the evaluator answers them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal as TypingLiteral

__all__ = ["TIMES", "Atom", "Literal", "Query", "Rule", "Time", "atom"]

Time = TypingLiteral["start", "end"]
#: The times a literal may be read at.
TIMES: tuple[str, ...] = ("start", "end")


@dataclass(frozen=True)
class Atom:
    """``name(args...)``: a predicate or action term applied to constants.

    Attributes:
        name: the predicate's or action term's name.
        args: the argument constants' names.
        position: 0-based character offset of the atom in the query text (0 when built in Python).
    """

    name: str
    args: tuple[str, ...] = ()
    position: int = field(default=0, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise ValueError(f"an atom's name must be an identifier, got {self.name!r}")
        if not isinstance(self.args, tuple) or not all(
            isinstance(a, str) and a.isidentifier() for a in self.args
        ):
            raise ValueError(f"{self.name}: arguments must be a tuple of identifiers, got {self.args!r}")

    def __str__(self) -> str:
        return f"{self.name}({', '.join(self.args)})"


def atom(name: str, *args: str) -> Atom:
    """``atom("touch", "hand", "box")`` is ``touch(hand, box)``."""
    return Atom(name, tuple(args))


@dataclass(frozen=True)
class Literal:
    """An atom or its negation, read at ``time``; its grade is g or 1 - g.

    Attributes:
        atom: the predicate atom.
        negated: grade ``1 - g`` instead of ``g``.
        time: ``"start"`` (before the interventions) or ``"end"`` (after).
    """

    atom: Atom
    negated: bool = False
    time: Time = "end"

    def __post_init__(self) -> None:
        if not isinstance(self.atom, Atom):
            raise TypeError(f"a literal holds an Atom, got {type(self.atom).__name__}")
        if self.time not in TIMES:
            raise ValueError(f"{self.atom}: time must be one of {TIMES}, got {self.time!r}")

    def __str__(self) -> str:
        text = f"not {self.atom}" if self.negated else str(self.atom)
        return f"{text}@{self.time}"


@dataclass(frozen=True)
class Query:
    """``Pr[outcome [do(counterfactual)] | do(interventions), evidence]`` (module docstring).

    Attributes:
        outcome: literals that must all hold (a conjunction, grades multiplied); at least one.
        evidence: conditioning literals (default time ``start``: the current grounded beliefs).
        interventions: action terms executed in the (factual) world, in order.
        counterfactual: action terms of the counterfactual world, or ``None`` for an
            interventional query; the outcome is then read in that world.
        text: the source text when parsed, else ``""``.
    """

    outcome: tuple[Literal, ...]
    evidence: tuple[Literal, ...] = ()
    interventions: tuple[Atom, ...] = ()
    counterfactual: tuple[Atom, ...] | None = None
    text: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not self.outcome:
            raise ValueError("a query needs at least one outcome literal")
        for what, items, kind in (
            ("outcome", self.outcome, Literal),
            ("evidence", self.evidence, Literal),
            ("interventions", self.interventions, Atom),
            ("counterfactual", self.counterfactual or (), Atom),
        ):
            if not isinstance(items, tuple) or not all(isinstance(x, kind) for x in items):
                raise TypeError(f"Query.{what} must be a tuple of {kind.__name__}, got {items!r}")
        if self.counterfactual is not None and not self.counterfactual:
            raise ValueError("a counterfactual query needs at least one counterfactual action term")

    @property
    def is_counterfactual(self) -> bool:
        """Whether the outcome is read in a counterfactual world."""
        return self.counterfactual is not None

    def atoms(self) -> tuple[Atom, ...]:
        """Every predicate atom of the query (outcome, then evidence)."""
        return tuple(lit.atom for lit in self.outcome + self.evidence)

    def __str__(self) -> str:
        out = " and ".join(map(str, self.outcome))
        if self.counterfactual is not None:
            out += "[" + ", ".join(f"do({a})" for a in self.counterfactual) + "]"
        given = [f"do({a})" for a in self.interventions] + [str(e) for e in self.evidence]
        return f"P({out} | {', '.join(given)})" if given else f"P({out})"


@dataclass(frozen=True)
class Rule:
    """``premises ∧ do[action] ⇒ Pr[conclusion] > kappa`` (Eq. 6.11), over variables such as h, o.

    Attributes:
        premises: literals that must hold in the current situation (time ``start``).
        action: the action term executed.
        conclusion: the literal whose probability is bounded (time ``end``).
        kappa: the bound, in [0, 1).
        text: the source text when parsed, else ``""``.
    """

    premises: tuple[Literal, ...]
    action: Atom
    conclusion: Literal
    kappa: float
    text: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.kappa, int | float) or not 0.0 <= float(self.kappa) < 1.0:
            raise ValueError(f"a rule's kappa must be a number in [0, 1), got {self.kappa!r}")

    def query(self) -> Query:
        """The query the rule abbreviates: ``Pr[conclusion | do(action), premises]``."""
        return Query((self.conclusion,), self.premises, (self.action,))

    def __str__(self) -> str:
        lhs = " and ".join([*map(str, self.premises), f"do({self.action})"])
        return f"{lhs} => P({self.conclusion}) > {float(self.kappa)!r}"
