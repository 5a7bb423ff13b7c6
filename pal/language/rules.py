"""Rule schemas (thesis Eq. 6.11): licensed by the world model's graph, listed, checked against data.

A rule schema ``premise_1 ∧ ... ∧ do[a] ⇒ Pr[conclusion] > κ`` abbreviates the causal query
``Pr[conclusion | do(a), premises] > κ``. It is *licensed* by a causal graph only if the graph
holds the mechanisms the rule relies on:

- from the action variables the action term sets (``ActionTermDef.actions``) to **every**
  variable of the conclusion's support S_P (``Signature.support``): the action must be able to
  change everything the conclusion reads (for ``touch``: the hand, the object and the contact);
- from **every** variable of each premise's support to **some** variable of the conclusion's
  support (for ``reachable``: the hand-object distance must feed the contact).

Paths are directed and at least one mechanism long (sharing a variable is not a mechanism). They
run in the graph unrolled over the steps of a plan: a lag-0 variable's value is carried into its
lag-1 copy at the next step (``graph.lagged``, Alg. 4.1), so a path may step from ``v`` to a
lag-1 slot ``L`` with ``graph.lagged[L] == v``. This is how a premise read at the start reaches
the first step: ``pos.box ~> pos_prev.box -> contact.box``. The license records every path found.
A rule whose conclusion is read at start, or whose κ is outside [0, 1), is refused as well.

A :class:`RuleBook` keeps the licensed rules of a signature and graph, lists them and checks
each against data: ``Pr[conclusion | do(a), premises]`` is estimated by an evaluator (by default
:func:`pal.language.evaluate.evaluate`) and the rule *holds* when ``p - 1.645 se > κ``, is
*violated* when ``p + 1.645 se < κ``, and is *undecided* otherwise (one-sided 95 %).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from pal.language.signature import LanguageError, Signature
from pal.language.syntax import parse_rule
from pal.language.terms import Atom, Rule

__all__ = [
    "Z_ONE_SIDED",
    "Connection",
    "License",
    "RuleBook",
    "RuleCheck",
    "UnlicensedRuleError",
    "instantiate",
]

#: One-sided 95 % normal quantile used by :meth:`RuleBook.check`.
Z_ONE_SIDED = 1.645


class UnlicensedRuleError(LanguageError):
    """A rule schema the world model's graph does not license, naming the missing path."""


def instantiate(rule: Rule, bindings: Mapping[str, str]) -> Rule:
    """Substitute constants for the rule variables: ``instantiate(r, {"h": "hand", "o": "box"})``.

    Arguments not in ``bindings`` are kept (they are constants already). Positions and the source
    text are kept, so later errors still point into the schema's text.

    Raises:
        LanguageError: a binding for a name the rule does not use, or a value that is not an identifier.
    """
    used = {n for lit in (*rule.premises, rule.conclusion) for n in lit.atom.args} | set(rule.action.args)
    for var, value in bindings.items():
        if var not in used:
            raise LanguageError(
                f"rule {rule}: binding {var!r} names no argument; the rule uses {sorted(used)}"
            )
        if not isinstance(value, str) or not value.isidentifier():
            raise LanguageError(f"rule {rule}: binding {var!r} -> {value!r} is not a constant name")

    def sub(a: Atom) -> Atom:
        return Atom(a.name, tuple(bindings.get(n, n) for n in a.args), position=a.position)

    return replace(
        rule,
        premises=tuple(replace(p, atom=sub(p.atom)) for p in rule.premises),
        action=sub(rule.action),
        conclusion=replace(rule.conclusion, atom=sub(rule.conclusion.atom)),
    )


