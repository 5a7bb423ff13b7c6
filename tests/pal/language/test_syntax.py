"""The query and rule parser: a table of malformed texts, each with its error class and the exact
0-based position its one-line message names; and parse -> str -> parse round trips."""

from __future__ import annotations

import re

import pytest

from pal.language.signature import (
    ArityError,
    NotAnActionError,
    SortError,
    UnknownConstantError,
    UnknownPredicateError,
)
from pal.language.syntax import MAX_TEXT_CHARS, QuerySyntaxError, parse_query, parse_rule
from pal.language.terms import Literal, Query, Rule, atom
from pal.language.vocabularies import pushing_signature

SIG = pushing_signature()
RULE = "reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) > 0.5"

# (text, parse as "query" or "rule", check with the pushing signature, error class, position)
MALFORMED = [
    # unbalanced parentheses and brackets
    ("P(touch(hand, box)", "query", False, QuerySyntaxError, 18),  # missing ')' at end of input
    ("touch(hand, box))", "query", False, QuerySyntaxError, 16),
    ("P((touch(hand, box))", "query", False, QuerySyntaxError, 2),
    ("P(touch(hand, box)]", "query", False, QuerySyntaxError, 18),
    ("P[touch(hand, box) | do(reach(hand, box))", "query", False, QuerySyntaxError, 41),
    ("touch(hand, box) | do[reach(hand, box))", "query", False, QuerySyntaxError, 38),
    ("touch(hand, box)[do(hold(hand))", "query", False, QuerySyntaxError, 31),
    ("touch(hand, box)[]", "query", False, QuerySyntaxError, 17),
    # empty text and trailing garbage
    ("", "query", False, QuerySyntaxError, 0),
    ("   ", "query", False, QuerySyntaxError, 3),
    ("touch(hand, box) extra", "query", False, QuerySyntaxError, 17),
    ("P(touch(hand, box)) x", "query", False, QuerySyntaxError, 20),
    ("touch(hand, box) $", "query", False, QuerySyntaxError, 17),
    ("touch(hand, box), near(hand, box)", "query", False, QuerySyntaxError, 16),
    ("touch(hand, box) | do(reach(hand, box)) near(hand, box)", "query", False, QuerySyntaxError, 40),
    # bad '@' tags
    ("touch(hand, box)@middle", "query", False, QuerySyntaxError, 17),
    ("touch(hand, box)@", "query", False, QuerySyntaxError, 17),
    ("touch(hand, box)@3", "query", False, QuerySyntaxError, 17),
    ("touch(hand, box)@start@end", "query", False, QuerySyntaxError, 22),
    # '|' with nothing after it
    ("touch(hand, box) |", "query", False, QuerySyntaxError, 18),
    ("P(touch(hand, box) | )", "query", False, QuerySyntaxError, 21),
    # do without an atom
    ("touch(hand, box) | do()", "query", False, QuerySyntaxError, 22),
    ("touch(hand, box) | do(hand)", "query", False, QuerySyntaxError, 26),
    ("touch(hand, box) | do", "query", False, QuerySyntaxError, 21),
    # keywords used as names
    ("do(touch, box)", "query", False, QuerySyntaxError, 0),
    ("P(touch(and, box))", "query", False, QuerySyntaxError, 8),
    ("touch(do, box)", "query", False, QuerySyntaxError, 6),
    ("and(hand, box)", "query", False, QuerySyntaxError, 0),
    ("not not touch(hand, box)", "query", False, QuerySyntaxError, 4),
    ("not", "query", False, QuerySyntaxError, 3),
    ("Pr", "query", False, QuerySyntaxError, 2),
    ("P touch(hand, box)", "query", False, QuerySyntaxError, 2),
    # numbers and punctuation where a name is expected
    ("3(hand)", "query", False, QuerySyntaxError, 0),
    ("touch(hand, 3)", "query", False, QuerySyntaxError, 12),
    ("touch(hand box)", "query", False, QuerySyntaxError, 11),
    ("touch(hand,)", "query", False, QuerySyntaxError, 11),
    ("touch(hand. box)", "query", False, QuerySyntaxError, 10),
    ("touch hand", "query", False, QuerySyntaxError, 6),
    ("touch(hand, box) and", "query", False, QuerySyntaxError, 20),
    # the signature's errors, at the offending atom (or argument)
    ("tuch(hand, box)", "query", True, UnknownPredicateError, 0),
    ("P(near(hand, box) | tuch(hand, box))", "query", True, UnknownPredicateError, 20),
    ("touch(hand)", "query", True, ArityError, 0),
    ("P(touch(hand, box) | do(reach(hand)))", "query", True, ArityError, 24),
    ("near(hand, box) and touch(hand, box, ball)", "query", True, ArityError, 20),
    ("P(touch(hand, box) | do(near(hand, box)))", "query", True, NotAnActionError, 24),
    ("P(touch(hand, box)[do(near(hand, box))] | do(hold(hand)))", "query", True, NotAnActionError, 22),
    ("P(touch(hand, box) | do(fly(hand)))", "query", True, NotAnActionError, 24),
    ("reach(hand, box)", "query", True, NotAnActionError, 0),
    ("touch(hand, cup)", "query", True, UnknownConstantError, 12),
    ("near(hand,   kettle)", "query", True, UnknownConstantError, 13),
    ("P(touch(hand, box) | near(hand, cup))", "query", True, UnknownConstantError, 32),
    ("touch(hand, box) | do(hold(cup))", "query", True, UnknownConstantError, 27),
    ("P(touch(hand, box) | do(reach(box, hand)))", "query", True, SortError, 24),
    ("reachable(box, box)", "query", True, SortError, 0),
    # rules
    ("", "rule", False, QuerySyntaxError, 0),
    ("reachable(h, o) and do(reach(h, o)) P(touch(h, o)) > 0.5", "rule", False, QuerySyntaxError, 36),
    ("reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) > 1.5", "rule", False, QuerySyntaxError, 56),
    ("reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) > 1", "rule", False, QuerySyntaxError, 56),
    ("reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) > -0.5", "rule", False, QuerySyntaxError, 56),
    ("reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) > x", "rule", False, QuerySyntaxError, 56),
    ("reachable(h, o) and do(reach(h, o)) => P(touch(h, o))", "rule", False, QuerySyntaxError, 53),
    ("reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) < 0.5", "rule", False, QuerySyntaxError, 54),
    ("reachable(h, o) and do(reach(h, o)) => P(touch(h, o)) > 0.5 x", "rule", False, QuerySyntaxError, 60),
    ("reachable(h, o) and do(reach(h, o)) => touch(h, o) > 0.5", "rule", False, QuerySyntaxError, 39),
    (
        "reachable(h, o) and do(reach(h, o)) => P(touch(h, o)@start) > 0.5",
        "rule",
        False,
        QuerySyntaxError,
        53,
    ),
    ("do(reach(h, o)) and do(push(h, o)) => P(touch(h, o)) > 0.5", "rule", False, QuerySyntaxError, 20),
    ("reachable(h, o) => P(touch(h, o)) > 0.5", "rule", False, QuerySyntaxError, 16),
    ("reachable(h, o) and do(reach(h, o)) => P(tuch(h, o)) > 0.5", "rule", True, UnknownPredicateError, 41),
    ("reachable(h) and do(reach(h, o)) => P(touch(h, o)) > 0.5", "rule", True, ArityError, 0),
    ("reachable(h, o) and do(near(h, o)) => P(touch(h, o)) > 0.5", "rule", True, NotAnActionError, 23),
    ("reach(h, o) and do(reach(h, o)) => P(touch(h, o)) > 0.5", "rule", True, NotAnActionError, 0),
    ("reachable(box, o) and do(reach(h, o)) => P(touch(h, o)) > 0.5", "rule", True, SortError, 0),
]


