"""Running command lines one at a time off the UI thread, and feeding an opened session file.

All commands — typed, from a panel or key, or read from a file — go through one queue and one
worker thread, in order. A solve therefore never blocks the keyboard, and a command typed while a
solve runs waits its turn instead of racing it on the scene. The worker talks to the UI only with
messages (``post_message`` is thread-safe and does not make the solver wait for a redraw).

Each job runs in its own *daemon* thread rather than a Textual thread worker: those run in the
event loop's default executor, which ``asyncio.run`` and the interpreter join at exit, so quitting
during a long solve used to wait for the solve. A daemon thread is abandoned instead (it is asked to
stop at the next iteration boundary, and dies with the process).

A solve (`iterate`, `slide`) runs in the solver process (stw_tui/session/child_process.py): the
worker thread only waits on its pipe, so the UI thread never waits for the solver's interpreter
lock, and quitting kills that process.
"""

from __future__ import annotations

import threading
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING

from stw_tui.app.heap import HeapSettler
from stw_tui.app.messages import (CommandFinished, CommandStarted, IterationReported, Job, Origin, SurveyProgressed,
                                  TaskFinished)
from stw_tui.session.child_process import NotPortable, SolverProcess, runs_in_solver_process, start_helpers
from stw_tui.session.queries import SceneInfo, scene_info
from stw_tui.sym.errors import StwError
from stw_tui.sym.language import QUERIES, classify_line

if TYPE_CHECKING:
    from textual.app import App

    from stw_tui.session.session import Session
    from stw_tui.sos.backend import StepReport


# Seconds a quitting TUI gives its solver process to write the iterate it has reached (at its
# next report: milliseconds on most scenes) before killing it: the periodic checkpoint, up to
# 3 s old, is what a longer iteration keeps. Ctrl+Q must still end stw well within a second.
QUIT_GRACE = 0.3
# ... and when the terminal hung up: nobody waits for the screen, and the solver process is niced
# (on a loaded machine it may not run at all for a few hundred ms).
HANGUP_GRACE = 2.0


def changes_scene(line: str) -> bool:
    """Whether a command line (that succeeded) may have changed the scene (or, as `save` and
    `export` do, writes what the scene is): any command but the queries (language.QUERIES)."""
    verb = classify_line(line).verb
    return verb is not None and verb not in QUERIES


class Script:
    """The lines of an opened session file, replayed to the end or stepped through, and the
    commands typed (or sent by a key or a panel) while it replays: those that may change the scene
    wait for its end (the file's own lines, its `print` checks among them, must run on the scene
    it builds), and read-only ones answer between two of its lines."""

    def __init__(self, path: Path, text: str, stepping: bool):
        self.path = path
        self.lines = text.splitlines()
        self.position = 0             # index of the next line to run
        self.running = not stepping   # False: wait for a step key
        self.held: list[Job] = []     # typed during the replay: run after its last line, in order
        self.queries: list[Job] = []  # read-only ones typed during it: run before its next line

    @property
    def done(self) -> bool:
        """Whether every line of the opened file has been run."""
        return self.position >= len(self.lines)

    def _is_command(self, index: int) -> bool:
        return not classify_line(self.lines[index]).is_blank

    def upcoming(self) -> tuple[int, str] | None:
        """The next command line (number, text), skipping comments and blank lines."""
        for index in range(self.position, len(self.lines)):
            if self._is_command(index):
                return index + 1, self.lines[index]
        return None

    def advance(self) -> tuple[list[str], Job | None]:
        """Move past the next command line.

        Returns:
            The comment lines passed on the way (to show them) and the job (None at the end).
        """
        comments = []
        while not self.done:
            index = self.position
            self.position += 1
            if self._is_command(index):
                return comments, Job(self.lines[index], number=index + 1, origin=Origin.FILE)
            if self.lines[index].strip():
                comments.append(self.lines[index])
        return comments, None


