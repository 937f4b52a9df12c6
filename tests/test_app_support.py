"""Shared helpers of the TUI tests (no tests here): waiting for the session worker, typing at the console."""

from __future__ import annotations

import time
from pathlib import Path

SESSIONS = Path(__file__).resolve().parent.parent / "sessions"


async def settle(pilot, timeout: float = 30.0) -> None:
    """Wait until every queued command (and a replaying session) has run and been shown."""
    app = pilot.app
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        await pilot.pause(0.02)
        if app.settled:
            await pilot.pause()
            return
    raise AssertionError(f"the app did not settle in {timeout} s (running: {app.runner.current})")


async def submit(pilot, line: str) -> None:
    """Type a whole line at the console prompt and press Enter."""
    field = pilot.app.repl.input
    field.focus()
    field.value = line
    field.cursor_position = len(line)
    await pilot.press("enter")


def log_text(app) -> str:
    """Everything the console log shows, as plain text."""
    return "\n".join(line.text for line in app.repl.log_widget.lines)


async def until(pilot, condition, what: str, timeout: float = 10.0) -> None:
    """Wait until `condition()` holds: timers and workers run late on a loaded machine, so poll
    rather than pause a fixed time, and fail with `what` when the deadline passes."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"not {what} within {timeout} s")
        await pilot.pause(0.02)
