"""A backend's calls on a daemon thread of their own, so that a plugin that ignores a stop can be
abandoned instead of holding the session (and the process) for ever.

The driver (:func:`stw_tui.sos.backend.run_iterations`) hands its loop (``init`` and every
iteration, in one call) to the thread and waits for its answer. While it waits it polls the
caller's stop flag; once a stop has been asked for, a call that has not answered within
:data:`STOP_GRACE` seconds is given up: :class:`HungBackend` is raised, the solve fails as "hung"
and its result, should it ever come, is dropped. The thread is a daemon thread, not an executor's
worker: ``concurrent.futures`` joins its threads at interpreter exit, which a hung call would
block for ever.

Each call runs in a copy of the driver's context (``contextvars``), so the scene's limits in force
(stw_tui/sym/limits.py) and numpy's error state reach the backend as if it ran on the caller's thread.
Ctrl+C while waiting (headless `stw run`) ends the solve at once with an error: the main thread is
the one that receives it, the backend's thread never does.

A backend whose calls cannot hang (``Backend.bounded_calls``: the shared SQP, one bounded
iteration a call) has its calls made on the caller's thread instead (:class:`Inline`), without
the hand-offs' cost; Ctrl+C there ends the solve with the same error.
"""

from __future__ import annotations

import atexit
import contextvars
import os
import queue
import threading
import time
from typing import Any, Callable

from stw_tui.sym.errors import SolveError

STOP_GRACE = 5.0   # seconds a backend may take to honour a stop before it is abandoned as hung
POLL = 0.05        # seconds between looks at the stop flag while a call runs
JOIN_TIMEOUT = 1.0  # seconds the exit waits for an idle thread to end (it takes a fraction of a ms)


class HungBackend(SolveError):
    """A backend ignored a stop for :data:`STOP_GRACE` seconds and was abandoned."""