@dataclass(frozen=True)
class Connection:
    """One directed path the license relies on.

    Attributes:
        kind: ``"action"`` (action term -> conclusion) or ``"premise"`` (premise -> conclusion).
        term: the action or premise atom, as text.
        path: variable names from source to target; a step ``v -> L`` with ``L`` a lag-1 copy
            of ``v`` is the carry to the next step.
    """

    kind: str
    term: str
    path: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible form."""
        return {"kind": self.kind, "term": self.term, "path": list(self.path)}


@dataclass(frozen=True)
class License:
    """A licensed (instantiated) rule and the paths that license it."""

    rule: Rule
    connections: tuple[Connection, ...]

    @property
    def paths(self) -> list[list[str]]:
        """The paths as lists of variable names."""
        return [list(c.path) for c in self.connections]

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible form."""
        return {
            "rule": str(self.rule),
            "kappa": float(self.rule.kappa),
            "connections": [c.to_dict() for c in self.connections],
        }


def _path(graph: Any, sources: Iterable[str], targets: set[str]) -> tuple[str, ...] | None:
    """Shortest directed path (>= 1 edge) from any source to any target, lag carries included."""
    g = graph.nx
    carries: dict[str, list[str]] = {}
    for slot, base in graph.lagged.items():
        carries.setdefault(base, []).append(slot)
    queue = deque((s,) for s in sources)
    seen: set[str] = set()
    while queue:
        path = queue.popleft()
        for nxt in [*sorted(g.successors(path[-1])), *sorted(carries.get(path[-1], ()))]:
            if nxt in targets:
                return (*path, nxt)
            if nxt not in seen:
                seen.add(nxt)
                queue.append((*path, nxt))
    return None


def _in_graph(graph: Any, rule: Rule, names: Iterable[str], what: str) -> tuple[str, ...]:
    names = tuple(names)
    for n in names:
        if n not in graph:
            raise UnlicensedRuleError(
                f"rule {rule} is not licensed: variable {n!r} ({what}) is not in the graph"
            )
    return names


def license(rule: Rule, signature: Signature, graph: Any) -> License:
    """License an instantiated rule by paths of ``graph`` (a :class:`models.graph.CausalGraph`).

    Raises:
        UnlicensedRuleError: naming the missing path, the variable missing from the graph, a
            conclusion read at start or a κ outside [0, 1).
        LanguageError: (subclasses) the rule does not fit the signature (e.g. an unbound variable).
    """
    if not isinstance(rule, Rule):
        raise TypeError(f"expected a Rule, got {type(rule).__name__}")
    if not (isinstance(rule.kappa, int | float) and 0.0 <= float(rule.kappa) < 1.0):
        raise UnlicensedRuleError(f"rule {rule}: kappa must be in [0, 1), got {rule.kappa!r}")
    if rule.conclusion.time != "end":
        raise UnlicensedRuleError(f"rule {rule}: its conclusion {rule.conclusion} must be read at end")
    signature.check(rule)
    term, constants = signature.action(rule.action)
    concl = rule.conclusion.atom
    actions = _in_graph(graph, rule, term.actions(constants), f"action of {rule.action}")
    targets = _in_graph(graph, rule, signature.support(concl), f"support of {concl}")
    connections: list[Connection] = []
    for target in targets:
        path = _path(graph, actions, {target})
        if path is None:
            source = f"action {actions[0]!r}" if len(actions) == 1 else f"any of the actions {list(actions)}"
            raise UnlicensedRuleError(
                f"rule {rule} is not licensed: no directed path from {source} to {target!r} (support of {concl})"
            )
        connections.append(Connection("action", str(rule.action), path))
    for premise in rule.premises:
        for var in _in_graph(graph, rule, signature.support(premise.atom), f"support of {premise.atom}"):
            path = _path(graph, (var,), set(targets))
            if path is None:
                raise UnlicensedRuleError(
                    f"rule {rule} is not licensed: no directed path from {var!r} (support of {premise.atom}) "
                    f"to any of {list(targets)} (support of {concl})"
                )
            connections.append(Connection("premise", str(premise.atom), path))
    return License(rule, tuple(connections))


