"""The key hints line at the bottom: the app's keys first, then the focused widget's.

Textual's Footer mounts one widget per key and recomposes itself on every focus change; with
Pilot on basketball at 80x24 that was about half of what F2, F3 and Esc cost (F3 ~200 ms of UI
time with it, ~130 ms without). This is one line of text, rendered again when the bindings
change, and a click on a key presses it, as on the Footer.
"""

from __future__ import annotations

from rich.text import Text
from textual import events
from textual.widget import Widget


class KeyHints(Widget):
    """Keys and what they do, in one line: ``order`` (actions) first, in that order, then the
    other shown bindings of the focused widget and its ancestors. Only whole hints are shown:
    one that does not fit is left out with those after it, so at 80 columns it is the widget's
    own keys that go, never the app's; an ellipsis says some are left out (F1 lists them all)."""

    COMPONENT_CLASSES = {"key-hints--key", "key-hints--disabled"}
    DEFAULT_CSS = """
    KeyHints {
        height: 1;
        background: $footer-background;
        color: $footer-description-foreground;
    }
    KeyHints > .key-hints--key {
        color: $footer-key-foreground;
        text-style: bold;
    }
    KeyHints > .key-hints--disabled {
        color: $text-disabled;
    }
    """

    def __init__(self, order: list[tuple[str, str]], **kwargs):
        super().__init__(**kwargs)
        self._order = {key_action: i for i, key_action in enumerate(order)}
        self._spans: list[tuple[int, int, str]] = []   # (start, end, key) of each hint shown

    def on_mount(self) -> None:
        self.screen.bindings_updated_signal.subscribe(self, lambda screen: self.refresh())

    def on_unmount(self) -> None:
        self.screen.bindings_updated_signal.unsubscribe(self)

    def hints(self) -> list[tuple[str, str, str, bool]]:
        """(key, key as shown, description, enabled) of each binding to show, in order."""
        seen: set[str] = set()
        shown = []
        for _node, binding, enabled, _tooltip in self.screen.active_bindings.values():
            if binding.show and binding.action not in seen:   # one hint per action, as the Footer
                seen.add(binding.action)
                shown.append((binding, enabled))
        last = len(self._order)
        shown.sort(key=lambda item: self._order.get((item[0].key, item[0].action), last))   # stable
        return [(b.key, self.app.get_key_display(b), b.description, enabled) for b, enabled in shown]

    def render(self) -> Text:
        key_style = self.get_component_rich_style("key-hints--key")
        disabled = self.get_component_rich_style("key-hints--disabled")
        text = Text(no_wrap=True, overflow="crop", end="", style=self.rich_style)   # the line's background
        self._spans = []
        width = self.size.width or None
        hints = self.hints()
        for i, (key, display, description, enabled) in enumerate(hints):
            start = len(text)
            hint = Text(display, key_style if enabled else disabled)
            if description:
                hint.append(f" {description}", None if enabled else disabled)
            # Room for " …" after it unless it is the last: a next hint (3 cells or more) would not fit
            room_after = 0 if i == len(hints) - 1 else 2
            if width is not None and text.cell_len + hint.cell_len + room_after > width:
                text.append("…", disabled)   # more keys than fit: F1 lists them
                break
            text.append_text(hint)
            self._spans.append((start, len(text), key if enabled else ""))
            text.append(" ")
        return text

    def on_click(self, event: events.Click) -> None:
        for start, end, key in self._spans:
            if start <= event.x < end:
                if key:
                    self.app.simulate_key(key)
                else:
                    self.app.bell()
                return