class Runner:
    """The queue of jobs and the state of the one running in the worker."""

    def __init__(self, app: "App", session: "Session | None" = None, solver_process: bool = True,
                 journal: Path | None = None, settle_heap: bool = False):
        self.app = app
        # After each job the heap is collected and frozen (heap.py): stw's own process only, not a
        # test's, whose heap is the test runner's.
        self.heap = HeapSettler() if settle_heap else None
        self.session = session
        self.journal = journal   # the file a session made here journals to (None: not journalled)
        self.replay_folder: Path | None = None   # the opened session file's folder: its lines write only there
        # Solves run in a child process: the UI thread then never waits for the solver's
        # interpreter lock (stw_tui/session/child_process.py).
        self.solver = SolverProcess() if solver_process else None
        if self.solver is not None:
            start_helpers()
        self.queue: deque[Job] = deque()
        self.current: Job | None = None
        self.stop_requested = threading.Event()
        self.thread: threading.Thread | None = None   # the worker of the current job
        self.reports: list["StepReport"] = []     # of the running (or last) solve

    @property
    def busy(self) -> bool:
        """Whether a job is running."""
        return self.current is not None

    @property
    def solving(self) -> bool:
        """Whether the running job is a solve (which F4 stops)."""
        return self.current is not None and self.current.is_solve

    def submit(self, job: Job) -> bool:
        """Queue a job; returns True when it has to wait behind a running one."""
        waiting = self.busy
        self.queue.append(job)
        self.pump()
        return waiting

    def pump(self) -> None:
        """Start the next queued job if none runs (called on the UI thread)."""
        if self.current is not None or not self.queue:
            return
        self.current = self.queue.popleft()
        self.stop_requested.clear()
        if self.current.is_solve:
            self.reports = []
        self.thread = threading.Thread(target=self.run, args=(self.current,), name="stw-session", daemon=True)
        self.thread.start()

    def stop(self) -> bool:
        """Ask a running solve to stop at the next iteration boundary; True if one was running."""
        if not self.solving:
            return False
        self.stop_requested.set()
        if self.solver is not None:   # now, not at the waiting side's next look (up to POLL_S later)
            self.solver.cancel()
        return True

    def abandon(self, grace: float = QUIT_GRACE) -> None:
        """The app is quitting: end the solver process (a solve there first keeps the iterate it
        has reached, if it gets to it within ``grace`` seconds), ask a running job to stop and
        never start the queued ones. The worker thread is not waited for (it is a daemon thread).
        """
        self.queue.clear()
        if self.solver is not None:   # before the stop: a solve stopped there would be journalled as
            self.solver.close(grace=grace)   # a stopped one, which a resume solves again
        self.stop_requested.set()

    def finished(self) -> None:
        """The worker's job is done (its message was handled): start the next one."""
        self.current = None
        self.pump()

    # --- in the worker thread ----------------------------------------------------------------
    def _post(self, message) -> None:
        """Post to the app; a message to an app that has quit meanwhile is dropped."""
        try:
            self.app.post_message(message)
        except RuntimeError:   # the event loop is already closed
            pass

    def run(self, job: Job) -> None:
        """Execute ``job`` on the session and post what happened. Never raises."""
        try:
            if self.session is None:   # the first job loads the core here, off the UI thread
                self.session = _new_session(self.journal)
        except Exception as exc:  # e.g. a broken install: say so instead of staying busy forever
            self._post(CommandFinished(job, None, exc, SceneInfo()))
            return
        if job.task is not None:
            self._run_task(job)
            return
        job.continuation = self.session.in_block   # read here: the UI thread would race the worker
        self._post(CommandStarted(job))

        def on_report(report: "StepReport") -> bool:
            if hasattr(report, "results"):   # a survey's table so far: the gallery shows it
                self._post(SurveyProgressed(survey_snapshot(report)))
                return not self.stop_requested.is_set()
            self.reports.append(report)
            self._post(IterationReported(report))
            return not self.stop_requested.is_set()
        on_report.cancelled = self.stop_requested.is_set   # polled inside one-call backends (IPOPT)

        outcome, error = None, None
        try:
            outcome = self._execute(job, on_report)
        except StwError as exc:
            error = exc
        except Exception as exc:  # a core bug must reach the console, not kill the worker
            error = exc
        try:
            proposal = self.session.proposal      # `set preview on`: the figure player shows it
            info = scene_info(self.session.scene, proposal.scene if proposal is not None else None,
                              outcome.dense if outcome is not None else None) if job.measure else None
        except Exception:  # measuring is best effort
            info = SceneInfo()
        # The views read this copy (in the UI thread and in their background computations)
        # while the next command changes the session's scene.
        self._post(CommandFinished(job, outcome, error, info, self.session.scene.copy()))
        self._settle_heap()

    def _settle_heap(self) -> None:
        if self.heap is not None:
            self.heap.settle()

    def _execute(self, job: Job, on_report):
        """Apply the job's line: a solve in the solver process, anything else here."""
        if self.solver is not None and not self.session.in_block and runs_in_solver_process(job.line):
            try:
                session, outcome, error = self.solver.execute(self.session, job.line, job.number, on_report,
                                                              self.stop_requested.is_set)
            except NotPortable:   # a session that does not pickle still solves, here
                pass
            else:
                self.session = session
                if error is not None:
                    raise error
                return outcome
        self.session.replay_folder = self.replay_folder
        return self.session.execute(job.line, line=job.number, on_report=on_report)

    def _run_task(self, job: Job) -> None:
        result, error = None, None
        try:
            result = job.task(self.session)
        except Exception as exc:  # shown in the console, like a command's error
            error = exc
        self._post(TaskFinished(job, result, error))
        self._settle_heap()


def survey_snapshot(table):
    """A copy of a survey table that the worker thread no longer changes."""
    from dataclasses import replace

    return replace(table, results=list(table.results), notes=list(table.notes))


def _new_session(journal: Path | None) -> "Session":
    """A new session (the core's first import: numpy, scipy, sympy, about a second), journalled to
    ``journal`` with its solves checkpointed beside it when one is given."""
    from stw_tui.session.session import Session

    session = Session(journal_path=journal)
    if journal is not None:
        from stw_tui.session.autosave import Checkpoints

        session.checkpoints = Checkpoints(Path(journal))
    return session
