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
  solver's warm start. Numbers are written with ``repr`` precision, so they read back bit for bit.
- :func:`stw_tui.session.resume.resume` replays the journal line by line through the session, as `stw SESSION` would,
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
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stw_tui.session.history import State
from stw_tui.sos.scene import Window
from stw_tui.sym.errors import StwError

if TYPE_CHECKING:
    from stw_tui.session.session import Session

SOLVE_COMMANDS = frozenset({"iterate", "slide"})
SUFFIX = ".ckpt"
VERSION = 1


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
    from stw_tui.session.interpreter import WarmStart
    from stw_tui.sos.backend import SolverState

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


def kept_note(journal: Path) -> str:
    """What quitting says: where the session is kept, and how to reopen it."""
    return f"stw: this session is kept in {journal}; `stw --resume {journal}` reopens it"
