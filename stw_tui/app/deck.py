"""A deck of views with a tab strip: the panels (F2) and the plots (F3).

Textual's ``TabbedContent`` made a switch cost two or three full frames: the new pane was laid
out and drawn empty, then refilled when its ``TabActivated`` message came back (a second layout),
and the table refitted its columns once it had a size (a third). At 80x24 on basketball the
Eqns panel drew an empty header at 55 ms, its rows at 170 and its final column widths at 223
(issue 52). A :class:`Deck` switches in one frame: its ``prepare`` hook brings the view up to date
*before* it is shown (a hidden panel fits its columns to the deck's width, see
``ScenePanel._room``), then one :class:`ContentSwitcher` change shows it (hidden views are
``display: none``: never laid out nor drawn) and the strip, a single widget, redraws its two rows.
"""

from __future__ import annotations

from typing import Callable, Iterable

from rich.console import Group
from rich.text import Text
from textual import events
from textual.containers import Vertical
from textual.message import Message
from textual.renderables.bar import Bar
from textual.widget import Widget
from textual.widgets import ContentSwitcher

PAD = 1   # blanks either side of a tab's label (Textual's Tab: padding 0 1)


def tab_id(title: str) -> str:
    """The id of the tab that shows a view titled ``title`` ("tab-eqns")."""
    return f"tab-{title.lower()}"


class TabStrip(Widget):
    """The deck's tab labels over an underline, the active one marked: one widget that redraws
    its two rows when the active tab or the focus mark changes (no layout)."""

    DEFAULT_CSS = """
    TabStrip {
        height: 2;
        width: 1fr;
    }
    """
    COMPONENT_CLASSES = {"tab-strip--tab", "tab-strip--active", "tab-strip--active-focus",
                         "tab-strip--bar", "tab-strip--bar-active", "tab-strip--bar-focus"}

    class Clicked(Message):
        """A tab's label was clicked."""

        def __init__(self, tab: str):
            super().__init__()
            self.tab = tab

    def __init__(self, titles: Iterable[str], **kwargs):
        super().__init__(**kwargs)
        self.titles = list(titles)
        self.active = 0
        self.marked = False      # the deck holds the focus: accent colours

    def show(self, index: int | None = None, marked: bool | None = None) -> None:
        """Mark tab ``index`` active and/or set the focus mark; redraw only on a change."""
        changed = False
        if index is not None and index != self.active:
            self.active, changed = index, True
        if marked is not None and marked != self.marked:
            self.marked, changed = marked, True
        if changed:
            self.refresh()

    def spans(self) -> list[tuple[int, int]]:
        """(start, end) columns of each tab, padding included."""
        spans, x = [], 0
        for title in self.titles:
            width = len(title) + 2 * PAD
            spans.append((x, x + width))
            x += width
        return spans

    def render(self) -> Group:
        style = self.get_component_rich_style
        labels = Text(no_wrap=True, overflow="crop")
        for i, title in enumerate(self.titles):
            if i == self.active:
                name = "tab-strip--active-focus" if self.marked else "tab-strip--active"
            else:
                name = "tab-strip--tab"
            labels.append(" " * PAD + title + " " * PAD, style(name))
        start, end = self.spans()[self.active] if self.titles else (0, 0)
        highlight = style("tab-strip--bar-focus" if self.marked else "tab-strip--bar-active")
        # Textual's own underline (the Underline widget's renderable): the same look as before
        bar = Bar((start + PAD, end - PAD), highlight_style=highlight, background_style=style("tab-strip--bar"))
        return Group(labels, bar)

    def on_click(self, event: events.Click) -> None:
        for title, (start, end) in zip(self.titles, self.spans()):
            if start <= event.x < end:
                event.stop()
                self.post_message(self.Clicked(tab_id(title)))
                return


class Deck(Vertical):
    """Views (panels or plots) of which one shows at a time, under a :class:`TabStrip`.

    Args:
        views: (title, widget) of each view, in tab order; each widget needs an id.
        prepare: called with a view just before it is shown (the app brings it up to date).
        ahead: after each switch, once the screen is refreshed, also ``prepare`` the view that the
            next switch shows (for views whose work runs in the background, as the plots': the
            next F3 then finds it ready).
    """

    DEFAULT_CSS = """
    Deck > ContentSwitcher {
        height: 1fr;
    }
    """

    def __init__(self, views: Iterable[tuple[str, Widget]], prepare: Callable[[Widget], None] | None = None,
                 ahead: bool = False, **kwargs):
        super().__init__(**kwargs)
        views = list(views)
        self._views = {tab_id(title): widget for title, widget in views}
        self._titles = [title for title, _ in views]
        self._active = next(iter(self._views))
        self.prepare = prepare
        self.ahead = ahead

    def compose(self):
        yield TabStrip(self._titles)
        yield ContentSwitcher(*self._views.values(), initial=self._views[self._active].id)

    @property
    def tabs(self) -> list[str]:
        """The tab ids, in order."""
        return list(self._views)

    def view(self, tab: str) -> Widget:
        """The view of tab ``tab``."""
        return self._views[tab]

    @property
    def views(self) -> dict[str, Widget]:
        """Tab id -> view."""
        return dict(self._views)

    @property
    def current(self) -> Widget:
        """The view shown."""
        return self._views[self._active]

    @property
    def active(self) -> str:
        """The id of the tab shown ("tab-eqns"); setting it shows that tab's view."""
        return self._active

    @active.setter
    def active(self, tab: str) -> None:
        """Show tab ``tab`` (as :meth:`show`)."""
        self.show(tab)

    def show(self, tab: str) -> Widget:
        """Show tab ``tab``'s view (brought up to date first by ``prepare``); returns it."""
        widget = self._views[tab]     # KeyError: no such tab
        if tab == self._active:
            return widget
        self._active = tab
        if not self.is_mounted:
            return widget
        if self.prepare is not None:
            self.prepare(widget)
        self.query_one(ContentSwitcher).current = widget.id
        self.query_one(TabStrip).show(index=self.tabs.index(tab))
        if self.ahead and self.prepare is not None:   # after this switch's frame, not competing with it
            self.call_after_refresh(self.prepare, self.upcoming)
        return widget

    @property
    def upcoming(self) -> Widget:
        """The view the next switch (F2/F3) shows."""
        return self._views[self.next_tab()]

    def next_tab(self, step: int = 1) -> str:
        """The id of the tab ``step`` after the active one (wrapping round)."""
        tabs = self.tabs
        return tabs[(tabs.index(self._active) + step) % len(tabs)]

    def mark(self, marked: bool) -> None:
        """Mark the strip as holding the focus (accent colours) or not."""
        self.query_one(TabStrip).show(marked=marked)

    def on_mount(self) -> None:
        self.query_one(TabStrip).show(index=self.tabs.index(self._active))

    def on_tab_strip_clicked(self, event: TabStrip.Clicked) -> None:
        """A click on a tab shows it and focuses its view."""
        event.stop()
        widget = self.show(event.tab)
        if widget.focusable:
            self.screen.set_focus(widget)
