"""The status line: what the solver is doing, in one row."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rich.text import Text
from textual.widget import Widget

if TYPE_CHECKING:
    from stw_tui.session.queries import SceneMeasures
    from stw_tui.session.snapshots import Measures
    from stw_tui.sos.backend import StepReport


class StatusLine(Widget):
    """State, then how good the scene's motion is, then the window and the backend. Shortened,
    never cut, to fit the width: labels and digits go first.

    The numbers are the scene's as it is now, measured in the session worker after every command
    (stw_tui/session/queries.py, ``scene_measures``): its objective over the whole animation, its
    dense violation (the continuous-time check: the one that counts) with the constraint worst
    there when it fails, and its violation at the instances. While a solve runs they are the
    running solve's instead (iteration, the window's objective and violation, ms per iteration).
    A replayed line with more to come is not measured: the numbers of the scene before it are
    then shown dim and marked ``stale`` until the next measurement.

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
        self.report: "StepReport | None" = None        # of the running solve
        self.measures: "SceneMeasures | None" = None   # of the scene after the last measured command
        self.proposal: "Measures | None" = None        # of a solve's proposal (`set preview on`)

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

    def measured(self, measures: "SceneMeasures | None", proposal: "Measures | None" = None) -> None:
        """Show the scene's numbers as measured after a command (None: it has nothing to measure,
        no DOF), and those of a pending proposal; they replace the running solve's."""
        self.measures, self.proposal, self.report, self.stale = measures, proposal, None, False
        self.refresh()

    def render(self) -> Text:
        return self.render_text(self.size.width or None)

    def _report_parts(self) -> tuple[str, str, str]:
        """The running solve's numbers: full, compact, short."""
        r = self.report
        ms = f"  {r.total_ms:.1f} ms/it" if self.show_timing else ""
        return (f"iter {r.iteration}  obj {r.objective:.6g}  viol {r.max_violation:.2e}{ms}",
                f"it {r.iteration} obj {r.objective:.4g} viol {r.max_violation:.1e}",
                f"viol {r.max_violation:.0e}")

    def _measure_parts(self) -> tuple[str, str, str]:
        """The scene's numbers: full, compact, short."""
        m = self.measures
        obj_full = f"obj {m.objective:.6g}  " if m.objective is not None else ""
        obj_compact = f"obj {m.objective:.4g} " if m.objective is not None else ""
        if m.dense is None:
            return f"{obj_full}dense unchecked", f"{obj_compact}dense ?", "dense ?"
        worst = f" ({m.worst})" if m.worst else ""
        full = f"{obj_full}dense {m.dense:.2e}{worst}  inst {m.instances:.2e}"
        compact = f"{obj_compact}dense {m.dense:.1e}{worst} inst {m.instances:.1e}"
        p = self.proposal
        if p is not None and p.objective is not None:
            full += f"  proposal obj {p.objective:.6g} dense {p.dense:.2e}"
        return full, compact, f"dense {m.dense:.0e}"

    def _variants(self) -> list[tuple[str, str, str]]:
        """(numbers, place part, separator) from the most detailed to the shortest."""
        full = compact = short = ""
        if self.report is not None:
            full, compact, short = self._report_parts()
        elif self.measures is not None:
            full, compact, short = self._measure_parts()
        if self.stale and full:
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
