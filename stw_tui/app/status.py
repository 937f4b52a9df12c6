"""The status line: what the solver is doing, in one row."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rich.text import Text
from textual.widgets import Static

if TYPE_CHECKING:
    from ..backend import StepReport


class StatusLine(Static):
    """Iteration, objective, violation, backend and ms per iteration of the newest report.

    Args:
        show_timing: False hides the milliseconds (deterministic snapshots).
    """

    def __init__(self, show_timing: bool = True, **kwargs):
        super().__init__(**kwargs)
        self.show_timing = show_timing
        self.backend = "scipy"
        self.window = "all"
        self.state = "idle"
        self.report: "StepReport | None" = None

    def show(self, *, state: str | None = None, report: "StepReport | None" = None,
             backend: str | None = None, window: str | None = None, clear_report: bool = False) -> None:
        """Change some fields and redraw."""
        if state is not None:
            self.state = state
        if report is not None or clear_report:
            self.report = report
        if backend is not None:
            self.backend = backend
        if window is not None:
            self.window = window
        self.update(self.render_text())

    def render_text(self) -> Text:
        busy = self.state not in ("idle", "step")
        text = Text.assemble((f" {self.state} ", "reverse bold" if busy else "reverse"), " ")
        r = self.report
        if r is not None:
            text.append(f"iter {r.iteration}  obj {r.objective:.6g}  viol {r.max_violation:.2e}  ")
            if self.show_timing:
                text.append(f"{r.total_ms:.1f} ms/it  ")
        text.append(f"backend {self.backend}  window {self.window}", style="dim")
        return text
