"""A stop asked for while an SQP iteration runs ends that iteration at once (issue 52 item 5:
F4 ends a solve within 300 ms).

The driver's stop flag (``settings[CANCELLED]``, the TUI's F4) was read only at iteration
boundaries, and one basketball iteration far from the solution takes 0.1-0.4 s on these
machines. :func:`check` is called where an iteration loops (its attempts, the line search, the
QP's active-set passes and interior-point iterations): once the flag is up it raises
:class:`StepStopped`, the iteration is dropped, and the run ends STOPPED with the state of its
last whole iteration (what ``iterate K adapt=0`` replays, K its reports). A check reads a
context variable and calls the flag: about a microsecond, nothing beside a factorization. The
numbers of an iteration that is not stopped are those it had without the checks.
"""

from __future__ import annotations

import contextvars
from contextlib import contextmanager
from typing import Callable, Iterator

_FLAG: contextvars.ContextVar[Callable[[], bool] | None] = contextvars.ContextVar("stw_sqp_stop", default=None)


class StepStopped(Exception):
    """The user asked to stop while an iteration ran: it is abandoned, the last whole one stands."""


@contextmanager
def stoppable(cancelled: Callable[[], bool] | None) -> Iterator[None]:
    """Within the block, :func:`check` raises StepStopped once ``cancelled()`` is true (None:
    never)."""
    token = _FLAG.set(cancelled)
    try:
        yield
    finally:
        _FLAG.reset(token)


def check() -> None:
    """Raise StepStopped if a stop has been asked for (see :func:`stoppable`)."""
    cancelled = _FLAG.get()
    if cancelled is not None and cancelled():
        raise StepStopped
