"""Checkpoints of a running solve: a kill during a long `iterate` loses at most a few seconds.

While a journalled session solves, the iterate the backend has reached is written every
:data:`DEFAULT_EVERY` seconds (``$STW_CHECKPOINT_EVERY`` to change it) to ``JOURNAL.solving``,
which each write replaces atomically (temporary file, fsync, rename, fsync of the folder): a kill
leaves the previous checkpoint or the new one, never half of one. It holds numbers and names only
(JSON, stw_tui/session/checkpoint_record.py's, as a finished solve's), plus

- ``offset``: the journal's size when the solve began (its own line is journalled when it ends);
- ``text``: the lines that replay what the solve had kept at that iterate, as a stopped solve is
  journalled: ``iterate K adapt=0`` after the lines of the rounds (and `slide` positions) before it;
- ``command`` and ``iteration``: what was running, to say what was restored.

When the command ends (done, stopped or failed) its line is journalled and the file removed. A
solver process whose parent is gone (a killed or hung-up TUI) writes the iterate it has reached at
once (:meth:`MidSolve.keep_latest`) and ends without journalling. If the process dies first,
:func:`stw_tui.session.resume.restore` (called by its ``resume``) finds the file with the offset of
the journal's end, journals ``text`` and puts the checkpoint's state in place, as if the solve had
been stopped there. With `--resolve` the lines are solved again instead.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from stw_tui.session.atomic_file import replace_text
from stw_tui.session.checkpoint_record import VERSION, scene_record
from stw_tui.session.protocol import SessionLike
from stw_tui.session.throttle import Throttle

SUFFIX = ".solving"
EVERY_VARIABLE = "STW_CHECKPOINT_EVERY"
DEFAULT_EVERY = 3.0   # seconds between checkpoints of a running solve


def midsolve_path(journal: Path) -> Path:
    """Where ``journal``'s running-solve checkpoint lives: beside it, ``JOURNAL.solving``."""
    return journal.with_name(journal.name + SUFFIX)


def _every() -> float:
    """The period from ``$STW_CHECKPOINT_EVERY`` (seconds; 0: every iteration), else the default."""
    try:
        value = float(os.environ.get(EVERY_VARIABLE, DEFAULT_EVERY))
    except ValueError:
        return DEFAULT_EVERY
    return value if value >= 0 else DEFAULT_EVERY


@dataclass
class Trail:
    """The command a solve belongs to, and the lines that replay what it kept before this solve
    (the adaptive rounds and `slide` positions already done)."""

    command: str
    lines: list[str] = field(default_factory=list)

    def then(self, lines: list[str]) -> "Trail":
        """The trail of a later solve of the same command, after ``lines`` were kept too."""
        return Trail(self.command, self.lines + list(lines))


class MidSolve:
    """The running-solve checkpoint of one journal.

    Args:
        journal: the journal file.
        every: seconds between checkpoints (None: ``$STW_CHECKPOINT_EVERY`` or the default).
        clock: monotonic seconds (tests pass a fake one).
    """

    def __init__(self, journal: Path, every: float | None = None, clock: Callable[[], float] = time.monotonic):
        self.journal = journal
        self.path = midsolve_path(journal)
        self.every = _every() if every is None else every
        self.clock = clock
        self.written = False   # a checkpoint of the running command is on disk
        self._unwritten: Callable[[], None] | None = None   # writes the last iterate not yet on disk

    def __getstate__(self) -> dict:
        # the pending write is a closure over a running solve: it neither pickles nor belongs elsewhere
        return {**self.__dict__, "_unwritten": None}

    def hook(self, scene, problem, warm_of: Callable, trail: Trail) -> Callable:
        """The ``on_state`` of :func:`stw_tui.sos.backend.run_iterations` for one solve of ``problem``
        on ``scene`` (the command's working copy): it writes a checkpoint when one is due.
        ``warm_of(state)`` is the warm start the solve would leave at ``state``."""
        try:
            offset = self.journal.stat().st_size
        except OSError:
            offset = 0
        throttle = Throttle(self.every, self.clock)
        throttle.mark()   # the first checkpoint is due a period after the start

        def on_state(k: int, state) -> None:
            def write() -> None:
                self._unwritten = None
                now = scene.copy()
                now.with_coefficients(problem.scatter(state.s))
                self.write(now, warm_of(state), offset, trail, k)
            self._unwritten = write   # a closure only: copying the scene each iteration would cost
            if throttle.due():
                write()
        return on_state

    def keep_latest(self) -> None:
        """Write the last iterate the running solve reached, if the periodic checkpoint has not
        (the solver process's parent is gone: nothing more of this solve will be kept)."""
        if self._unwritten is not None:
            self._unwritten()

    def write(self, scene, warm, offset: int, trail: Trail, k: int) -> None:
        """Replace the checkpoint atomically. A failure costs only the checkpoint, not the solve."""
        record = scene_record(scene, warm, offset)
        record.update(command=trail.command, iteration=k, time=time.time(),
                      text="\n".join([*trail.lines, f"iterate {k} adapt=0"]))
        try:
            replace_text(self.path, json.dumps(record, allow_nan=False))
            self.written = True
        except (OSError, ValueError):
            pass

    def ended(self, force: bool = False) -> None:
        """The command is journalled: its running checkpoint is no longer needed (``force``: remove
        it even if this process did not write it)."""
        self._unwritten = None
        if self.written or force:
            self.written = False
            try:
                self.path.unlink(missing_ok=True)
            except OSError:
                pass

    def load(self) -> dict | None:
        """The checkpoint on disk (None: none, or unreadable)."""
        try:
            record = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        ok = isinstance(record, dict) and record.get("version") == VERSION and isinstance(record.get("text"), str)
        return record if ok else None


def hook_for(session: SessionLike, scene, problem, warm_of: Callable, trail: Trail | None):
    """The checkpointing ``on_state`` for a solve of ``session`` (None: it is not journalled to a
    file, or `set preview on` makes the solve a proposal, which a resume must not apply)."""
    checkpoints = getattr(session, "checkpoints", None)
    if checkpoints is None or trail is None or scene.settings.get("preview"):
        return None
    return checkpoints.midsolve.hook(scene, problem, warm_of, trail)
