"""The text syntax of queries (Eq. 6.10) and rule schemas (Eq. 6.11): a recursive-descent parser.

Grammar (EBNF; ``{x}`` repeats, ``[x]`` is optional; whitespace is free)::

    query      = ( "P" | "Pr" ) ( "(" body ")" | "[" body "]" ) | body ;
    body       = outcome [ "[" do_term { "," do_term } "]" ] [ "|" condition { "," condition } ] ;
    outcome    = literal { and literal } ;
    condition  = do_term | literal ;
    do_term    = "do" ( "(" atom ")" | "[" atom "]" ) ;
    literal    = [ "not" | "~" | "¬" ] atom [ "@" ( "start" | "end" ) ] ;
    atom       = IDENT "(" [ IDENT { "," IDENT } ] ")" ;
    rule       = item { and item } ( "=>" | "⇒" ) ( "P" | "Pr" ) ( "(" literal ")" | "[" literal "]" )
                 ">" NUMBER ;
    item       = do_term | literal ;            (exactly one do_term per rule)
    and        = "and" | "&" | "∧" ;

``P``, ``Pr``, ``do``, ``and`` and ``not`` are keywords, not names. Outcome literals are read at
``end`` (after the interventions), condition and premise literals at ``start`` (the current
grounded beliefs), unless tagged. An outcome followed by ``[do(c), ...]`` is counterfactual:
``P(moving(box)[do(hold(hand))] | do(push(hand, box)))`` reads "would the box have moved had the
hand held still". In a rule the arguments may be rule variables (``h``, ``o``), bound to constants
by :func:`pal.language.rules.instantiate`; the bound κ is in [0, 1) and the conclusion is read at
``end``.

Every malformed text raises :class:`QuerySyntaxError`, whose message is one line naming the
0-based character position and what was expected and found::

    query: expected ')' at position 18, found end of input

A text longer than :data:`MAX_TEXT_CHARS` characters is refused with a
:class:`QuerySyntaxError` naming its length and the limit, before it is read.

With a signature the parsed value is checked too, and the signature's own errors
(:mod:`pal.language.signature`) name the position of the offending atom.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from pal.language.signature import LanguageError, Signature, UnknownConstantError, sort_error
from pal.language.terms import TIMES, Atom, Literal, Query, Rule

__all__ = ["MAX_TEXT_CHARS", "QuerySyntaxError", "parse_query", "parse_rule"]

#: The longest query or rule text parsed, characters (some 600 conjuncts); longer ones are refused.
MAX_TEXT_CHARS = 10_000

#: Keywords: the canonical token kind of each spelling.
_KEYWORDS = {"P": "P", "Pr": "P", "do": "do", "and": "and", "not": "not"}
_OPERATORS = {"=>": "=>", "⇒": "=>", "&": "and", "∧": "and", "~": "not", "¬": "not"}
_TOKEN = re.compile(
    r"\s*(?:(?P<number>\d+(?:\.\d*)?(?:[eE][-+]?\d+)?|\.\d+)|(?P<ident>[^\W\d]\w*)"
    r"|(?P<op>=>|[()\[\],|@>&~⇒∧¬])|(?P<junk>\S))"
)


class QuerySyntaxError(LanguageError):
    """A malformed query or rule text.

    Attributes:
        position: 0-based character offset of the offending token (``len(text)`` at the end).
        text: the whole text parsed.
    """

    def __init__(self, message: str, position: int, text: str) -> None:
        super().__init__(message)
        self.position = position
        self.text = text

    def caret(self) -> str:
        """Two lines: the text's line holding the error and a caret under the position."""
        start = self.text.rfind("\n", 0, self.position) + 1
        end = self.text.find("\n", self.position)
        line = self.text[start : end if end >= 0 else len(self.text)]
        return f"{line}\n{' ' * (self.position - start)}^"


class _Token(NamedTuple):
    kind: str  # ident, number, junk, end, a keyword's canonical kind, or the operator itself
    text: str
    pos: int

    def describe(self) -> str:
        return "end of input" if self.kind == "end" else repr(self.text)


def _tokens(text: str) -> list[_Token]:
    out: list[_Token] = []
    pos = 0
    while (m := _TOKEN.match(text, pos)) is not None and m.lastgroup is not None:
        kind, value, start = m.lastgroup, m.group(m.lastgroup), m.start(m.lastgroup)
        if kind == "ident":
            kind = _KEYWORDS.get(value, "ident" if value.isidentifier() else "junk")
        elif kind == "op":
            kind = _OPERATORS.get(value, value)
        out.append(_Token(kind, value, start))
        pos = m.end()
    out.append(_Token("end", "", len(text)))
    return out


