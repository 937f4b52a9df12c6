"""Computing a view's data in a background thread, keeping only the newest request.

A plot needs only the data of its latest request (the newest iterate, the frame just scrubbed
to): requests made while one is being computed replace each other, and the one left is computed
next. So there is never more than one thread per view, and a fast solve or a held arrow key does
not pile up work that competes with the solver for the interpreter.

The caller keeps the other half of "latest only": results come back as messages, and one may
arrive after a newer request was made (or after the view was cleared). :meth:`LatestOnly.accept`
says whether a result is still the one to show; :attr:`LatestOnly.pending` whether one is coming.

The threads are daemon threads, as the session worker's (see runner.py): quitting never waits
for a computation.
"""

from __future__ import annotations

import threading
from typing import Any, Callable

Deliver = Callable[[int, Any, "BaseException | None"], None]


class LatestOnly:
    """Runs one computation at a time off the calling thread; of those submitted meanwhile, only
    the last is run. Each result is handed to ``deliver(sequence, result, error)`` *in the
    background thread* (post a message from there: that is thread-safe in Textual).

    The thread is started once, at the first request, and then waits for the next: starting a
    thread per request blocked the caller until the new thread got the interpreter lock, tens of
    milliseconds of UI time while a solve held it.

    :meth:`submit`, :meth:`drop`, :meth:`accept` and :attr:`pending` are for the caller's thread
    (the UI's): they keep which request is the newest and which result was last accepted.
    """

    def __init__(self, deliver: Deliver, name: str = "stw-view"):
        self._deliver = deliver
        self._name = name
        self._ready = threading.Condition()
        self._waiting: tuple[int, Callable[[], Any]] | None = None
        self._thread: threading.Thread | None = None
        self._sequence = 0
        self._requested = 0   # sequence number of the newest request
        self._accepted = 0    # ... and of the newest result accepted

    @property
    def pending(self) -> bool:
        """The newest request's result has not been accepted yet."""
        return self._accepted < self._requested

    def accept(self, sequence: int) -> bool:
        """Whether the result numbered ``sequence`` is to be shown: False when it is older than
        one accepted or dropped since. Accepting it makes every older result stale."""
        if sequence <= self._accepted:
            return False
        self._accepted = sequence
        return True

    def drop(self) -> None:
        """Nothing is to be shown: the waiting computation is not run, and the results of every
        request made so far (one may be running) will not be accepted."""
        with self._ready:
            self._sequence += 1
            self._waiting = None
            self._requested = self._accepted = self._sequence

    def submit(self, compute: Callable[[], Any]) -> int:
        """Compute ``compute()`` in the background (after the running one; it replaces any
        computation still waiting). Returns the sequence number its result will carry."""
        with self._ready:
            self._sequence += 1
            self._waiting = (self._sequence, compute)
            self._requested = self._sequence
            self._ready.notify()
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, name=self._name, daemon=True)
                self._thread.start()
            return self._sequence

    def _loop(self) -> None:
        while True:
            with self._ready:
                while self._waiting is None:
                    self._ready.wait()
                (sequence, compute), self._waiting = self._waiting, None
            result, error = None, None
            try:
                result = compute()
            except Exception as exc:  # the view says what went wrong; the thread goes on
                error = exc
            try:
                self._deliver(sequence, result, error)
            except Exception:  # the app has quit meanwhile: nobody to tell
                pass
