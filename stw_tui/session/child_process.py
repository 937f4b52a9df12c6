"""Child processes of stw: how they start, and the solver process that runs the TUI's solves.

A solve run in a thread of the TUI's own process competes with the event loop for the interpreter
lock: every key then waits for the solver's Python between its numpy calls, and a solve can be
abandoned but not ended. :class:`SolverProcess` runs a solve in a process of its own instead
(tests/tmux_latency.py measures the keys while one runs). The session goes there as a pickle (a scene pickles in
milliseconds: its compiled terms are plain data plus generated code that is cached on disk), the
iteration reports stream back through a pipe as they come, and the session comes back, changed by
the command exactly as it would have been here. The same code runs on the same state, so the
result is bit for bit the one of a solve in this process.

A process that dies (killed, out of memory, a crashing backend) costs only the command: the
session here is the one from before it, and the journal on disk never saw the line (an entry is
written when it is settled, at the end).

Headless, `stw run` solves there too when the backend is a plugin other than the shared SQP
(:attr:`~stw_tui.sos.backend.Backend.bounded_calls` false; see ``Session.solver_process``): a plugin
that holds the interpreter lock in C would otherwise keep Ctrl+C's handler from ever running. The
child ignores SIGINT (a terminal sends it to the whole process group); Ctrl+C in the waiting
process ends the child at once (SIGKILL) and the command with an error.

No solver process outlives its parent, and none takes its running solve with it. A parent that
dies (kill -9, a hang-up) closes the pipe: at its next report the child writes the iterate its
solve has reached as the running checkpoint (stw_tui/session/midsolve.py), journals nothing and
ends, so `stw --resume` goes on from there. One held in C, which reports nothing, is ended by
Linux (``PR_SET_PDEATHSIG``) when the fork server, its parent, ends with stw; it keeps the
periodic checkpoint.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import pickle
import signal
import sys
import threading
import time
from typing import Callable

from stw_tui.sos import backend_calls
from stw_tui.sos.backend_calls import HungBackend, interrupted
from stw_tui.sym.errors import StwError
from stw_tui.sym.language import classify_line

POLL_S = 0.05          # how often the waiting side looks at cancellation and at the child's health
SOLVE_VERBS = frozenset({"iterate", "slide"})   # the commands that run in the solver process
# Added to the solver process's niceness (see serve): where both want a core, the TUI (idle but
# for keys) wins it; mild, so a solve is not starved by other busy processes of the user.
CHILD_NICENESS = 5
# Seconds past backend_calls.STOP_GRACE (when the child abandons a backend that ignores a stop)
# that the child has to answer a stop before it is ended: one held in C cannot even abandon it.
ANSWER_MARGIN = 1.0
# A backend that may hang (not the shared SQP, whose iterations read the stop themselves) and whose
# process stops counting BEAT_S beats for HELD_S seconds after a stop holds the interpreter lock in
# C: nothing in that process can answer any more, so it is ended then, not after STOP_GRACE.
BEAT_S, HELD_S = 0.1, 1.0
PR_SET_PDEATHSIG = 1   # <linux/prctl.h>: the signal a process gets when its parent ends
PRELOAD = ["stw_tui.session.survey", "stw_tui.session.session", "stw_tui.session.interpreter", "stw_scipy"]


def process_context():
    """Forkserver where there is one: a clean, single-threaded parent that has imported the core
    once, so a child starts in a fraction of a second instead of importing sympy and scipy again,
    and none of this process's threads (Textual's) leak into it. Spawn elsewhere."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)
    return context


def start_helpers() -> None:
    """Start multiprocessing's helper processes (the resource tracker, and the fork server with
    the core imported) now, while stderr is still the terminal's: started later from inside
    Textual, which replaces stderr with an object that has no file descriptor, a child fails
    with "bad value(s) in fds_to_keep". The fork server imports in the background meanwhile."""
    from multiprocessing import forkserver, resource_tracker

    # Started ignoring SIGHUP, which they keep through exec (and the solver process through fork):
    # a hang-up of the terminal's process group then leaves the TUI to end its solve (it keeps
    # the last iterate); each helper still ends when stw does (its pipe from stw closes).
    hangup = getattr(signal, "SIGHUP", None)
    previous = signal.signal(hangup, signal.SIG_IGN) if hangup is not None else None
    try:
        resource_tracker.ensure_running()
        if process_context().get_start_method() == "forkserver":
            forkserver.ensure_running()
    except Exception:  # the first child then reports its own error; the TUI must start regardless
        pass
    finally:
        if hangup is not None:
            signal.signal(hangup, previous)


