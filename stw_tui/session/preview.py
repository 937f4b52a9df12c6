"""Preview, then accept: with `set preview on`, a solve's result is a proposal. The scene stays as
it was; `accept` makes the proposal the scene (a step that `undo` takes back), `reject` drops it.

The solve line is journalled as it ran, and so are `accept` and `reject`: a replayed journal makes
the same proposal and the same decision. A new solve replaces a pending proposal, and proposes
from the scene, not from the proposal.
"""

from __future__ import annotations

from stw_tui.session.history import State, become
from stw_tui.session.outcome import Outcome
from stw_tui.session.protocol import SessionLike
from stw_tui.sos.scene import Scene
from stw_tui.sym.errors import StwError


def comparison(session: SessionLike) -> str:
    """Objective and violations of the proposal and of the scene over the whole animation, one
    line each (a window's solve reports the window's own objective: the terms its free control
    points change, over the times they reach; these are the numbers to compare)."""
    from stw_tui.session.snapshots import measure

    return ("over the whole animation, proposed and as it is now:\n"
            f"  proposal: {measure(session.proposal.scene).describe()}\n"
            f"  now:      {measure(session.scene).describe()}")


def propose(session: SessionLike, scene: Scene, before: State, outcome: Outcome, text: str) -> Outcome:
    """Keep a solve's result as the proposal (with its warm start), leaving the scene and the
    warm start as they were before the solve. ``text`` is the solve's line: with `accept` after
    it, it makes the lines that rebuild the proposal as the scene."""
    lines = (*session.history.lines, outcome.journal_text or text, "accept")
    session.proposal = State(scene, session.warm, lines)
    session.warm = before.warm
    outcome.dense = None   # the proposal's check, not the scene's
    outcome.message = (f"{outcome.message}\npreview: the scene is unchanged; `accept` takes the result, "
                       f"`reject` drops it\n{comparison(session)}")
    return outcome


def _pending(session: SessionLike, verb: str) -> State:
    if session.proposal is None:
        raise StwError(f"nothing to {verb}: with `set preview on`, a solve proposes its result")
    return session.proposal


def accept(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`accept`: the proposal becomes the scene (a step)."""
    proposal = _pending(session, "accept")
    become(session, scene, proposal)
    session.proposal = None
    return Outcome(message="accepted the proposed motion (`undo` takes it back)", lines=proposal.lines)


def reject(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`reject`: drop the proposal (not a step: the scene does not change)."""
    _pending(session, "reject")
    session.proposal = None
    return Outcome(message="rejected the proposed motion; the scene is unchanged")
