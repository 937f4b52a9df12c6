"""The console: a log of commands and results, and a prompt with history and Tab completion."""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Callable

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.events import Resize
from textual.geometry import Size
from textual.widget import Widget
from textual.widgets import Input, Label, RichLog

from stw_tui.app.completion import History, complete
from stw_tui.app.messages import CommandRequested, Origin
from stw_tui.sym.errors import SourceError, printable

if TYPE_CHECKING:
    from stw_tui.sos.scene import Scene

PROMPT, CONTINUATION = "stw> ", "...> "


class CommandInput(Input):
    """The prompt line: up/down browse history, Tab completes commands and names."""

    BINDINGS = [
        Binding("up", "history(-1)", "Previous command", show=False),
        Binding("down", "history(1)", "Next command", show=False),
        # Bound here so Tab completes instead of moving the focus (the focused widget wins).
        Binding("tab", "complete", "Complete", show=False),
        # The log scrolls from the prompt: no need to move the focus to read back.
        Binding("pageup", "scroll_log(-1)", "Scroll the log", show=False),
        Binding("pagedown", "scroll_log(1)", "Scroll the log", show=False),
    ]

    def __init__(self, scene_of: Callable[[], "Scene"], backends: Callable[[], list[str]], **kwargs):
        super().__init__(**kwargs)
        self.history = History()
        self._scene_of = scene_of
        self._backends = backends

    def _watch_value(self, value: str) -> None:
        # Input makes its virtual width the text's width through a layout reactive: a layout of
        # the whole screen at every keystroke, about half of a typed key's UI time (basketball,
        # 80x24). The width only bounds horizontal scrolling, which needs no layout: set it
        # quietly first, so Input's own assignment finds nothing to change.
        self.set_reactive(Widget.virtual_size, Size(self.content_width, 1))
        super()._watch_value(value)

    def action_history(self, direction: int) -> None:
        self.value = self.history.previous(self.value) if direction < 0 else self.history.next()
        self.cursor_position = len(self.value)

    def action_scroll_log(self, pages: int) -> None:
        log = self.screen.query_one(Console).log_widget
        (log.scroll_page_down if pages > 0 else log.scroll_page_up)(animate=False)

    def action_complete(self) -> None:
        head = self.value[:self.cursor_position]
        new_head, choices = complete(head, self._scene_of(), self._backends())
        self.value = new_head + self.value[self.cursor_position:]
        self.cursor_position = len(new_head)
        if choices:
            self.screen.query_one(Console).write_note("  ".join(choices))


