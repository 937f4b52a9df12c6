"""The Textual front end of stw. The core never imports this package.

``create_app`` builds a configured app (tests import it); ``run_app`` is what `stw [SESSION]` runs.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from stw_tui.app.app import StwApp

if TYPE_CHECKING:
    from stw_tui.session.session import Session

__all__ = ["StwApp", "create_app", "run_app"]


def settings_file() -> Path:
    """Where `stw` remembers the TUI's theme: $XDG_CONFIG_HOME/stw/tui.json (~/.config by default)."""
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(base) / "stw" / "tui.json"


def create_app(session_path: str | Path | None = None, step: bool = False, session: "Session | None" = None,
               *, show_timing: bool = True, blink: bool = True, settings_path: str | Path | None = None,
               solver_process: bool = True, journal: str | Path | None = None,
               notes: "list[str] | None" = None, quit_on_hangup: bool = False,
               settle_heap: bool = False) -> StwApp:
    """A ready-to-run app.

    Args:
        session_path: a .stw session to open and replay (or step through).
        step: step through the session line by line (F6) instead of replaying it to the end.
        session: drive this session instead of a new empty one.
        show_timing: show ms per iteration in the status line (False: deterministic snapshots).
        blink: blink the text cursor (False: deterministic snapshots).
        settings_path: a JSON file that remembers the theme between runs (None: not remembered).
        solver_process: run solves in a child process (False: in a thread of this one, where a
            plugin installed only in this process, as tests do, is found).
        journal: without ``session``, the file the new session journals to (its solves
            checkpointed beside it); the session is made, with the core's imports, off the UI
            thread once the app shows.
        notes: lines to show in the console when the app opens (what `stw --resume` restored).
        quit_on_hangup: SIGHUP quits as Ctrl+Q does (`stw` itself; a test's app leaves it alone).
        settle_heap: collect and freeze the heap after each command (`stw` itself, see heap.py; a
            test's app leaves the test runner's heap alone).
    """
    return StwApp(session=session, session_path=session_path, step=step, show_timing=show_timing, blink=blink,
                  settings_path=settings_path, solver_process=solver_process, journal=journal, notes=notes,
                  quit_on_hangup=quit_on_hangup, settle_heap=settle_heap)


# Seconds a thread may hold the interpreter lock while another waits for it (Python's default is
# 0.005). A solve runs in a thread of this process, and each turn of Textual's event loop gives the
# lock up in `select` and then waits for it: at 5 ms a wait, the dozens of turns a key takes cost
# hundreds of ms. Measured with tests/tmux_latency.py on basketball (2 busy cores, two runs each):
# the TUI solve while keys were pressed took 2.4x and 2.2x the headless one, against 4.2x and 7.8x
# at the default; console echo median 76 and 113 ms against 103 and 260 ms.
SWITCH_INTERVAL = 0.0005


def run_app(session_path: str | Path | None = None, step: bool = False,
            journal: str | Path | None = None, exit_process: bool = True, session: "Session | None" = None,
            notes: "list[str] | None" = None) -> int:
    """Run the TUI until the user quits, then end the process (or return its exit code).

    Args:
        session_path, step: as for :func:`create_app`.
        journal: a file the session's journal is appended to as commands are applied (each entry
            is written and closed at once, so nothing is pending at exit); solves are
            checkpointed beside it (stw_tui/session/autosave.py).
        session: drive this session (a resumed one, see stw_tui/session/autosave.py) instead of a new one.
        notes: lines to show in the console when the app opens (what a resume restored).
        exit_process: end the process with ``os._exit`` once the screen is restored, so Ctrl+Q
            takes well under a second: an interpreter that has loaded sympy and scipy spends about
            a second finalizing them, and a solve abandoned by Ctrl+Q (a daemon thread) is not
            waited for. False: return the exit code instead (for callers that go on).
    """
    # A new session (journalled or not) is made by the app's worker once the app shows: the core's
    # imports (numpy, scipy, sympy) took 1.2 s before the first frame when it was made here.
    # Its Runner starts multiprocessing's helpers here, before Textual replaces stderr
    # (child_process.start_helpers).
    app = create_app(session_path, step=step, session=session, settings_path=settings_file(), journal=journal,
                     notes=notes, quit_on_hangup=True, settle_heap=True)
    sys.setswitchinterval(SWITCH_INTERVAL)
    app.run()
    code = app.return_code or 0
    kept = session.journal.path if session is not None else journal
    try:
        if kept is not None:   # the screen is restored: say it
            from stw_tui.session.autosave import kept_note

            print(kept_note(Path(kept)), file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
    except OSError:   # hung up: no terminal to say it on
        pass
    if exit_process:
        # A survey's Dask workers are not killed here: each exits on its own once this process
        # is gone (Dask's AsyncProcess watches the parent), about 1.5 s later, busy or not.
        # SIGTERM'ing them first raced Dask's nanny thread, which reacts to their deaths by
        # releasing their queues' semaphores (unlinked, but os._exit cut it off before it told
        # the resource tracker: "leaked semaphore" and "No such file" over the shell, 1 run in
        # about 25 under load) or by starting new workers (12 semaphores left).
        _release_semaphores()
        os._exit(code)
    return code


def _release_semaphores() -> None:
    """Unlink the named semaphores of this process's multiprocessing objects (a survey's process
    pool and queues), as a normal interpreter exit does first (multiprocessing.util._exit_function
    runs the finalizers of priority >= 0: semaphore cleanup, queue closing; no joins). os._exit
    skips that, and the resource tracker then warns about "leaked semaphore objects" on the
    terminal just restored."""
    try:
        from multiprocessing import util

        util._run_finalizers(0)
    except Exception:  # best effort: quitting must not fail on it
        pass