class _Parser:
    """One pass over the tokens of ``text``; ``what`` ("query" or "rule") prefixes errors."""

    def __init__(self, text: str, what: str) -> None:
        if not isinstance(text, str):
            raise TypeError(f"{what}: expected a str, got {type(text).__name__}")
        self.text, self.what = text, what
        if len(text) > MAX_TEXT_CHARS:
            raise QuerySyntaxError(
                f"{what}: the text has {len(text)} characters, more than the limit of {MAX_TEXT_CHARS}; "
                "split it into smaller queries",
                MAX_TEXT_CHARS,
                text,
            )
        self.toks = _tokens(text)
        self.i = 0
        self.arg_positions: dict[int, tuple[int, ...]] = {}  # atom position -> argument positions
        self.tag: _Token | None = None  # the time tag of the last literal, if any

    def peek(self) -> _Token:
        return self.toks[self.i]

    def next(self) -> _Token:
        tok = self.toks[self.i]
        self.i += tok.kind != "end"
        return tok

    def fail(self, expected: str, tok: _Token) -> QuerySyntaxError:
        return QuerySyntaxError(
            f"{self.what}: expected {expected} at position {tok.pos}, found {tok.describe()}",
            tok.pos,
            self.text,
        )

    def expect(self, kind: str, expected: str | None = None) -> _Token:
        tok = self.next()
        if tok.kind != kind:
            raise self.fail(expected or f"'{kind}'", tok)
        return tok

    def open(self) -> str:
        """``(`` or ``[`` after P, Pr or do; returns the matching closer."""
        keyword = self.toks[self.i - 1].text  # P, Pr or do, just read
        tok = self.next()
        if tok.kind not in ("(", "["):
            raise self.fail(f"'(' or '[' after {keyword!r}", tok)
        return ")" if tok.kind == "(" else "]"

    def atom(self, what: str) -> Atom:
        name = self.next()
        if name.kind != "ident":
            raise self.fail(what, name)
        self.expect("(", f"'(' after {name.text!r}")
        args: list[_Token] = []
        if self.peek().kind == ")":
            self.next()
        else:
            while True:
                arg = self.next()
                if arg.kind != "ident":
                    raise self.fail("an argument name", arg)
                args.append(arg)
                sep = self.next()
                if sep.kind == ")":
                    break
                if sep.kind != ",":
                    raise self.fail("',' or ')'", sep)
        self.arg_positions[name.pos] = tuple(a.pos for a in args)
        return Atom(name.text, tuple(a.text for a in args), position=name.pos)

    def literal(self, time: str) -> Literal:
        negated = self.peek().kind == "not"
        if negated:
            self.next()
        a = self.atom("a predicate name")
        self.tag = None
        if self.peek().kind == "@":
            self.next()
            self.tag = self.next()
            if self.tag.kind != "ident" or self.tag.text not in TIMES:
                raise self.fail("'start' or 'end' after '@'", self.tag)
            time = self.tag.text
        return Literal(a, negated, time)  # type: ignore[arg-type]

    def do_term(self) -> Atom:
        self.expect("do", "'do'")
        close = self.open()
        a = self.atom("an action term name")
        self.expect(close)
        return a

    def query(self) -> Query:
        close = None
        if self.peek().kind == "end":
            raise self.fail("a query", self.peek())
        if self.peek().kind == "P":
            self.next()
            close = self.open()
        outcome = [self.literal("end")]
        while self.peek().kind == "and":
            self.next()
            outcome.append(self.literal("end"))
        counterfactual = None
        if self.peek().kind == "[":
            self.next()
            counterfactual = [self.do_term()]
            while self.peek().kind == ",":
                self.next()
                counterfactual.append(self.do_term())
            self.expect("]", "',' or ']'")
        interventions: list[Atom] = []
        evidence: list[Literal] = []
        if self.peek().kind == "|":
            self.next()
            while True:
                if self.peek().kind == "do":
                    interventions.append(self.do_term())
                elif self.peek().kind in ("ident", "not"):
                    evidence.append(self.literal("start"))
                else:
                    raise self.fail("a condition (a literal or do(...))", self.peek())
                if self.peek().kind != ",":
                    break
                self.next()
        more = "','" if interventions or evidence else "'|'"
        self.expect(close or "end", f"{more} or " + (f"'{close}'" if close else "end of input"))
        if close is not None:
            self.expect("end", "end of input")
        return Query(
            tuple(outcome),
            tuple(evidence),
            tuple(interventions),
            None if counterfactual is None else tuple(counterfactual),
            text=self.text,
        )

    def rule(self) -> Rule:
        premises: list[Literal] = []
        action: Atom | None = None
        while True:
            tok = self.peek()
            if tok.kind == "do" and action is None:
                action = self.do_term()
            elif tok.kind in ("ident", "not"):
                premises.append(self.literal("start"))
            else:
                expected = (
                    "a literal (a rule has one do-term)" if tok.kind == "do" else "a literal or do(...)"
                )
                raise self.fail(expected, tok)
            if self.peek().kind != "and":
                break
            self.next()
        if action is None:
            raise self.fail("'and do(...)' (a rule needs an action term)", self.peek())
        self.expect("=>", "'=>'")
        self.expect("P", "'P(' or 'Pr['")
        close = self.open()
        conclusion = self.literal("end")
        if conclusion.time != "end" and self.tag is not None:
            raise self.fail("a conclusion read at end", self.tag)
        self.expect(close)
        self.expect(">", "'>'")
        bound = self.expect("number", "a bound κ (a number in [0, 1))")
        kappa = float(bound.text)
        if not 0.0 <= kappa < 1.0:
            raise self.fail("a bound κ in [0, 1)", bound)
        self.expect("end", "end of input")
        return Rule(tuple(premises), action, conclusion, kappa, text=self.text)