def quiet_child() -> None:
    """A child writes nothing to the terminal (it would draw over the TUI)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)


def die_with_parent() -> bool:
    """Have Linux SIGKILL this process when its parent ends (a plugin's call held in C would
    otherwise run on, orphaned, until it returns). False where that cannot be asked (not Linux).
    Only for a child of a single-threaded parent, the fork server: the signal comes when the
    *thread* that started the child ends."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def end_with_parent(orphan_kill: bool) -> None:
    """In a child of the fork server (``orphan_kill``): be killed when the server ends, which it
    does when stw does (die_with_parent, asked while this process holds the server open, so it
    cannot have ended yet; then let go of it). A hang-up is then stw's to act on: it ends the
    solve keeping its last iterate. Elsewhere a hang-up ends the process (the default)."""
    dies = orphan_kill and die_with_parent()
    if orphan_kill:
        _leave_fork_server()
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_IGN if dies else signal.SIG_DFL)


def pool_worker(orphan_kill: bool) -> None:
    """The initializer of a survey's pool worker: quiet, and gone when stw goes (end_with_parent)."""
    quiet_child()
    end_with_parent(orphan_kill)


def runs_in_solver_process(text: str) -> bool:
    """Whether the command line ``text`` is a solve that :class:`SolverProcess` runs."""
    return classify_line(text).verb in SOLVE_VERBS


class _Unanswered(Exception):
    """The child did not answer a stop within STOP_GRACE + ANSWER_MARGIN seconds."""


def _may_hang(session) -> bool:
    """Whether the session's backend may hang (a plugin's calls; not the shared SQP's, which read
    the stop inside their iterations and hold the lock in C only briefly)."""
    from stw_tui.sos.backend import load_backend

    try:
        return not load_backend(session.scene.backend).bounded_calls
    except (StwError, AttributeError):
        return True


class _HeldInC(Exception):
    """The child's beat stopped for HELD_S seconds after a stop: its interpreter lock is held in C."""


def _keep_beating(beat) -> None:
    """Count ``beat`` up every BEAT_S seconds, for ever (a daemon thread of the child): the count
    stops only while the interpreter lock is held in C."""
    while True:
        beat.value += 1
        time.sleep(BEAT_S)


class NotPortable(Exception):
    """The session does not pickle, so it cannot be sent to the solver process."""


