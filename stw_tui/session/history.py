"""Undo, redo and named snapshots of a session's scene.

A command never changes the scene it is given: :meth:`Session._apply` applies it to a copy that
replaces the scene when it succeeds. So the scene a command started from is a finished value
that nothing changes afterwards, and keeping it costs one reference (its curves and sympy
expressions are shared with the scenes after it). History keeps those scenes, with the solver's
warm start (the multipliers the next `iterate` starts from), so that after `undo` the scene and the
next solve are exactly what they would have been without the undone command.

`undo` and `redo` are commands like the others: they are journalled, and replaying the journal
undoes the same steps. A step is one command that succeeded and may change the scene; commands
that only read it (`print`, `show`, `cse`, `help`, `snapshots`, `diff`, `export`, `save`) and `snapshot` are not
steps, and neither is a command that failed.

Each state also keeps the clean session that rebuilds it (``lines``, what `save` writes): the
steps that led to it, in order. A step adds its line to the lines before it; `undo`, `redo`,
`restore` and `accept` return to a kept state, and with it to that state's lines, adding none of
their own. So an undone line, the `undo` itself, a failed line and a read-only one are never in it.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

from stw_tui.session.outcome import Outcome
from stw_tui.session.protocol import SessionLike
from stw_tui.sos.scene import Scene
from stw_tui.sym.errors import StwError
from stw_tui.sym.language import QUERIES, WRITERS, classify_line


HISTORY_LIMIT = 200
# First words of commands that are no step of the history: they never change the scene, or
# manage the history themselves.
NOT_STEPS = QUERIES | WRITERS | {"undo", "redo", "snapshot", "reject"}


@dataclass(frozen=True)
class State:
    """A scene and the warm start of the solve that produced it. Neither is changed once kept."""

    scene: Scene
    warm: Any = None     # backend.WarmStart | None
    lines: tuple[str, ...] = ()   # the clean session that rebuilds it (History.lines)

    @classmethod
    def of(cls, session: SessionLike) -> "State":
        """The session's state, kept apart from it: the warm start is copied, because a backend
        may reuse its arrays."""
        return cls(session.scene, copy.deepcopy(session.warm), session.history.lines)


@dataclass(frozen=True)
class Step:
    """A command, and the state that undoing (or redoing) it returns to."""

    text: str
    state: State


@dataclass
class History:
    """Bounded undo and redo stacks, and named snapshots."""

    limit: int = HISTORY_LIMIT
    undo_steps: list[Step] = field(default_factory=list)
    redo_steps: list[Step] = field(default_factory=list)
    snapshots: dict[str, State] = field(default_factory=dict)
    # The clean session: the lines that rebuild the scene now, in order (a multi-line block is one)
    lines: tuple[str, ...] = ()
    _measures: dict = field(default_factory=dict, repr=False)   # name -> (scene, its Measures)

    def settled(self, text: str, before: State, journal_text: str | None = None,
                lines: tuple[str, ...] | None = None) -> None:
        """A command succeeded (called by the session after it replaced the scene).

        Args:
            text: the command as typed; its first word says whether it is a step.
            before: the session's state before the command.
            journal_text: what the journal keeps instead of ``text``, if anything.
            lines: the clean session now, where the command returned to a kept state
                (``Outcome.lines``); None: a step adds its line to :attr:`lines`, another
                command leaves them.
        """
        if lines is not None:
            self.lines = lines
        verb = classify_line(text).verb
        if verb is None or verb in NOT_STEPS:
            return
        self.undo_steps.append(Step(journal_text or text, before))
        del self.undo_steps[:-self.limit]
        self.redo_steps.clear()
        if lines is None:
            self.lines = (*self.lines, journal_text or text)

    def saved(self) -> tuple:
        """The stacks and snapshots as they are now, for :meth:`put_back` (handlers such as `undo`
        and `snapshot` change them in place, before their journal line is written)."""
        return list(self.undo_steps), list(self.redo_steps), dict(self.snapshots)

    def put_back(self, saved: tuple) -> None:
        """Return to what :meth:`saved` kept: the command that changed them did not happen."""
        self.undo_steps[:], self.redo_steps[:] = saved[0], saved[1]
        self.snapshots.clear()
        self.snapshots.update(saved[2])

    def measured(self, name: str):
        """A snapshot's :class:`~stw_tui.session.snapshots.Measures`, computed once (its scene never changes)."""
        from stw_tui.session.snapshots import measure

        scene = self.snapshots[name].scene
        cached = self._measures.get(name)
        if cached is None or cached[0] is not scene:
            cached = self._measures[name] = (scene, measure(scene))
        return cached[1]

    @staticmethod
    def describe(text: str) -> str:
        """A command for messages: its first line in backquotes, with … if it spans more."""
        first = text.strip().splitlines()[0] if text.strip() else text
        return f"`{first}`" + (" …" if "\n" in text.strip() else "")


