"""A one-line edit dialog: panels ask for a value, then turn it into a command line."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Label


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
            yield Label(self._title, id="dialog-title")
            field = Input(self._value, id="dialog-input")
            field.cursor_blink = self._blink
            yield field
            yield Label(self._hint or "Enter applies · Esc cancels", id="dialog-hint")

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        self.dismiss(event.value)

    def action_cancel(self) -> None:
        self.dismiss(None)
