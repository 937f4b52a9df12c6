"""Handlers of the commands that act on the session rather than only on its scene: history
and snapshots (:mod:`.history`) and files (:mod:`.export`). Each takes the session, the scene
copy the command works on, and the parsed command, and returns an Outcome."""

from __future__ import annotations

from stw_tui.session import export, history, preview
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


# `survey`, `adopt` and `show` load their modules when first used: the survey engines pull in
# multiprocessing and concurrent.futures, `show` the linkage printer (~20-35 ms of every start
# of a session that never uses them).
def _survey(session, scene, cmd, on_report):
    from stw_tui.session import survey_session
    return survey_session.survey(session, scene, cmd, on_report)


def _adopt(session, scene, cmd, on_report):
    from stw_tui.session import survey_session
    return survey_session.adopt(session, scene, cmd, on_report)


def _set_scheduler(session, scene, cmd):
    from stw_tui.session import survey_session
    return survey_session.set_scheduler(session, scene, cmd)


def _show(session, scene, cmd):
    from stw_tui.session import show
    return show.show(session, scene, cmd)


def _cse(session, scene, cmd):
    from stw_tui.session import show
    return show.cse(session, scene, cmd)


_survey.reports_progress = _adopt.reports_progress = True   # as survey_session's own


SESSION_HANDLERS = {
    cmds.UndoCmd: history.undo,
    cmds.RedoCmd: history.redo,
    cmds.SnapshotCmd: history.snapshot,
    cmds.RestoreCmd: history.restore,
    cmds.SnapshotsCmd: history.list_snapshots,
    cmds.DiffCmd: history.diff,
    cmds.ExportCmd: export.export,
    cmds.SaveCmd: export.save,
    cmds.SurveyCmd: _survey,
    cmds.AdoptCmd: _adopt,
    cmds.SchedulerCmd: _set_scheduler,
    cmds.ShowCmd: _show,
    cmds.CseCmd: _cse,
    cmds.JournalCmd: journal_info,
    cmds.AcceptCmd: preview.accept,
    cmds.RejectCmd: preview.reject,
}