def _check_atom(signature: Signature, a: Atom, action: bool, args: tuple[int, ...], variables: bool) -> None:
    """Check one atom; unknown arguments are rule variables when ``variables`` is set."""
    lookup = signature.action if action else signature.predicate
    unknown = [i for i, n in enumerate(a.args) if n not in signature.constants]
    if not unknown:
        lookup(a)
        return
    known = (signature.actions if action else signature.predicates).get(a.name)
    if known is None or (not action and a.name in signature.actions) or known.arity != len(a.args):
        lookup(a)  # raises the name or arity error, which the signature checks before constants
    if not variables:
        i = unknown[0]
        raise UnknownConstantError(
            f"unknown object {a.args[i]!r} at position {args[i] if i < len(args) else a.position} "
            f"in {a}; the signature knows {sorted(signature.constants)}"
        )
    assert known is not None  # else lookup raised
    for i, (n, s) in enumerate(zip(a.args, known.sorts, strict=True)):  # constants among variables
        c = signature.constants.get(n)
        if c is not None and c.sort not in s.split("|"):
            raise sort_error(a, i, c, s)


def _check(parser: _Parser, signature: Signature, item: Query | Rule) -> None:
    """Check the atoms of ``item`` in text order, naming positions."""
    if not isinstance(signature, Signature):
        raise TypeError(f"signature must be a Signature, got {type(signature).__name__}")
    query = item.query() if isinstance(item, Rule) else item
    atoms = [(lit.atom, False) for lit in query.outcome + query.evidence]
    atoms += [(a, True) for a in query.interventions + (query.counterfactual or ())]
    for a, action in sorted(atoms, key=lambda x: x[0].position):
        positions = parser.arg_positions.get(a.position, ())
        _check_atom(signature, a, action, positions, variables=isinstance(item, Rule))


def parse_query(text: str, signature: Signature | None = None) -> Query:
    """Parse a query such as ``"P(touch(hand, box) | do(reach(hand, box)), near(hand, box))"``.

    Args:
        text: the query (grammar in the module docstring).
        signature: if given, every atom is checked against it.

    Raises:
        QuerySyntaxError: malformed text, naming the position, what was expected and found.
        UnknownPredicateError, UnknownConstantError, ArityError, SortError, NotAnActionError:
            from the signature, naming the atom's position.
    """
    parser = _Parser(text, "query")
    query = parser.query()
    if signature is not None:
        _check(parser, signature, query)
    return query


def parse_rule(text: str, signature: Signature | None = None) -> Rule:
    """Parse a rule schema such as ``"reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) > 0.8"``.

    Arguments that are not constants of ``signature`` are rule variables; bind them with
    :func:`pal.language.rules.instantiate`.

    Args:
        text: the rule (grammar in the module docstring).
        signature: if given, predicate and action names, ``do`` terms, arities and the sorts of
            constant arguments are checked.

    Raises:
        QuerySyntaxError: malformed text (also a κ outside [0, 1) or a conclusion read at start).
        UnknownPredicateError, ArityError, SortError, NotAnActionError: from the signature.
    """
    parser = _Parser(text, "rule")
    rule = parser.rule()
    if signature is not None:
        _check(parser, signature, rule)
    return rule