@pytest.mark.parametrize(("text", "kind", "checked", "error", "position"), MALFORMED)
def test_malformed_text_gets_a_one_line_error_naming_its_position(text, kind, checked, error, position):
    parse = parse_query if kind == "query" else parse_rule
    with pytest.raises(error) as info:
        parse(text, SIG if checked else None)
    assert type(info.value) is error  # the specific class, not a parent
    message = str(info.value)
    assert "\n" not in message
    named = [int(p) for p in re.findall(r"at position (\d+)", message)]
    assert named == [position], message
    if isinstance(info.value, QuerySyntaxError):
        assert info.value.position == position and info.value.text == text
        assert message.startswith(f"{kind}: expected ")
        line, caret = info.value.caret().split("\n")
        assert caret == " " * position + "^" and line == text


def test_the_table_covers_every_error_class_and_at_least_twenty_queries():
    queries = [row for row in MALFORMED if row[1] == "query" and row[3] is QuerySyntaxError]
    assert len(queries) >= 20
    assert {row[3] for row in MALFORMED} == {
        QuerySyntaxError,
        UnknownPredicateError,
        UnknownConstantError,
        ArityError,
        SortError,
        NotAnActionError,
    }


@pytest.mark.parametrize("conjuncts", [600, 16_000])
@pytest.mark.parametrize("kind", ["query", "rule"])
def test_a_text_past_the_length_limit_is_refused_naming_its_length_and_the_limit(kind, conjuncts):
    body = " and ".join("touch(hand, box)" for _ in range(conjuncts))
    text = f"P({body})" if kind == "query" else f"{body} and do(reach(h, o)) => P(touch(h, o)) > 0.5"
    parse = parse_query if kind == "query" else parse_rule
    assert len(text) > MAX_TEXT_CHARS == 10_000
    with pytest.raises(QuerySyntaxError) as info:
        parse(text, SIG)
    assert str(info.value) == (
        f"{kind}: the text has {len(text)} characters, more than the limit of 10000; split it into smaller queries"
    )
    assert info.value.position == MAX_TEXT_CHARS and info.value.text == text
    at_limit = " and ".join("touch(hand, box)" for _ in range(400))
    assert len(parse_query(f"P({at_limit})").outcome) == 400  # below the limit: parsed as before


