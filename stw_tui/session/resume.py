"""`stw --resume`: a session rebuilt from its journal, with the checkpoints of :mod:`.autosave` put
in place of the solves they recorded. Above the session (it builds one), so nothing in the
session imports it."""

from __future__ import annotations

import os
import time
from pathlib import Path

from stw_tui.session.autosave import SOLVE_COMMANDS, Checkpoints, apply_record
from stw_tui.session.checkpoint_record import install, restored_scene
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError
from stw_tui.sym.language import classify_line


def resume(journal: str | Path, *, resolve: bool = False, on_line=None,
           on_note=None) -> tuple["Session", int, int]:
    """A session rebuilt from ``journal``, which it goes on appending to. A solve that was running
    when the process died is brought back from its last running checkpoint (midsolve.py), and
    ``on_note`` is called with a sentence saying so. A last line without its newline (never
    acknowledged) is dropped and cut off the file, and a line that is not UTF-8 is skipped; each
    with a note saying what was dropped.

    Returns:
        (session, solves restored from checkpoints, solves run again).
    Raises:
        SourceError, StwError: a line of the journal fails on replay (the session stops there).
    """
    journal = Path(journal).expanduser()
    try:
        data = journal.read_bytes()
    except OSError as exc:
        raise StwError(f"cannot read journal {journal}: {exc}") from exc
    records = {} if resolve else Checkpoints(journal).load()
    session = Session()           # no journal file while replaying: the lines are there already
    restored = solved = 0
    offset = 0
    *lines, torn = data.split(b"\n")
    for number, raw in enumerate(lines, start=1):
        offset += len(raw) + 1
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:   # not a line stw wrote: a damaged file, or an old torn one
            _note(on_note, f"journal line {number} is not valid UTF-8 ({exc.reason} at byte {exc.start}); "
                           f"dropped: {raw[:80]!r}")
            continue
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
    if torn:   # no newline: never acknowledged (a kill or a full disk while it was written)
        _note(on_note, f"journal line {len(lines) + 1} was cut off before its end and never acknowledged; "
                       f"dropped: {torn[:80]!r}")
        try:   # cut it off, or the next line journalled would be appended to it
            os.truncate(journal, offset)
        except OSError as exc:
            raise StwError(f"cannot cut the unfinished last line off journal {journal}: {exc}") from exc
    session.journal.path = journal
    session.checkpoints = Checkpoints(journal)
    note = restore(session, journal, offset, resolve)
    if note is not None and on_note is not None:
        on_note(note)
    return session, restored, solved


def _note(on_note, text: str) -> None:
    if on_note is not None:
        on_note(text)


def restore(session: Session, journal: Path, size: int, resolve: bool) -> str | None:
    """After a resume replayed ``journal`` (``size`` bytes): bring back the solve that was running
    when the process died, if its checkpoint starts at the journal's end.

    Returns:
        What was restored, in a sentence (None: nothing to restore).
    """
    midsolve = session.checkpoints.midsolve   # resume() set them up for this journal
    record = midsolve.load()
    if record is None or record.get("offset") != size or session.in_block:
        return None
    when = time.strftime("%H:%M:%S", time.localtime(record.get("time", 0)))
    what = f"`{record.get('command', 'iterate')}` at iteration {record.get('iteration')} (checkpoint of {when})"
    if resolve:
        for line in record["text"].splitlines():
            session.execute(line)
        midsolve.ended(force=True)
        return f"solved again up to the running solve's last checkpoint: {what}"
    try:
        scene = restored_scene(session, record)
    except (StwError, KeyError, TypeError, ValueError):
        return f"the running solve's checkpoint does not fit the journal; not restored: {what}"
    entry = session.journal.append(record["text"], None)
    session.journal.settle(entry, True)      # on disk first (raises StwError when it cannot be)
    install(session, scene, record, record["text"])
    if session.checkpoints is not None:
        session.checkpoints.record(session)  # a later resume restores it like any finished solve
    midsolve.ended(force=True)
    last = record["text"].splitlines()[-1]
    return f"resumed from the running solve's last checkpoint: {what}; journalled as `{last}`"