class SolverProcess:
    """One child process that executes solve commands on a copy of the session, started on the
    first solve and kept for the next ones (its caches of compiled terms stay warm).

    Args:
        quiet: the child writes nothing to the terminal (the TUI's; `stw run`'s child writes a
            plugin's output where the command's own goes).
    """

    def __init__(self, quiet: bool = True):
        self.quiet = quiet
        self._process = None
        self._conn = None
        self._cancel = None
        self._progress = None
        self._beat = None

    @property
    def pid(self) -> int | None:
        """The child's process id while it runs (tests kill it)."""
        return self._process.pid if self._process is not None and self._process.is_alive() else None

    def execute(self, session, text: str, line: int | None, on_report: Callable, cancelled: Callable[[], bool]):
        """Run the command ``text`` on a copy of ``session`` (a :class:`~stw_tui.session.session.Session`;
        not imported here, which the session's own modules import) in the child.

        ``on_report`` gets each iteration's report as it comes (returning False stops the solve,
        as does ``cancelled()`` turning true). Returns (session, outcome, error): the session as
        the command left it, with the command's outcome, or its error (the returned session has then recorded the failure,
        as one in this process would have).

        Raises:
            StwError: the child died; ``session`` is as it was.
            SolveError: Ctrl+C (headless) while the child ran: it is ended at once (SIGKILL, which
                no interpreter lock held in C can delay); ``session`` is as it was. A HungBackend
                when the child has not answered a stop (F4) within STOP_GRACE + ANSWER_MARGIN s:
                it is ended, the session as it was.
            NotPortable: the session cannot be copied to a process (the caller then runs the
                command itself).
        """
        try:
            payload = pickle.dumps(session, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:   # e.g. a plugin's object that does not pickle
            raise NotPortable(str(exc)) from exc
        try:
            return self._execute(payload, text, line, on_report, cancelled, _may_hang(session))
        except KeyboardInterrupt:   # wherever in the wait it lands
            # the child's own count, not the reports read here: Ctrl+C may land between a
            # report's arrival and its reading
            done = self._progress.value if self._progress is not None else 0
            self.close()
            backend = getattr(getattr(session, "scene", None), "backend", "?")
            raise interrupted(backend, f"iteration {done + 1}") from None
        except (_Unanswered, _HeldInC) as exc:
            done = self._progress.value if self._progress is not None else 0
            self.close()
            checkpoints = getattr(session, "checkpoints", None)
            if checkpoints is not None:   # the abandoned solve's, which a resume must not bring back
                checkpoints.midsolve.ended(force=True)
            backend = getattr(getattr(session, "scene", None), "backend", "?")
            how = (f"held the interpreter lock in C for {HELD_S:g} s after the stop, during iteration {done + 1},"
                   if isinstance(exc, _HeldInC) else
                   f"ignored the stop for {backend_calls.STOP_GRACE:g} s during iteration {done + 1}")
            raise HungBackend(f"backend {backend} hung: it {how} and its process was ended; "
                              "the scene is unchanged") from None

    def _ended_if_hung(self, error) -> None:
        """A backend the child abandoned as hung may go on running in a thread there (busy for
        ever): the child goes, and the next solve starts a new one."""
        if isinstance(error, HungBackend):
            self.close()

    def cancel(self) -> None:
        """Ask the running solve to stop now (any thread): the child reads the flag inside its
        iterations (stw_tui/sos/stopping.py). The waiting side also sets it from ``cancelled()``,
        within POLL_S, so a stop asked for before the command reached the child is not lost."""
        flag = self._cancel
        if flag is not None:
            flag.value = True

    def _execute(self, payload: bytes, text: str, line: int | None, on_report: Callable, cancelled: Callable[[], bool],
                 may_hang: bool = False):
        process, conn, cancel = self._ensure_started()
        cancel.value = False
        self._progress.value = 0
        stop_asked = heard = beats = None
        try:
            conn.send_bytes(pickle.dumps((payload, text, line), protocol=pickle.HIGHEST_PROTOCOL))
            while True:
                if not conn.poll(POLL_S):
                    if cancelled():
                        cancel.value = True
                    if cancel.value:
                        now = time.monotonic()
                        stop_asked = stop_asked or now
                        if beats != self._beat.value:
                            beats, heard = self._beat.value, now
                        if may_hang and now - max(heard, stop_asked) > HELD_S:
                            raise _HeldInC
                        if now - stop_asked > backend_calls.STOP_GRACE + ANSWER_MARGIN:
                            raise _Unanswered
                    if not process.is_alive():
                        raise EOFError
                    continue
                kind, *rest = pickle.loads(conn.recv_bytes())
                if kind == "report":
                    if on_report(rest[0]) is False or cancelled():
                        cancel.value = True
                    continue
                new_session, outcome, error = rest
                self._ended_if_hung(error)
                return new_session, outcome, error
        except (EOFError, OSError) as exc:   # it died, or close() (quitting) ended it
            code = self.close() if process is self._process else process.exitcode
            how = f" (exit code {code})" if code is not None else ""
            raise StwError(f"the solver process ended during `{text.strip()}`{how}; "
                           "the scene is as it was before the command") from exc

    def _ensure_started(self):
        if self._process is not None and self._process.is_alive():
            return self._process, self._conn, self._cancel
        self.close()
        context = process_context()
        ours, theirs = context.Pipe()
        # A flag in shared memory, not an Event: an Event's five named semaphores outlive the
        # os._exit with which the TUI quits, and the resource tracker warns about them after it.
        self._cancel = context.RawValue(ctypes.c_bool, False)
        self._progress = context.RawValue(ctypes.c_long, 0)   # the last iteration the child reported
        self._beat = context.RawValue(ctypes.c_long, 0)       # counted up while the child runs Python
        # From the fork server (single-threaded) the child may ask to die with its parent; a
        # spawned one's parent is the thread that started it, which ends with its job.
        orphan_kill = context.get_start_method() == "forkserver"
        self._process = context.Process(target=serve, args=(theirs, self._cancel, self.quiet, self._progress,
                                                            orphan_kill, self._beat),
                                        name="stw-solver", daemon=True)
        self._process.start()
        theirs.close()
        self._conn = ours
        return self._process, self._conn, self._cancel

    def close(self, grace: float = 0.0) -> int | None:
        """End the child (a solve in it is abandoned: quitting must not wait for it); returns its
        exit code. ``grace``: seconds the child has, once the pipe is closed, to write the iterate
        its solve has reached and end (serve), before it is killed."""
        process, conn, self._process, self._conn = self._process, self._conn, None, None
        if process is not None and conn is not None and grace > 0:
            conn.close()   # tells the child its parent is gone
            process.join(timeout=grace)
        if process is not None and process.is_alive():
            process.kill()   # before the pipe closes: no grace, no half-written checkpoint either
        if conn is not None:
            conn.close()
        if process is None:
            return None
        process.join(timeout=1.0)
        return process.exitcode


def serve(conn, cancel, quiet: bool = True, progress=None, orphan_kill: bool = False, beat=None) -> None:
    """The child: execute each (session, command) it is sent, streaming the reports, until the
    pipe closes. Ctrl+C is its parent's to act on (it ends this process). ``progress``: shared
    memory the child sets to each report's iteration before sending it, which the parent reads
    when Ctrl+C ends the child. ``orphan_kill``: ask to be killed when the parent (the fork
    server) ends (:func:`die_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    end_with_parent(orphan_kill)
    if quiet:
        quiet_child()
    parent = os.getppid()
    if beat is not None:
        threading.Thread(target=_keep_beating, args=(beat,), name="stw-beat", daemon=True).start()
    try:   # where cores are scarce, the keys come first: the TUI process wins the CPU over the solve
        os.nice(CHILD_NICENESS)
    except OSError:
        pass
    while True:
        try:
            payload, text, line = pickle.loads(conn.recv_bytes())
        except (EOFError, OSError):
            return
        session = pickle.loads(payload)

        def cancelled() -> bool:
            # Its parent gone (the fork server ends with stw: a TUI killed, a closed SSH session),
            # nobody waits for this solve any more.
            return cancel.value or os.getppid() != parent

        def on_report(report) -> bool:
            if progress is not None:
                progress.value = int(getattr(report, "iteration", progress.value))
            try:
                conn.send_bytes(pickle.dumps(("report", report), protocol=pickle.HIGHEST_PROTOCOL))
            except OSError:   # the pipe is closed: the parent died or quit
                _orphaned(session)
            return not cancelled()
        on_report.cancelled = cancelled   # polled inside one-call backends (IPOPT)

        outcome, error = None, None
        try:
            outcome = session.execute(text, line=line, on_report=on_report)
        except Exception as exc:  # the caller shows it as it would show one raised in its process
            error = _portable(exc)
        try:
            conn.send_bytes(pickle.dumps(("done", session, outcome, error), protocol=pickle.HIGHEST_PROTOCOL))
        except OSError:   # the parent is gone; the command is journalled here already
            return


def _leave_fork_server() -> None:
    """Close this child's copy of the fork server's liveness pipe (each child gets one, to start
    processes of its own through the server, which this one never does). The fork server ends when
    the last copy closes: with this one open, it outlived a killed stw as long as this process
    ran, and so did this process, whose end the kernel ties to the server's (die_with_parent)."""
    from multiprocessing import forkserver

    server = getattr(forkserver, "_forkserver", None)
    fd = getattr(server, "_forkserver_alive_fd", None)
    if fd is None:
        return
    server._forkserver_alive_fd = None
    try:
        os.close(fd)
    except OSError:
        pass


def _orphaned(session) -> None:
    """The parent is gone mid-solve: keep the iterate the solve has reached as its running
    checkpoint, journal nothing (the solve never ended; `stw --resume` goes on from there) and end
    at once. Journalling the broken pipe as the command's failure lost the solve."""
    checkpoints = getattr(session, "checkpoints", None)
    if checkpoints is not None:
        checkpoints.midsolve.keep_latest()
    os._exit(0)


def _portable(exc: Exception) -> Exception:
    """``exc``, or an StwError with its message when it does not survive a pickle round trip."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return StwError(str(exc))


__all__ = ["NotPortable", "SolverProcess", "die_with_parent", "end_with_parent", "pool_worker", "process_context",
           "quiet_child", "start_helpers", "runs_in_solver_process"]