class ConsoleLog(RichLog):
    """A RichLog whose text wraps to its own width, again whenever that width changes.

    RichLog renders what is written into lines at the width it has then, and keeps only those
    lines: after a resize the console stayed wrapped at the old width (issue 52). This keeps what
    was written (as many entries as the log keeps lines) and, when the width has changed, renders
    it all again at the new width (2000 entries: ~0.1 s, once per resize). Each entry is rendered
    at the log's width, given explicitly: RichLog otherwise measures text against the app
    console's width, which is the terminal's in a terminal but stays 80 under a test's Pilot.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._written: deque[tuple[object, dict]] = deque(maxlen=self.max_lines)
        self._wrapped_at: int | None = None    # the width the lines were rendered at
        self._rewriting = False

    def _width(self) -> int | None:
        width = self.scrollable_content_region.width
        return width if self._size_known and width > 0 else None

    def write(self, content, *args, **kwargs) -> "ConsoleLog":
        """Write ``content`` (kept, to be wrapped again at another width)."""
        options = {**dict(zip(("width", "expand", "shrink", "scroll_end", "animate"), args)), **kwargs}
        if not self._rewriting:
            self._written.append((content, options))
        width = self._width()
        if options.get("width") is None and width is not None:
            options = {**options, "width": width}
            self._wrapped_at = width
        super().write(content, **options)
        return self

    def clear(self) -> "ConsoleLog":
        """Clear the log and what it keeps."""
        self._written.clear()
        super().clear()
        return self

    def on_resize(self, event: Resize) -> None:
        """Wrap again once the new size is laid out: while the Resize event is handled, the
        region the lines would be wrapped to is still the old one. (RichLog's own handler renders
        what was written before the size was known.)"""
        self._rewriting = True
        try:
            super().on_resize(event)
        finally:
            self._rewriting = False
        self.call_after_refresh(self._rewrap)

    def _rewrap(self) -> None:
        width = self._width()
        if width is None or width == self._wrapped_at:
            return
        at_end = self.is_vertical_scroll_end
        self._rewriting = True
        try:
            RichLog.clear(self)
            for content, options in self._written:
                self.write(content, **{**options, "scroll_end": False})
        finally:
            self._rewriting = False
        if at_end:
            self.scroll_end(animate=False, immediate=False, x_axis=False)


class Console(Vertical):
    """Log plus prompt. Submitting a line posts :class:`CommandRequested`; the app runs it."""

    def __init__(self, scene_of: Callable[[], "Scene"], backends: Callable[[], list[str]],
                 blink: bool = True, **kwargs):
        super().__init__(**kwargs)
        self._scene_of = scene_of
        self._backends = backends
        self._blink = blink

    def compose(self) -> ComposeResult:
        yield ConsoleLog(id="console-log", wrap=True, markup=False, max_lines=2000)
        with Horizontal(id="prompt-row"):
            yield Label(PROMPT, id="prompt")
            command_input = CommandInput(self._scene_of, self._backends, id="command-input",
                                         placeholder="a command, `help`, Tab completes",
                                         select_on_focus=False)
            command_input.cursor_blink = self._blink
            yield command_input

    @property
    def input(self) -> CommandInput:
        """The prompt's input field."""
        return self.query_one(CommandInput)

    @property
    def log_widget(self) -> RichLog:
        """The log that commands, results and notes are written to."""
        return self.query_one(RichLog)

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        line = event.value
        self.input.history.add(line)
        self.input.value = ""
        self.post_message(CommandRequested(line, origin=Origin.CONSOLE))

    def set_prompt(self, continuation: bool) -> None:
        """Show the continuation prompt inside a `linkage` block, the normal one otherwise."""
        self.query_one("#prompt", Label).update(CONTINUATION if continuation else PROMPT)

    # --- writing (Text objects, never markup: user text contains [brackets]; and made
    # printable: a session line, a path or a plugin's message may hold escape sequences) -----
    def write_command(self, line: str, number: int | None = None, origin: Origin = Origin.CONSOLE,
                      continuation: bool = False) -> None:
        """Echo a command line, prefixed by its file line number or where it came from."""
        if number is not None:
            prefix = f"{number:>3}| "
        elif continuation:
            prefix = CONTINUATION
        else:
            prefix = PROMPT if origin == Origin.CONSOLE else f"{origin}> "
        self.log_widget.write(Text.assemble((prefix, "dim"), (printable(line), "bold")))

    def write_result(self, text: str) -> None:
        """Write what a command printed (plain text, never markup)."""
        if text:
            self.log_widget.write(Text(printable(text, newlines=True)))

    def write_note(self, text: str) -> None:
        """Write a note of the app's own, dimmed."""
        self.log_widget.write(Text(printable(text, newlines=True), style="dim italic"))

    def write_error(self, error: BaseException) -> None:
        """An error in red, with the offending line and a caret under the column when known."""
        message = str(error) if str(error) else type(error).__name__
        if not isinstance(error, Exception) or type(error).__module__.split(".")[0] != "stw_tui":
            message = f"internal error {type(error).__name__}: {message}"
        self.log_widget.write(Text(printable(message, newlines=True), style="bold red"))
        if isinstance(error, SourceError) and error.caret():
            self.log_widget.write(Text(error.caret(), style="red"))
