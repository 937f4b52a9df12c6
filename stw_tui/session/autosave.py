"""Autosave and resume: every TUI session journals to a per-user state directory, converged solves
checkpoint what they changed next to the journal, and `stw --resume [FILE]` rebuilds the scene
without solving again.

- The state directory is ``$XDG_STATE_HOME/stw`` (``platformdirs``' user state directory where
  XDG is not set). A session's journal there is named after its session file and start time.
- The journal is written line by line, flushed and fsynced before a command is acknowledged
  (:meth:`stw_tui.session.session.Journal.settle`), so a killed process loses no acknowledged command.
- After a converged solve, :class:`Checkpoints` appends one JSON line to ``JOURNAL.ckpt``: the
  journal's size once the solve's line was on disk, and everything a solve changes: the control
  points, the instances adaptive refinement added, the windows (`slide` moves one), and the
  solver's warm start (stw_tui/session/checkpoint_record.py: ``repr`` precision, read back bit
  for bit). A running solve is checkpointed every few seconds too, in a file of its own
  (stw_tui/session/midsolve.py).
- :func:`stw_tui.session.resume.resume` replays the journal line by line through the session, as `stw SESSION` would,
  except that a solve line with a checkpoint at its end is not solved: the checkpoint's state is
  put in its place (a history step, so `undo` still takes it back). Solves without one (stopped,
  not converged, or killed before their checkpoint was written) are solved again; a solve killed
  while it ran resumes from its last running checkpoint, as if stopped there. ``resolve=True``
  ignores the checkpoints and solves everything.

A checkpoint holds only numbers, names and flags (JSON), never code; one that does not fit the
replayed scene (other DOF, other sizes) is refused, and that solve runs instead.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

from stw_tui.session.checkpoint_record import VERSION, install, restored_scene, scene_record
from stw_tui.session.midsolve import MidSolve

if TYPE_CHECKING:
    from stw_tui.session.session import Session

SOLVE_COMMANDS = frozenset({"iterate", "slide"})
SUFFIX = ".ckpt"


def checkpoint_path(journal: Path) -> Path:
    """The checkpoint file beside ``journal`` (``JOURNAL.ckpt``)."""
    return journal.with_name(journal.name + SUFFIX)


def snapshot_record(session: "Session", offset: int) -> dict:
    """What a converged solve changed, and where in the journal it ended."""
    return scene_record(session.scene, session.warm, offset)


def apply_record(session: "Session", record: dict, text: str):
    """Put a checkpoint's state in place of solving ``text`` (a history step, like the solve).

    Returns:
        The journal entry of ``text`` (in memory: the line is in the journal file already).
    Raises:
        StwError: the checkpoint does not fit the scene (other DOF or control point counts).
    """
    scene = restored_scene(session, record)
    entry = session.journal.append(text, None)
    entry.ok = True
    install(session, scene, record, text)
    return entry


class Checkpoints:
    """The checkpoint file of one journal: one JSON line per converged solve, appended and fsynced."""

    def __init__(self, journal: Path):
        self.path = checkpoint_path(journal)
        self.journal = journal
        self.midsolve = MidSolve(journal)   # the running solve's, every few seconds (midsolve.py)

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


def kept_note(journal: Path) -> str:
    """What quitting says: where the session is kept, and how to reopen it."""
    return f"stw: this session is kept in {journal}; `stw --resume {journal}` reopens it"
