"""Dialogs: a one-line edit (panels ask for a value, then turn it into a command line) and the
backend comparison table. Their text is shown literally: never read as markup (titles and hints
hold command synopses with [brackets]), control characters escaped."""

from __future__ import annotations

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import DataTable, Input, Label

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