class BackendThread:
    """The daemon thread that runs a backend's calls in order, for one run of iterations.

    The thread is an idle one left by an earlier run when there is one (:data:`IDLE_KEPT` are
    kept): starting a thread cost 0.14 ms of every `iterate`, 3% of the pendulum's.

    Args:
        name: the backend's name (for messages and the thread's name).
        cancelled: the caller's stop flag, polled while a call runs.
    """

    def __init__(self, name: str, cancelled: Callable[[], bool]):
        self.name = name
        self.cancelled = cancelled
        self.context = contextvars.copy_context()
        self._answered = True   # no call waiting for its answer (close() may keep the thread)
        with _POOL_LOCK:
            self._worker = _IDLE.pop() if _IDLE else None
        if self._worker is None:
            self._worker = _Worker()
        self._thread = self._worker.thread
        self._thread.name = f"stw-backend-{name}"

    def call(self, what: str | Callable[[], str], fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` on the backend's thread; its result, or the exception it raised.

        Args:
            what: what the call does, for the messages ("iteration 3"), or a function that says
                what it is doing at the moment (a call that runs many iterations).
        Raises:
            HungBackend: a stop was asked for and the call did not answer within STOP_GRACE s.
            SolveError: Ctrl+C while the call ran.
        """
        reply: queue.SimpleQueue = queue.SimpleQueue()
        self._answered = False
        self._worker.requests.put((self.context, fn, args, reply))
        try:
            ok, value = self._wait(reply, what)
            self._answered = True
        except KeyboardInterrupt:   # wherever in the wait it lands
            raise interrupted(self.name, what) from None
        if ok:
            return value
        raise value

    def _wait(self, reply: queue.SimpleQueue, what) -> tuple[bool, Any]:
        """The call's (ok, result or exception), watching the stop flag meanwhile."""
        stop_asked = None
        while True:
            try:
                return reply.get(timeout=POLL)
            except queue.Empty:
                pass
            if stop_asked is None and self.cancelled():
                stop_asked = time.monotonic()
            if stop_asked is not None and time.monotonic() - stop_asked > STOP_GRACE:
                raise HungBackend(
                    f"backend {self.name} hung: it ignored the stop for {STOP_GRACE:g} s during {_said(what)} "
                    "and was abandoned (it may go on running in the background until stw exits); "
                    "the scene is unchanged")

    def close(self) -> None:
        """Done with the thread. One whose calls all answered waits idle for the next run (or,
        with :data:`IDLE_KEPT` idle already, ends and is joined at interpreter exit:
        :func:`_join_closed`); one abandoned in a hung call ends once that call returns, and is
        not waited for."""
        worker, self._worker = self._worker, None
        if worker is None:
            return
        if not self._answered:
            worker.requests.put(None)
            return
        with _POOL_LOCK:
            if len(_IDLE) < IDLE_KEPT:
                worker.thread.name = "stw-backend-idle"
                _IDLE.append(worker)
                return
        worker.requests.put(None)
        with _POOL_LOCK:
            _CLOSED.difference_update([t for t in _CLOSED if not t.is_alive()])
            _CLOSED.add(worker.thread)


class Inline:
    """A :class:`BackendThread`'s calls made on the caller's own thread, for a backend whose
    calls each return after a bounded amount of work (``Backend.bounded_calls``): a stop is
    honoured at the loop's next iteration boundary, and there is nothing to abandon."""

    def __init__(self, name: str):
        self.name = name

    def call(self, what: str | Callable[[], str], fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)``; its result, or the exception it raised.

        Raises:
            SolveError: Ctrl+C while the call ran (as :meth:`BackendThread.call` says it).
        """
        try:
            return fn(*args)
        except KeyboardInterrupt:
            raise interrupted(self.name, what) from None

    def close(self) -> None:
        """Nothing to close: no thread was taken."""


class _Worker:
    """A daemon thread serving (context, fn, args, reply) requests until it reads None."""

    def __init__(self):
        self.requests: queue.SimpleQueue = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._serve, name="stw-backend", daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while True:
            request = self.requests.get()
            if request is None:
                return
            context, fn, args, reply = request
            try:
                answer = (True, context.run(fn, *args))
            except BaseException as exc:  # noqa: BLE001 - the driver decides what a fault means
                answer = (False, exc)
            # an idle thread holds nothing of its last call (a backend's problem, its arrays)
            del request, context, fn, args
            reply.put(answer)
            del answer, reply


def _said(what: str | Callable[[], str]) -> str:
    return what() if callable(what) else what


def interrupted(name: str, what: str | Callable[[], str]) -> SolveError:
    """The error of a solve ended by Ctrl+C, on a backend thread or on the caller's."""
    return SolveError(f"interrupted (Ctrl+C) during {_said(what)} of backend {name}; the scene is unchanged")


IDLE_KEPT = 2   # idle threads kept for the next runs (two solves may run at once: a survey's, the console's)

# Idle threads, and threads told to end. A thread still unwinding a backend's C++ when the
# interpreter exits is killed there, and torch's noexcept frames turn that into "terminate called
# without an active exception" and exit status 134 (1 `stw run --backend torch` in 10): they are
# ended and joined before that, at exit rather than in close(), where waiting for a thread to end
# cost 0.2 ms of every `iterate`.
_IDLE: list[_Worker] = []
_CLOSED: set[threading.Thread] = set()
_POOL_LOCK = threading.Lock()


@atexit.register
def _join_closed() -> None:
    with _POOL_LOCK:
        idle = _IDLE[:]
        _IDLE.clear()
        threads = list(_CLOSED) + [worker.thread for worker in idle]
    for worker in idle:
        worker.requests.put(None)
    for thread in threads:
        thread.join(timeout=JOIN_TIMEOUT)


def _forget_idle_in_child() -> None:
    """A forked child has none of its parent's threads: their idle entries would never answer."""
    global _POOL_LOCK
    _POOL_LOCK = threading.Lock()
    _IDLE.clear()
    _CLOSED.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_idle_in_child)
