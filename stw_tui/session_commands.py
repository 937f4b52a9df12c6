"""Handlers of the commands that act on the session rather than only on its scene: history
and snapshots (:mod:`.history`) and files (:mod:`.export`). Each takes the session, the scene
copy the command works on, and the parsed command, and returns an Outcome."""

from __future__ import annotations

from . import autosave, export, history, preview, show, survey_session
from .language import session_commands as cmds

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
    cmds.JournalCmd: autosave.journal_info,
    cmds.AcceptCmd: preview.accept,
    cmds.RejectCmd: preview.reject,
}
