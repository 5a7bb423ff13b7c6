"""Which handlers are active: pal's own registry, and Pyro's public ``am_i_wrapped``.

Every pal handler (:class:`inference.handlers.ProgramMessenger`) registers itself here when
it is entered, by ``with`` or while a program runs it, and leaves when it exits, in step
with Pyro's handler stack: on an exception it also drops the handlers entered after it, as
Pyro does. The queries read pal's active handlers from here (e.g. a ``MeasurementScale``
entered with ``with``) instead of from Pyro's private stack.

The fast paths of the queries (the torch twins :meth:`models.WorldModel.predict` and
:meth:`models.WorldModel.rollout`) bypass the Pyro program, so they may run only when no
handler at all is active (:func:`no_handler_active`): a pal handler would change the
program, and a foreign one (``poutine.trace``, ``poutine.condition``, a plate, ...) would
not see its sites.
"""

from __future__ import annotations

from pyro.poutine.messenger import Messenger
from pyro.poutine.runtime import am_i_wrapped

__all__ = ["active_handlers", "no_handler_active"]

_ACTIVE: list[Messenger] = []


def active_handlers() -> tuple[Messenger, ...]:
    """Pal's handlers active now, innermost (the last entered) first."""
    return tuple(reversed(_ACTIVE))


def no_handler_active() -> bool:
    """True when no Pyro handler, pal's or foreign, is active: a query may take its fast path."""
    return not am_i_wrapped() and not _ACTIVE


def register(handler: Messenger) -> None:
    """Record that ``handler`` was entered (after Pyro installed it)."""
    _ACTIVE.append(handler)


def unregister(handler: Messenger) -> None:
    """Record that ``handler`` exited: drop it and every handler entered after it."""
    for i, h in enumerate(_ACTIVE):
        if h is handler:
            del _ACTIVE[i:]
            return
