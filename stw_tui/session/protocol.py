"""What a command handler may use of the session it acts on.

:class:`~stw_tui.session.session.Session` dispatches every command to a handler (the interpreter,
history, export, show, preview, survey). Handlers sit below the session, so they name it through
this protocol instead of importing it: the imports run one way, session -> handlers.
"""

from __future__ import annotations

from typing import Any, Protocol

from stw_tui.sos.scene import Scene


class SessionLike(Protocol):
    """The state a session keeps between commands (see ``Session`` for what each holds)."""

    scene: Scene          # the scene every command reads and (on a copy) changes
    warm: Any             # the solver's warm start (backend.WarmStart) or None
    history: Any          # undo/redo and named snapshots (history.History)
    journal: Any          # the lines applied so far (session.Journal)
    proposal: Any         # a solve's result awaiting accept/reject (history.State) or None
    runs: list            # RunResult of each solve, in order
    checkpoints: Any      # autosave.Checkpoints of an autosaved session, else None
    survey: Any           # the last survey's table (survey.SurveyTable), for `adopt`
    trusted_schedulers: set   # cluster addresses the user named outside the session file