@dataclass(frozen=True)
class RuleCheck:
    """A licensed rule checked against data: ``p`` estimates ``Pr[conclusion | do(a), premises]``.

    Attributes:
        verdict: ``"holds"`` (p - 1.645 se > κ), ``"violated"`` (p + 1.645 se < κ) or ``"undecided"``.
    """

    rule: Rule
    p: float
    se: float
    verdict: str

    @property
    def interval(self) -> tuple[float, float]:
        """The one-sided 95 % bounds ``p ∓ 1.645 se``."""
        return self.p - Z_ONE_SIDED * self.se, self.p + Z_ONE_SIDED * self.se

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible form."""
        return {
            "rule": str(self.rule),
            "kappa": float(self.rule.kappa),
            "p": self.p,
            "se": self.se,
            "verdict": self.verdict,
        }


class RuleBook:
    """The licensed rule schemas of one signature and world-model graph.

    Args:
        signature: the signature the rules are written in.
        graph: the world model's :class:`models.graph.CausalGraph`.
    """

    def __init__(self, signature: Signature, graph: Any) -> None:
        if not isinstance(signature, Signature):
            raise TypeError(f"signature must be a Signature, got {type(signature).__name__}")
        self.signature, self.graph = signature, graph
        self._licenses: list[License] = []

    def add(self, rule: str | Rule, bindings: Mapping[str, str] | None = None) -> License:
        """Instantiate ``rule`` with ``bindings``, license it and keep it.

        Raises:
            UnlicensedRuleError: the graph does not license it (the rule is not kept).
            QuerySyntaxError, LanguageError: malformed text, an unbound variable, a signature error.
        """
        schema = parse_rule(rule, self.signature) if isinstance(rule, str) else rule
        if not isinstance(schema, Rule):
            raise TypeError(f"expected rule text or a Rule, got {type(rule).__name__}")
        concrete = instantiate(schema, dict(bindings or {}))
        atoms = [*(p.atom for p in concrete.premises), concrete.action, concrete.conclusion.atom]
        for a in atoms:
            for n in a.args:
                if n not in self.signature.constants:
                    raise LanguageError(
                        f"rule {schema}: variable {n!r} of {a} at position {a.position} is unbound; "
                        f"bindings give {dict(bindings or {})}, constants are {sorted(self.signature.constants)}"
                    )
        granted = license(concrete, self.signature, self.graph)
        self._licenses.append(granted)
        return granted

    def list(self) -> tuple[License, ...]:
        """The licensed rules with their paths, in the order added."""
        return tuple(self._licenses)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible listing."""
        return {"rules": [lic.to_dict() for lic in self._licenses]}

    def check(
        self, world: Any, situations: Any, evaluate: Callable[..., Any] | None = None, **options: Any
    ) -> tuple[RuleCheck, ...]:
        """Check every licensed rule against ``world`` from ``situations``.

        Args:
            world: a :class:`pal.language.world.World` (the model or a simulator).
            situations: the start situations.
            evaluate: ``evaluate(query, signature, world, situations, **options) -> answer`` with
                ``answer.p`` and ``answer.se``; default :func:`pal.language.evaluate.evaluate`.
            **options: passed to ``evaluate`` (samples, generator, horizon, ...).

        Raises:
            ValueError: the evaluator returned a non-finite p or se.
        """
        if evaluate is None:
            from pal.language.evaluate import evaluate
        out = []
        for lic in self._licenses:
            answer = evaluate(lic.rule.query(), self.signature, world, situations, **options)
            p, se = float(answer.p), float(answer.se)
            if not (math.isfinite(p) and math.isfinite(se) and se >= 0.0):
                raise ValueError(
                    f"rule {lic.rule}: the evaluator returned p={p}, se={se}; expected finite, se >= 0"
                )
            kappa = float(lic.rule.kappa)
            if p - Z_ONE_SIDED * se > kappa:
                verdict = "holds"
            elif p + Z_ONE_SIDED * se < kappa:
                verdict = "violated"
            else:
                verdict = "undecided"
            out.append(RuleCheck(lic.rule, p, se, verdict))
        return tuple(out)
