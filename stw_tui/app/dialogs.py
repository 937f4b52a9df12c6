"""Dialogs: a one-line edit (panels ask for a value, then turn it into a command line), the
backend comparison table, and the screen shown while the terminal is smaller than 80x24. Their
text is shown literally: never read as markup (titles and hints hold command synopses with
[brackets]), control characters escaped.

Below 80x24 the panels, plots, console and key hints no longer fit (at 60x20 the Opt tab
disappeared and the hints were cut): instead of a broken layout, :class:`TooSmallScreen` says so,
and goes away by itself once the terminal is large enough again. It is modal, so the app's keys
(F1, F2…) do not act on the screen hidden behind it; Ctrl+Q still quits.
"""

from __future__ import annotations

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.geometry import Size
from textual.screen import ModalScreen
from textual.widgets import DataTable, Input, Label, Static

from stw_tui.sym.errors import printable


class EditDialog(ModalScreen[str | None]):
    """Ask for one value. Dismisses with the text (Enter) or None (Escape).

    Args:
        title: what is being edited.
        value: the current value, pre-filled and selected so typing replaces it.
        hint: a line under the field (the command that will run).
    """

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, title: str, value: str = "", hint: str = "", blink: bool = True):
        super().__init__()
        self._title, self._value, self._hint, self._blink = title, value, hint, blink

    def compose(self) -> ComposeResult:
        with Vertical(id="dialog"):
            yield Label(printable(self._title), id="dialog-title", markup=False)
            field = Input(self._value, id="dialog-input")
            field.cursor_blink = self._blink
            yield field
            hint = self._hint or "Enter applies · Esc cancels"
            yield Label(printable(hint), id="dialog-hint", markup=False)

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        self.dismiss(event.value)

    def action_cancel(self) -> None:
        self.dismiss(None)


COMPARE_COLUMNS = ("backend", "its", "conv", "ms/it", "s total", "objective", "max viol", "Δ motion")


class CompareScreen(ModalScreen[None]):
    """The rows of :func:`stw_tui.session.compare.compare_scene` in a table (as `stw compare` prints them).

    Args:
        rows: one dict per backend (keys as compare_scene returns them).
        n: the iterations each backend was given.
        show_timing: show ms per iteration and seconds (False for deterministic snapshots).
    """

    BINDINGS = [Binding("escape", "close", "Close"), Binding("c", "close", "Close", show=False)]

    def __init__(self, rows: list[dict], n: int, show_timing: bool = True):
        super().__init__()
        self.rows, self.n, self.show_timing = rows, n, show_timing

    def compose(self) -> ComposeResult:
        with Vertical(id="compare"):
            yield Label(f"Backends on this scene, up to {self.n} iteration(s) each from the same start",
                        id="compare-title")
            yield DataTable(id="compare-table", cursor_type="row", zebra_stripes=True)
            yield Label("Esc closes · Δ motion: largest DOF difference from the first backend",
                        id="compare-hint")

    def on_mount(self) -> None:
        table = self.query_one(DataTable)
        table.add_columns(*COMPARE_COLUMNS)
        for r in self.rows:
            timing = (f"{r['median_ms_per_iteration']:.2f}", f"{r['seconds_to_converge']:.3f}")
            if not self.show_timing:
                timing = ("-", "-")
            backend = Text(printable(str(r["backend"])))   # a str cell is markup; a spec may hold [
            table.add_row(backend, str(r["iterations"]), "yes" if r["converged"] else "no",
                          *timing, f"{r['objective']:.6g}", f"{r['max_violation']:.2e}",
                          f"{r['max_motion_difference']:.2e}", key=str(r["backend"]))
        table.focus()

    def action_close(self) -> None:
        self.dismiss(None)


MIN_SIZE = Size(80, 24)


def too_small(size: Size) -> bool:
    """Whether a terminal of ``size`` is too small for stw's layout."""
    return size.width < MIN_SIZE.width or size.height < MIN_SIZE.height


def too_small_message(size: Size) -> str:
    """What the screen says for a terminal of ``size``."""
    return (f"The terminal is {size.width}×{size.height}: make it at least "
            f"{MIN_SIZE.width}×{MIN_SIZE.height} to use stw.\n\n"
            "(A larger window, or a smaller font.) Ctrl+Q quits.")


class TooSmallScreen(ModalScreen[None]):
    """'Make the terminal at least 80x24', until it is."""

    DEFAULT_CSS = """
    TooSmallScreen {
        align: center middle;
        background: $background;
    }
    TooSmallScreen > Static {
        width: 100%;
        height: auto;
        padding: 0 1;
        text-align: center;
    }
    """

    def compose(self) -> ComposeResult:
        yield Static(too_small_message(self.app.size), id="too-small", markup=False)

    def on_resize(self) -> None:
        """Say the new size; close once it is large enough (the app asks too, see StwApp)."""
        size = self.app.size
        if not too_small(size):
            if self.app.screen is self:
                self.dismiss(None)
            return
        self.query_one("#too-small", Static).update(too_small_message(size))

    def on_screen_resume(self) -> None:
        """Back on top (a screen pushed over it closed): close if the terminal is large enough now."""
        if not too_small(self.app.size):
            self.dismiss(None)
