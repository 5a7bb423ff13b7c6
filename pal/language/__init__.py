"""A grounded query language over the world model (thesis §6.4.3, Eq. 6.8-6.11).

Modules, one concept each:

- :mod:`~pal.language.terms`: atoms, literals, queries and rule schemas (values, no meaning);
- :mod:`~pal.language.signature`: Σ = ⟨O, P, A, R⟩, the typed constants, predicates and action
  terms, and the language's errors;
- :mod:`~pal.language.predicates`: grounding maps g_P(x_S(t), o_1..o_n) ∈ [0, 1] (Eq. 6.9),
  the ``@predicate`` decorator; :mod:`~pal.language.builtins`: near, touch, reachable, moving,
  on, left_of on the graded relations of :mod:`pal.perception`;
- :mod:`~pal.language.actions`: do-terms compiled to fixed sequences or to action inference;
- :mod:`~pal.language.world`: situations, outcomes and the world model as a world;
  :mod:`~pal.language.sim_worlds`: the simulators (pushing world, ``Pusher-v5``) as worlds;
- :mod:`~pal.language.evaluate`: P(outcome | do(...), evidence) with a Monte-Carlo standard
  error (Eq. 6.10), counterfactual twin worlds;
- :mod:`~pal.language.syntax`: the text syntax and its one-line errors;
- :mod:`~pal.language.rules`: rule schemas licensed by the graph's mechanisms (Eq. 6.11);
- :mod:`~pal.language.vocabularies`: the signatures of the pushing world and ``Pusher-v5``.

Example::

    sig = pushing_signature(horizon=1)
    P("touch(hand, box) | do(reach(hand, box)), near(hand, box)", sig, ModelWorld(model), situations,
      model=model, samples=32)
"""

from pal.language.actions import CompileContext, fixed_action_term, inferred_action_term
from pal.language.builtins import builtin_predicates
from pal.language.evaluate import Answer, EvidenceError, P, answer, compile_plans, evaluate
from pal.language.predicates import MissingVariableError, WindowError, literal_grade, predicate
from pal.language.rules import License, RuleBook, RuleCheck, UnlicensedRuleError, instantiate
from pal.language.signature import (
    ActionTermDef,
    ArityError,
    Constant,
    GroundingRangeError,
    LanguageError,
    NotAnActionError,
    PredicateDef,
    Signature,
    SortError,
    UnknownConstantError,
    UnknownPredicateError,
)
from pal.language.sim_worlds import PusherWorld, PushingWorld, pusher_situations, pushing_situations
from pal.language.syntax import QuerySyntaxError, parse_query, parse_rule
from pal.language.terms import Atom, Literal, Query, Rule, atom
from pal.language.vocabularies import pusher_signature, pushing_signature
from pal.language.world import ModelWorld, Outcome, Situations, World

__all__ = [
    "ActionTermDef",
    "Answer",
    "ArityError",
    "Atom",
    "CompileContext",
    "Constant",
    "EvidenceError",
    "GroundingRangeError",
    "LanguageError",
    "License",
    "Literal",
    "MissingVariableError",
    "ModelWorld",
    "NotAnActionError",
    "Outcome",
    "P",
    "PredicateDef",
    "PusherWorld",
    "PushingWorld",
    "Query",
    "QuerySyntaxError",
    "Rule",
    "RuleBook",
    "RuleCheck",
    "Signature",
    "Situations",
    "SortError",
    "UnknownConstantError",
    "UnknownPredicateError",
    "UnlicensedRuleError",
    "WindowError",
    "World",
    "answer",
    "atom",
    "builtin_predicates",
    "compile_plans",
    "evaluate",
    "fixed_action_term",
    "inferred_action_term",
    "instantiate",
    "literal_grade",
    "parse_query",
    "parse_rule",
    "predicate",
    "pusher_signature",
    "pusher_situations",
    "pushing_signature",
    "pushing_situations",
]
