"""What a command did, as the interpreter hands it back to the session (a module of its own, so
the interpreter and the session commands need not import the session that calls them)."""

from __future__ import annotations

from dataclasses import dataclass, field

from stw_tui.sos.backend import RunResult
from stw_tui.sos.continuous import DenseReport


@dataclass
class PrintResult:
    """What `print` showed: a value at time ``t``, or (``t`` None) a summary over an interval."""

    expr: str
    t: float | None
    value: float | dict


@dataclass
class Outcome:
    """What a command did: a message for the console, and any printed values or solver run."""

    message: str = ""
    prints: list[PrintResult] = field(default_factory=list)
    run: RunResult | None = None
    journal_text: str | None = None   # what replays this command, when that differs from the text
    # the clean session after it (history.History.lines), where the command returned to a kept
    # state (undo, redo, restore, accept) rather than adding its own line
    lines: tuple[str, ...] | None = None
    # the continuous-time check of the scene the command left, where it made one (an `iterate`'s):
    # the panels show it instead of checking the same motion again
    dense: DenseReport | None = None