def become(session: SessionLike, scene: Scene, state: State) -> None:
    """Make the command's scene copy (and the session's warm start) the kept state, exactly.
    The kept scene is copied, so it stays unchanged for a later undo or redo."""
    vars(scene).clear()
    vars(scene).update(vars(state.scene.copy()))
    session.warm = copy.deepcopy(state.warm)


# --- handlers: (session, scene copy, command) -> Outcome -------------------------------------
def undo(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`undo`: return to the state before the last step, keeping the current one for `redo`."""

    history = session.history
    if not history.undo_steps:
        raise StwError("nothing to undo")
    step = history.undo_steps.pop()
    history.redo_steps.append(Step(step.text, State.of(session)))
    become(session, scene, step.state)
    left = len(history.undo_steps)
    return Outcome(message=f"undid {History.describe(step.text)} "
                           f"({left} more step{'s' if left != 1 else ''} to undo)", lines=step.state.lines)


def redo(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`redo`: return to the state the last `undo` took back."""

    history = session.history
    if not history.redo_steps:
        raise StwError("nothing to redo")
    step = history.redo_steps.pop()
    history.undo_steps.append(Step(step.text, State.of(session)))
    become(session, scene, step.state)
    return Outcome(message=f"redid {History.describe(step.text)}", lines=step.state.lines)


# --- named snapshots -------------------------------------------------------------------------
def _snapshot_state(session: SessionLike, name: str) -> State:
    history = session.history
    if name not in history.snapshots:
        known = ", ".join(history.snapshots) or "none yet; `snapshot NAME` keeps one"
        raise StwError(f"no snapshot named '{name}' (snapshots: {known})")
    return history.snapshots[name]


def snapshot(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """Keep the scene (not a step: the scene does not change)."""

    replaced = cmd.name in session.history.snapshots
    session.history.snapshots[cmd.name] = State.of(session)
    return Outcome(message=f"snapshot {cmd.name} {'replaced' if replaced else 'kept'}")


def restore(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """Make the scene a snapshot's (a step: `undo` takes it back)."""

    state = _snapshot_state(session, cmd.name)
    become(session, scene, state)
    # the snapshot's own lines: a saved session has no snapshot to restore
    return Outcome(message=f"restored snapshot {cmd.name}", lines=state.lines)


def list_snapshots(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`snapshots`: each snapshot's objective and violations, and the scene's now."""
    from stw_tui.session.snapshots import measure

    snaps = session.history.snapshots
    if not snaps:
        return Outcome(message="no snapshots; `snapshot NAME` keeps one")
    width = max(len(n) for n in [*snaps, "(now)"])
    lines = [f"{len(snaps)} snapshot(s):"]
    lines += [f"  {name:<{width}}  {session.history.measured(name).describe()}" for name in snaps]
    lines.append(f"  {'(now)':<{width}}  {measure(session.scene).describe()}")
    return Outcome(message="\n".join(lines))


def diff(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`diff NAME`: how the scene now differs from a snapshot."""
    from stw_tui.session.snapshots import describe_diff, diff_scenes, measure

    old = _snapshot_state(session, cmd.name).scene
    text = describe_diff(cmd.name, diff_scenes(old, session.scene), session.history.measured(cmd.name),
                         measure(session.scene))
    return Outcome(message=text)