def test_messages_name_what_was_expected_and_found():
    with pytest.raises(
        QuerySyntaxError, match=r"^query: expected '\|' or '\)' at position 18, found end of input$"
    ):
        parse_query("P(touch(hand, box)")
    with pytest.raises(QuerySyntaxError, match=r"expected '\(' or '\[' after 'do' at position 21"):
        parse_query("touch(hand, box) | do")
    with pytest.raises(QuerySyntaxError, match=r"after 'Pr' at position 2"):
        parse_query("Pr")
    with pytest.raises(QuerySyntaxError, match=r"found '1.5'"):
        parse_rule(RULE.replace("0.5", "1.5"))
    with pytest.raises(SortError, match=r"'box' is an object, expected body_part"):
        parse_rule(RULE.replace("reachable(h", "reachable(box"), SIG)
    with pytest.raises(UnknownPredicateError, match=r"the signature knows \['left_of', 'moving'"):
        parse_query("tuch(hand, box)", SIG)
    with pytest.raises(TypeError, match="expected a str, got int"):
        parse_query(3)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="signature must be a Signature"):
        parse_query("touch(hand, box)", {"touch": 1})  # type: ignore[arg-type]


def test_rule_variables_are_not_unknown_constants_but_query_arguments_are():
    rule = parse_rule(RULE, SIG)
    assert rule.action == atom("reach", "h", "o") and rule.kappa == 0.5
    with pytest.raises(UnknownConstantError, match="'h' at position 6"):
        parse_query("touch(h, o)", SIG)


ROUND_TRIP_QUERIES = [
    "touch(hand, box)",
    "P(touch(hand, box) | do(reach(hand, box)), near(hand, box))",
    "Pr[touch(hand, box) | do[reach(hand, box)], near(hand, box)]",
    "P(moving(box)[do(hold(hand))] | do(push(hand, box)), moving(box)@end)",
    "P(not touch(hand, ball) and moving(box) | ~near(hand, ball), left_of(hand, box)@end)",
    "P(near(hand, box)@start | do(reach(hand, box)), do(push(hand, box)))",
    "P(touch(hand, box)@end ∧ ¬moving(ball) | do(hold(hand)))",
    "P(touch(hand, box)[do(hold(hand)), do(reach(hand, ball))] | do(push(hand, box)))",
]


@pytest.mark.parametrize("text", ROUND_TRIP_QUERIES)
def test_query_round_trip(text):
    q = parse_query(text, SIG)
    again = parse_query(str(q), SIG)
    assert again == q and str(again) == str(q)
    assert again.text == str(q) and q.text == text


def test_parsed_queries_hold_the_expected_values():
    q = parse_query("P(moving(box)[do(hold(hand))] | do(push(hand, box)), moving(box)@end)")
    assert q == Query(
        (Literal(atom("moving", "box")),),
        (Literal(atom("moving", "box"), time="end"),),
        (atom("push", "hand", "box"),),
        (atom("hold", "hand"),),
    )
    assert q.is_counterfactual and q.outcome[0].time == "end"
    q = parse_query("P(not touch(hand, ball) | ~near(hand, ball))")
    assert q.outcome[0].negated and q.evidence[0].negated and q.evidence[0].time == "start"
    assert q.outcome[0].atom.position == 6 and q.evidence[0].atom.position == 27


@pytest.mark.parametrize(
    "text",
    [
        RULE,
        "reachable(h, o) ∧ do[reach(h, o)] ⇒ Pr[touch(h, o)] > 0.8",
        "do(push(hand, box)) => P(moving(box)) > 0.25",
        "near(h, o) and not touch(h, o) and do(reach(h, o)) => P(not touch(h, o)@end) > 0",
        "do(hold(h)) => P(near(h, o)) > 0.123456789",
        "do(hold(h)) => P(near(h, o)) > 1e-05",
    ],
)
def test_rule_round_trip(text):
    r = parse_rule(text, SIG)
    again = parse_rule(str(r), SIG)
    assert isinstance(again, Rule) and again == r and str(again) == str(r)
    assert again.query() == r.query()
