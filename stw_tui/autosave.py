"""Autosave and resume: every TUI session journals to a per-user state directory, converged solves
checkpoint what they changed next to the journal, and `stw --resume [FILE]` rebuilds the scene
without solving again.

- The state directory is ``$XDG_STATE_HOME/stw`` (``platformdirs``' user state directory where
  XDG is not set). A session's journal there is named after its session file and start time.
- The journal is written line by line, flushed and fsynced before a command is acknowledged
  (:meth:`stw_tui.session.Journal.settle`), so a killed process loses no acknowledged command.
- After a converged solve, :class:`Checkpoints` appends one JSON line to ``JOURNAL.ckpt``: the
  journal's size once the solve's line was on disk, and everything a solve changes: the control
  points, the instances adaptive refinement added, the windows (`slide` moves one), and the
  solver's warm start. Numbers are written with ``repr`` precision, so they read back bit for bit.
- :func:`resume` replays the journal line by line through the session, as `stw SESSION` would,
  except that a solve line with a checkpoint at its end is not solved: the checkpoint's state is
  put in its place (a history step, so `undo` still takes it back). Solves without one (stopped,
  not converged, or killed before their checkpoint was written) are solved again. ``resolve=True``
  ignores the checkpoints and solves everything.

A checkpoint holds only numbers, names and flags (JSON), never code; one that does not fit the
replayed scene (other DOF, other sizes) is refused, and that solve runs instead.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import StwError
from .history import State
from .language import classify_line
from .scene import Window

if TYPE_CHECKING:
    from .session import Session

SOLVE_COMMANDS = frozenset({"iterate", "slide"})
SUFFIX = ".ckpt"
VERSION = 1


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


def checkpoint_path(journal: Path) -> Path:
    return journal.with_name(journal.name + SUFFIX)


# --- what a checkpoint holds ------------------------------------------------------------------
def _plain(value):
    """JSON-ready form of numpy arrays and numbers, tuples as lists."""
    if isinstance(value, np.ndarray):
        return {"array": value.tolist(), "dtype": str(value.dtype)}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _restored(value):
    """Inverse of :func:`_plain` (lists back to tuples, for the warm start's signature)."""
    if isinstance(value, dict) and set(value) == {"array", "dtype"}:
        return np.array(value["array"], dtype=value["dtype"])
    if isinstance(value, list):
        return tuple(_restored(v) for v in value)
    return value


def _warm_record(warm) -> dict | None:
    if warm is None:
        return None
    state = {f.name: _plain(getattr(warm.state, f.name)) for f in fields(warm.state)}
    return {"signature": _plain(warm.signature), "state": state}


def _warm_from(record):
    if record is None:
        return None
    from .backend import SolverState
    from .interpreter import WarmStart

    state = {name: _restored(value) for name, value in record["state"].items()}
    return WarmStart(_restored(record["signature"]), SolverState(**state))


def snapshot_record(session: "Session", offset: int) -> dict:
    """What a converged solve changed, and where in the journal it ended."""
    scene = session.scene
    return {
        "version": VERSION, "offset": offset,
        "coef": {name: dof.curve.coef.tolist() for name, dof in scene.dofs.items()},
        "extra_instances": {k: list(v) for k, v in scene.extra_instances.items()},
        "windows": {k: [list(w.dofs) if w.dofs else None, list(w.interval) if w.interval else None]
                    for k, w in scene.windows.items()},
        "active_window": scene.active_window,
        "warm": _warm_record(session.warm),
    }


def apply_record(session: "Session", record: dict, text: str) -> None:
    """Put a checkpoint's state in place of solving ``text`` (a history step, like the solve).

    Raises:
        StwError: the checkpoint does not fit the scene (other DOF or control point counts).
    """
    scene = session.scene.copy()
    coef = record["coef"]
    if list(coef) != list(scene.dofs) or any(len(coef[n]) != d.curve.n_coef for n, d in scene.dofs.items()):
        raise StwError("the checkpoint does not fit the replayed scene")
    for name, dof in scene.dofs.items():
        dof.curve = dof.curve.with_coef(np.array(coef[name], dtype=float))
    scene.extra_instances = {k: tuple(float(t) for t in v) for k, v in record["extra_instances"].items()}
    scene.windows = {k: Window(k, tuple(d) if d else None, tuple(i) if i else None)
                     for k, (d, i) in record["windows"].items()}
    scene.active_window = record["active_window"]
    before = State.of(session)
    entry = session.journal.append(text, None)
    entry.ok = True
    session.scene, session.warm = scene, _warm_from(record["warm"])
    session.history.settled(text, before)


class Checkpoints:
    """The checkpoint file of one journal: one JSON line per converged solve, appended and fsynced."""

    def __init__(self, journal: Path):
        self.path = checkpoint_path(journal)
        self.journal = journal

    def record(self, session: "Session") -> None:
        """Called after a converged solve's journal line is on disk. A failure to write it costs
        only a re-solve on resume, so it is not an error of the command."""
        try:
            offset = self.journal.stat().st_size
            line = json.dumps(snapshot_record(session, offset), allow_nan=False)
            with self.path.open("a", encoding="utf-8") as out:
                out.write(line + "\n")
                out.flush()
                os.fsync(out.fileno())
        except (OSError, ValueError):
            pass

    def load(self) -> dict[int, dict]:
        """Records by journal offset; a damaged last line (a kill while writing it) is skipped."""
        records = {}
        try:
            lines = self.path.read_text(encoding="utf-8").splitlines()
        except OSError:
            return records
        for line in lines:
            try:
                record = json.loads(line)
            except ValueError:
                continue
            if isinstance(record, dict) and record.get("version") == VERSION:
                records[int(record["offset"])] = record
        return records


def resume(journal: str | Path, *, resolve: bool = False, on_line=None) -> tuple["Session", int, int]:
    """A session rebuilt from ``journal``, which it goes on appending to.

    Returns:
        (session, solves restored from checkpoints, solves run again).
    Raises:
        SourceError, StwError: a line of the journal fails on replay (the session stops there).
    """
    from .session import Session

    journal = Path(journal).expanduser()
    try:
        data = journal.read_bytes()
    except OSError as exc:
        raise StwError(f"cannot read journal {journal}: {exc}") from exc
    records = {} if resolve else Checkpoints(journal).load()
    session = Session()           # no journal file while replaying: the lines are there already
    restored = solved = 0
    offset = 0
    for number, raw in enumerate(data.split(b"\n"), start=1):
        offset += len(raw) + 1
        text = raw.decode("utf-8")
        verb = classify_line(text).verb if not session.in_block else None
        record = records.get(offset) if verb in SOLVE_COMMANDS else None
        if record is not None:
            try:
                apply_record(session, record, text.rstrip())
                restored += 1
                continue
            except StwError:
                pass                  # does not fit: solve it again
        outcome = session.execute(text, line=number)
        solved += verb in SOLVE_COMMANDS
        if on_line is not None:
            on_line(number, text, outcome)
    session.journal.path = journal
    session.checkpoints = Checkpoints(journal)
    return session, restored, solved


def journal_info(session: "Session", scene, cmd):
    """`journal`: the journal file, its checkpoints, and the state directory. Not a step."""
    from .outcome import Outcome

    path = session.journal.path
    lines = [f"journal: {path}" if path else "journal: none (this session is not written to a file)"]
    if session.checkpoints is not None:
        lines.append(f"checkpoints: {session.checkpoints.path}")
    lines.append(f"autosaved sessions: {state_dir()} (`stw --resume` reopens the last)")
    return Outcome(message="\n".join(lines), journal_text=f"# {cmd.text or 'journal'}")


def kept_note(journal: Path) -> str:
    """What quitting says: where the session is kept, and how to reopen it."""
    return f"stw: this session is kept in {journal}; `stw --resume {journal}` reopens it"
