"""The real `stw` command in a real terminal (tmux): it starts, replays, draws, quits on Ctrl+Q.

Key latency and solve time in tmux are measured by tests/tmux_latency.py (a script that prints
figures, not a test).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from conftest import ENDLESS

ROOT = Path(__file__).resolve().parent.parent
STW = Path(sys.executable).parent / "stw"

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None or not STW.exists(),
                                reason="needs tmux and the installed `stw` script")


@pytest.fixture(autouse=True)
def private_state_dir(tmp_path, monkeypatch):
    """`stw` autosaves its journal to $XDG_STATE_HOME/stw: keep the tests' out of the user's."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg-state"))


def tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], capture_output=True, text=True, check=False).stdout


def start(name: str, command: str, cwd=ROOT) -> list[str]:
    """Start ``command`` in a detached 100x30 tmux session on a private server; returns its base args."""
    # A private socket (-L) keeps the test off the user's tmux server.
    base = ["-L", name]
    # COLUMNS/LINES set by a test runner would override the real pane size.
    subprocess.run(["tmux", *base, "new-session", "-d", "-s", name, "-x", "100", "-y", "30",
                    f"env -u COLUMNS -u LINES {command}"], cwd=cwd, check=True)
    return base


def running(pid: int) -> bool:
    """Whether process ``pid`` is alive (a zombie waiting for tmux to reap it has ended)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def wait_for(base: list[str], name: str, text: str, timeout: float = 60) -> str:
    """Capture the pane until it shows ``text``; returns the last capture."""
    deadline = time.monotonic() + timeout
    screen = tmux(*base, "capture-pane", "-p", "-t", name)
    while text not in screen and time.monotonic() < deadline:
        time.sleep(0.1)
        screen = tmux(*base, "capture-pane", "-p", "-t", name)
    return screen


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states in /proc")
def test_ctrl_q_ends_the_process_within_a_second_while_a_solve_runs(tmp_path):
    jet = (ROOT / "sessions" / "particle_jet.stw").read_text().split("iterate")[0]
    script = tmp_path / "endless.stw"
    script.write_text(jet + ENDLESS + "iterate 1000000\n")
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    base = start(name, f"{STW} {script}")
    try:
        screen = wait_for(base, name, "solving")
        assert "solving" in screen, screen
        time.sleep(1.0)                       # well into the solve
        # The process itself, not the tmux session: tmux notices an exit ~0.4 s late under load.
        pid = int(tmux(*base, "display-message", "-p", "-t", name, "#{pane_pid}").strip())
        pressed = time.monotonic()
        tmux(*base, "send-keys", "-t", name, "C-q")
        while running(pid) and time.monotonic() - pressed < 10:
            time.sleep(0.01)
        latency = time.monotonic() - pressed
        assert not running(pid), "stw did not quit on Ctrl+Q"
        print(f"Ctrl+Q to process exit during a solve: {latency:.3f} s")
        assert latency < 1.0
    finally:
        tmux(*base, "kill-server")


def test_stw_runs_in_tmux_replays_a_session_and_quits():
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    base = start(name, f"{STW} sessions/particle_jet.stw")
    try:
        screen = wait_for(base, name, "end of particle_jet.stw")
        assert "end of particle_jet.stw" in screen, screen
        assert "Opt" + " " * 18 + "Curves" in screen.splitlines()[0], "not laid out at 100 columns"
        for visible in ("stw>", "DOF", "Eqns", "Curves", "f5 Iterate", "backend scipy", "converged"):
            assert visible in screen, (visible, screen)
        tmux(*base, "send-keys", "-t", name, "C-q")
        deadline = time.monotonic() + 10
        while name in tmux(*base, "list-sessions") and time.monotonic() < deadline:
            time.sleep(0.2)
        assert name not in tmux(*base, "list-sessions"), "stw did not quit on Ctrl+Q"
    finally:
        tmux(*base, "kill-server")


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states in /proc")
def test_autosave_survives_kill_9_and_resume_reopens_it_without_solving(tmp_path):
    """`stw SESSION` journals to $XDG_STATE_HOME/stw with checkpoints; after a real SIGKILL,
    resuming rebuilds the replayed scene without solving, and `stw --resume` opens the TUI on it."""
    import signal

    from stw_tui.session import resume
    from stw_tui.session.session import Session

    state = tmp_path / "state"
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    base = start(name, f"env PYTHONPATH={ROOT} XDG_STATE_HOME={state} {STW} sessions/particle_jet.stw")
    try:
        screen = wait_for(base, name, "end of particle_jet.stw")
        assert "end of particle_jet.stw" in screen, screen
        pid = int(tmux(*base, "display-message", "-p", "-t", name, "#{pane_pid}").strip())
        os.kill(pid, signal.SIGKILL)
        deadline = time.monotonic() + 10
        while running(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        tmux(*base, "kill-server")
    journals = list((state / "stw").glob("particle_jet-*.stw"))
    assert len(journals) == 1, journals
    resumed, restored, solved = resume.resume(journals[0])
    assert restored >= 1 and solved == 0
    uninterrupted = Session()
    uninterrupted.run_file(ROOT / "sessions" / "particle_jet.stw")
    assert (resumed.scene.coefficient_vector() == uninterrupted.scene.coefficient_vector()).all()
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    base = start(name, f"env PYTHONPATH={ROOT} XDG_STATE_HOME={state} {STW} --resume")
    try:
        # what it restored, inside the TUI (not on the shell's hidden screen), and Up recalls
        # the resumed session's last command. ("resumed" alone: the journal's long path wraps
        # onto the next line, and waiting for "resumed " ran into the 60 s timeout every time.)
        screen = wait_for(base, name, "restored from")
        assert "stw>" in screen and "backend scipy" in screen, screen
        assert "solve(s) restored from checkpoints" in " ".join(screen.split()), screen
        tmux(*base, "send-keys", "-t", name, "Up")
        screen = wait_for(base, name, "print f")
        assert "print f" in screen, screen
        tmux(*base, "send-keys", "-t", name, "C-q")
        deadline = time.monotonic() + 10
        while name in tmux(*base, "list-sessions") and time.monotonic() < deadline:
            time.sleep(0.2)
        assert name not in tmux(*base, "list-sessions"), "stw --resume did not quit on Ctrl+Q"
    finally:
        tmux(*base, "kill-server")


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states in /proc")
def test_quitting_after_a_survey_leaves_no_warning_on_the_terminal_and_no_process_behind():
    """A survey's process pool leaves named semaphores; quitting (os._exit) used to skip their
    cleanup, and the resource tracker printed "leaked semaphore objects" over the shell. Killing
    the Dask workers at quit raced Dask's own reaction to their deaths ("No such file", 1 run in
    about 25 under load): they end on their own once stw is gone, and so must every process it
    started (Dask's workers, the solver process, the fork server, the resource tracker)."""
    psutil = pytest.importorskip("psutil")    # Dask's own dependency
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    base = start(name, f"sh -c '{STW} sessions/particle_jet.stw; echo EXITED $?; sleep 60'")
    try:
        assert "end of particle_jet.stw" in wait_for(base, name, "end of particle_jet.stw")
        tmux(*base, "send-keys", "-t", name, "survey 4 seed=1", "Enter")
        screen = wait_for(base, name, "Esc closes", timeout=120)          # the gallery, with results
        assert "Esc closes" in screen, screen
        time.sleep(1.0)
        tmux(*base, "send-keys", "-t", name, "Escape")
        time.sleep(0.5)
        shell = int(tmux(*base, "display-message", "-p", "-t", name, "#{pane_pid}").strip())
        started = {p.pid for p in psutil.Process(shell).children(recursive=True)}
        assert len(started) >= 4, started   # stw, its Dask workers, the resource tracker, ...
        tmux(*base, "send-keys", "-t", name, "C-q")
        screen = wait_for(base, name, "EXITED")
        assert "EXITED 0" in screen, screen
        deadline = time.monotonic() + 15
        while any(running(pid) for pid in started) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not [pid for pid in started if running(pid)], "processes left behind after quitting"
        screen = tmux(*base, "capture-pane", "-p", "-t", name)   # the tracker writes as it ends
        assert "leaked" not in screen and "Warning" not in screen, screen
    finally:
        tmux(*base, "kill-server")


def test_resizing_below_80x24_asks_for_80x24_and_resizing_back_restores_the_layout():
    """Issue 52 items 3 and 2, in a real terminal: below 80x24 a screen asks for 80x24 (the
    panels' tabs used to vanish at 60x20); at 80x24 again the layout is back, still working, and
    the status line shows the scene's dense violation. (Runs this checkout's code: PYTHONPATH.)"""
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    base = start(name, f"env PYTHONPATH={ROOT} {STW} sessions/particle_jet.stw")
    try:
        screen = wait_for(base, name, "end of particle_jet.stw")
        assert "end of particle_jet.stw" in screen and "dense " in screen, screen
        tmux(*base, "resize-window", "-t", name, "-x", "60", "-y", "20")
        screen = wait_for(base, name, "make it at least")
        assert "make it at least" in screen and "60" in screen, screen
        assert "stw>" not in screen and "Eqns" not in screen, screen
        tmux(*base, "resize-window", "-t", name, "-x", "79", "-y", "30")   # one column short
        screen = wait_for(base, name, "79")
        assert "make it at least" in screen and "79" in screen, screen
        tmux(*base, "resize-window", "-t", name, "-x", "80", "-y", "24")
        # The layout is repainted over several frames (CI once captured the tabs drawn and the
        # rest still blank): wait, up to 30 s, for the whole screen rather than the first change.
        visible = ("stw>", "DOF", "Eqns", "Opt", "f5 Iterate", "dense ")
        deadline = time.monotonic() + 30
        screen = tmux(*base, "capture-pane", "-p", "-t", name)
        while ("make it at least" in screen or not all(v in screen for v in visible)) \
                and time.monotonic() < deadline:
            time.sleep(0.1)
            screen = tmux(*base, "capture-pane", "-p", "-t", name)
        lines = screen.splitlines()
        assert "make it at least" not in screen and len(lines) == 24, screen
        assert max(len(line) for line in lines) <= 80, screen
        for text in visible:
            assert text in screen, (text, screen)
        tmux(*base, "send-keys", "-t", name, "print x @ 0.5", "Enter")   # the console still answers
        screen = wait_for(base, name, "x @ 0.5 = ")
        assert "x @ 0.5 = " in screen, screen
    finally:
        tmux(*base, "kill-server")


def test_the_new_window_dialog_shows_its_bracketed_title_literally_and_the_app_lives_on(tmp_path):
    """Issue 52's crash: on the Win panel, `n` opened a dialog whose title
    `New window: NAME [dofs=a,b|all] [[A, B]]` was read as Textual markup (MarkupError, the app
    gone and ~420 lines of traceback over the shell). In a real terminal: it shows literally,
    Esc closes it, the app still answers and its journal holds what was replayed."""
    state = tmp_path / "state"
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    base = start(name, f"env PYTHONPATH={ROOT} XDG_STATE_HOME={state} {STW} sessions/particle_jet.stw")
    try:
        assert "end of particle_jet.stw" in wait_for(base, name, "end of particle_jet.stw")
        for _ in range(4):                                   # the panels, then Eqns, Const, Win
            tmux(*base, "send-keys", "-t", name, "F2")
            time.sleep(0.3)
        assert "window DOF interval" in wait_for(base, name, "window DOF interval"), "not on the Win panel"
        tmux(*base, "send-keys", "-t", name, "n")
        screen = wait_for(base, name, "New window: ")        # (the key hints say "n New window")
        assert "New window: NAME [dofs=a,b|all] [[A, B]]" in screen, screen
        assert "Traceback" not in screen and "MarkupError" not in screen, screen
        tmux(*base, "send-keys", "-t", name, "Escape")
        time.sleep(0.5)
        tmux(*base, "send-keys", "-t", name, "Escape")       # back to the console
        time.sleep(0.3)
        tmux(*base, "send-keys", "-t", name, "print x @ 0.5", "Enter")
        screen = wait_for(base, name, "x @ 0.5 = ")
        assert "x @ 0.5 = " in screen and "New window: " not in screen, screen
    finally:
        tmux(*base, "kill-server")
    journals = list((state / "stw").glob("particle_jet-*.stw"))
    assert len(journals) == 1, journals
    text = journals[0].read_text(encoding="utf-8")
    assert "iterate 20" in text and "print x @ 0.5" in text, text


def test_commands_typed_during_a_replay_wait_for_its_end_and_a_query_answers_after_the_solve(tmp_path):
    """Issue 52 item 4 in a real terminal: while a session file replays (here: its solve runs,
    never converging), a typed command that changes the scene waits for the file's end and a
    query answers when the solve ends; F4 stops the solve and halts the replay, F7 runs the rest
    of the file (its own check sees the file's scene), then the typed command."""
    jet = (ROOT / "sessions" / "particle_jet.stw").read_text().split("iterate")[0]
    script = tmp_path / "typed.stw"
    script.write_text(jet + "const k = 1\n" + ENDLESS + "iterate 1000000\nprint k @ 0\n", encoding="utf-8")
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    base = start(name, f"env PYTHONPATH={ROOT} {STW} {script}")
    try:
        assert "solving" in wait_for(base, name, "solving"), "the file's solve did not start"
        tmux(*base, "send-keys", "-t", name, "const k = 5", "Enter")
        assert "queued until the replay ends: const k = 5" in wait_for(base, name, "queued until the replay")
        tmux(*base, "send-keys", "-t", name, "print x @ 0.5", "Enter")
        screen = wait_for(base, name, "answers when the running solve ends")
        assert "answers when the running solve ends: print x @ 0.5" in screen, screen
        assert "x @ 0.5 = " not in screen, screen
        tmux(*base, "send-keys", "-t", name, "F4")
        screen = wait_for(base, name, "x @ 0.5 = ")
        joined = " ".join(screen.split())
        assert "replay halted" in joined and "x @ 0.5 = " in screen, screen
        assert "k @ 0 = " not in screen, screen               # the file's rest waits for F7
        tmux(*base, "send-keys", "-t", name, "F7")
        screen = wait_for(base, name, "running the 1 command(s) typed")
        joined = " ".join(screen.split())
        assert "k @ 0 = 1" in joined, screen                  # the file's check: its own k
        assert joined.index("end of typed.stw") < joined.index("running the 1 command(s) typed"), screen
        tmux(*base, "send-keys", "-t", name, "print k @ 0", "Enter")
        screen = wait_for(base, name, "k @ 0 = 5")
        assert "k @ 0 = 5" in screen, screen                  # the typed const ran after the file
    finally:
        tmux(*base, "kill-server")
