"""The status line: what the solver is doing, in one row."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rich.text import Text
from textual.widget import Widget

if TYPE_CHECKING:
    from stw_tui.sos.backend import StepReport


class StatusLine(Widget):
    """State, then iteration, objective, violation and ms per iteration of the newest report, then
    the window and the backend. Shortened, never cut, to fit the width: labels and digits go first.

    After a command that changes the scene, the report's numbers describe a scene that no longer
    exists: they are shown dim and marked ``stale`` until the next solve reports.

    Args:
        show_timing: False hides the milliseconds (deterministic snapshots).
    """

    def __init__(self, show_timing: bool = True, **kwargs):
        super().__init__(**kwargs)
        self.show_timing = show_timing
        self.backend = "scipy"
        self.window = "all"
        self.state = "idle"
        self.stale = False
        self.report: "StepReport | None" = None

    def show(self, *, state: str | None = None, report: "StepReport | None" = None,
             backend: str | None = None, window: str | None = None, clear_report: bool = False,
             stale: bool | None = None) -> None:
        """Change some fields and redraw. A new report is fresh unless ``stale`` says otherwise."""
        if state is not None:
            self.state = state
        if report is not None or clear_report:
            self.report = report
            self.stale = False
        if stale is not None:
            self.stale = stale
        if backend is not None:
            self.backend = backend
        if window is not None:
            self.window = window
        self.refresh()

    def render(self) -> Text:
        return self.render_text(self.size.width or None)

    def _variants(self) -> list[tuple[str, str, str]]:
        """(report part, place part, separator) from the most detailed to the shortest."""
        r = self.report
        full = compact = short = ""
        if r is not None:
            ms = f"  {r.total_ms:.1f} ms/it" if self.show_timing else ""
            full = f"iter {r.iteration}  obj {r.objective:.6g}  viol {r.max_violation:.2e}{ms}"
            compact = f"it {r.iteration} obj {r.objective:.4g} viol {r.max_violation:.1e}"
            short = f"viol {r.max_violation:.0e}"
            if self.stale:
                full, compact, short = f"stale: {full}", f"stale: {compact}", f"stale {short}"
        return [(full, f"window {self.window}  backend {self.backend}", "  "),
                (full, f"window {self.window}  {self.backend}", "  "),
                (compact, f"win {self.window} {self.backend}", "  "),
                (compact, f"win {self.window}", " "),
                (short, f"win {self.window}", " "),
                ("", f"win {self.window}", " ")]

    def render_text(self, width: int | None = None) -> Text:
        """The line, shortened to ``width`` cells when given."""
        busy = self.state not in ("idle", "step") and not self.state.startswith("step:")
        badge = Text(f" {self.state} ", style="reverse bold" if busy else "reverse")
        variants = self._variants()
        for report, place, gap in variants:
            text = badge.copy()
            text.append(" ")
            if report:
                text.append(report, style="dim italic" if self.stale else "")
                text.append(gap)
            text.append(place, style="dim")
            if width is None or text.cell_len <= width:
                return text
        text.truncate(width, overflow="ellipsis")
        return text
