"""Acting at most once every so many seconds: checkpoints of a running solve, redraws of the TUI.

:class:`Throttle` is the clock arithmetic (is it time yet?); :class:`ThrottledCall` adds the
trailing call: a request made too soon is not dropped but run once when the interval has passed,
however many requests came meanwhile (the newest iterate must be shown, just not 200 times a
second). Both take their clock, and the call its timer, as arguments: no sleeping in the tests,
and no Textual here (the app passes its ``set_timer``).
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable

Clock = Callable[[], float]
Schedule = Callable[[float, Callable[[], None]], Any]   # (delay, callback) -> a timer with .stop()


class Throttle:
    """At most once every ``interval`` seconds of ``clock``.

    Args:
        interval: seconds between two acts (0: no limit).
        clock: monotonic seconds (tests pass a fake one).
    """

    def __init__(self, interval: float, clock: Clock = time.monotonic):
        self.interval = interval
        self.clock = clock
        self._last = -math.inf   # never acted: the first act is due at once

    def wait(self) -> float:
        """Seconds until the next act is due (0: due now)."""
        return max(0.0, self.interval - (self.clock() - self._last))

    def mark(self, at: float | None = None) -> None:
        """Acted now (or at ``at`` of the clock): the next act is due ``interval`` seconds later."""
        self._last = self.clock() if at is None else at

    def reset(self) -> None:
        """Forget the last act: the next one is due at once."""
        self._last = -math.inf

    def due(self) -> bool:
        """Whether to act now; if so, counts it as done (for callers that drop what is too soon)."""
        if self.wait() > 0:
            return False
        self.mark()
        return True


class ThrottledCall:
    """Calls ``action`` at most once every ``interval`` seconds; a :meth:`request` that comes too
    soon is run when the interval has passed, and all requests made meanwhile are that one call.

    Args:
        action: what to run (it reads the newest state itself).
        interval: seconds between two calls.
        schedule: ``schedule(delay, callback)`` runs ``callback`` after ``delay`` seconds and returns
            a timer with ``stop()`` (Textual's ``set_timer``).
        clock: monotonic seconds (tests pass a fake one).
    """

    def __init__(self, action: Callable[[], None], interval: float, schedule: Schedule,
                 clock: Clock = time.monotonic):
        self.action = action
        self.throttle = Throttle(interval, clock)
        self._schedule = schedule
        self._timer = None
        self._ran = -math.inf   # when the action last ran

    @property
    def pending(self) -> bool:
        """A call is waiting for its turn."""
        return self._timer is not None

    def request(self) -> None:
        """Run the action now if it is due, else once it is (unless that is already arranged)."""
        if self._timer is not None:
            return
        wait = self.throttle.wait()
        if wait <= 0:
            self._run()
        else:
            self._timer = self._schedule(wait, self._run)

    def defer(self) -> None:
        """Count now as a call (the caller has just shown what the action would): the next one,
        waiting or requested, comes ``interval`` seconds from now, but never later than twice the
        interval after the last real call, however often it is deferred."""
        now = self.throttle.clock()
        self.throttle.mark(min(now, self._ran + self.throttle.interval))
        if self._timer is not None:
            self._timer.stop()
            self._timer = self._schedule(self.throttle.wait(), self._run)

    def cancel(self) -> None:
        """Drop the waiting call, if any, and let the next request run at once."""
        if self._timer is not None:
            self._timer.stop()
        self._timer = None
        self.throttle.reset()

    def _run(self) -> None:
        self._timer = None
        self.throttle.mark()
        self._ran = self.throttle.clock()
        self.action()
