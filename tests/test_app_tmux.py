"""The real `stw` command in a real terminal (tmux): it starts, replays, draws, quits on Ctrl+Q."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
STW = Path(sys.executable).parent / "stw"

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None or not STW.exists(),
                                reason="needs tmux and the installed `stw` script")


def tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], capture_output=True, text=True, check=False).stdout




def test_stw_runs_in_tmux_replays_a_session_and_quits():
    name = f"stw-test-{uuid.uuid4().hex[:8]}"
    # A private socket (-L) keeps the test off the user's tmux server.
    base = ["-L", name]
    subprocess.run(["tmux", *base, "new-session", "-d", "-s", name, "-x", "100", "-y", "30",
                    # COLUMNS/LINES set by a test runner would override the real pane size.
                    f"env -u COLUMNS -u LINES {STW} sessions/particle_jet.stw"], cwd=ROOT, check=True)
    try:
        def capture() -> str:
            return tmux(*base, "capture-pane", "-p", "-t", name)

        deadline = time.monotonic() + 30
        screen = capture()
        while "end of particle_jet.stw" not in screen and time.monotonic() < deadline:
            time.sleep(0.2)
            screen = capture()
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
