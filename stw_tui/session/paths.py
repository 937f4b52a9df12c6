"""Where autosaved sessions live: the per-user state directory and the journals in it."""

from __future__ import annotations

import os
import time
from pathlib import Path


def state_dir() -> Path:
    """Where autosaved journals go: ``$XDG_STATE_HOME/stw``, else the platform's user state dir."""
    xdg = os.environ.get("XDG_STATE_HOME")
    if xdg:
        return Path(xdg) / "stw"
    try:
        import platformdirs
    except ImportError:
        return Path.home() / ".local" / "state" / "stw"
    return Path(platformdirs.user_state_dir("stw"))


def new_journal_path(session_file: str | Path | None = None, now: float | None = None) -> Path:
    """A fresh journal in the state directory, named after the session file and the time
    (``arm_throw-20261130-174501.stw``; ``-2``, ``-3``… when taken). Creates the directory (0700)."""
    folder = state_dir()
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    stem = Path(session_file).stem if session_file else "session"
    base = f"{stem}-{time.strftime('%Y%m%d-%H%M%S', time.localtime(now))}"
    path, k = folder / f"{base}.stw", 2
    while path.exists():
        path, k = folder / f"{base}-{k}.stw", k + 1
    return path


def latest_journal() -> Path | None:
    """The most recently written journal in the state directory (None: there is none)."""
    folder = state_dir()
    journals = [p for p in folder.glob("*.stw") if p.is_file()] if folder.is_dir() else []
    return max(journals, key=lambda p: p.stat().st_mtime_ns, default=None)
