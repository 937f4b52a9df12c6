"""Handlers of the commands that act on the session rather than only on its scene: history
and snapshots (:mod:`.history`) and files (:mod:`.export`). Each takes the session, the scene
copy the command works on, and the parsed command, and returns an Outcome."""

from __future__ import annotations

from stw_tui.session import export, history, preview, show, survey_session
from stw_tui.session.outcome import Outcome
from stw_tui.session.paths import state_dir
from stw_tui.sym.language import session_commands as cmds


def journal_info(session, scene, cmd):
    """`journal`: the journal file, its checkpoints, and the state directory. Not a step."""
    path = session.journal.path
    lines = [f"journal: {path}" if path else "journal: none (this session is not written to a file)"]
    if session.checkpoints is not None:
        lines.append(f"checkpoints: {session.checkpoints.path}")
    lines.append(f"autosaved sessions: {state_dir()} (`stw --resume` reopens the last)")
    return Outcome(message="\n".join(lines), journal_text=f"# {cmd.text or 'journal'}")


SESSION_HANDLERS = {
    cmds.UndoCmd: history.undo,
    cmds.RedoCmd: history.redo,
    cmds.SnapshotCmd: history.snapshot,
    cmds.RestoreCmd: history.restore,
    cmds.SnapshotsCmd: history.list_snapshots,
    cmds.DiffCmd: history.diff,
    cmds.ExportCmd: export.export,
    cmds.SaveCmd: export.save,
    cmds.SurveyCmd: survey_session.survey,
    cmds.AdoptCmd: survey_session.adopt,
    cmds.SchedulerCmd: survey_session.set_scheduler,
    cmds.ShowCmd: show.show,
    cmds.CseCmd: show.cse,
    cmds.JournalCmd: journal_info,
    cmds.AcceptCmd: preview.accept,
    cmds.RejectCmd: preview.reject,
}
