"""The help screen (F1): a short tutorial, every key, and every command, scrollable and searchable.

The command texts come from :mod:`stw_tui.sym.language.help` (as `help` and `help COMMAND` print them)
and the keys from the widgets' own ``BINDINGS``, so neither is written twice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, VerticalScroll
from textual.screen import Screen
from textual.widgets import Input, Label, Static

if TYPE_CHECKING:
    from textual.app import App

# Prose paragraphs are single lines (the screen wraps them to its width); command lines fit 80 columns.
TUTORIAL = """\
A first animation: Witkin & Kass's jet-propelled particle (sessions/particle_jet.stw). Type each line at the console (stw>) and press Enter; Tab completes names.

  time 0 1 knots=12              the animation runs from t=0 to t=1
  const m = 1, g = 9.81          constants: change them any time
  dof x                          a degree of freedom: a curve x(t)
  let f = m*x'' + m*g            the jet force, named
  constraint start: x = 0, x' = 0 @ 0
  constraint end:   x = 1, x' = 0 @ 1
  objective fuel: f              minimize the integral of f^2
  iterate 20                     solve (F5 does the same); F4 stops a solve
  print x @ 0.5                  0.5 for the optimal cubic

While it solves, the plots follow each iteration: F3 cycles Curves, Expr (constraint values), Figure (space plays, arrows scrub) and Conv (convergence). F2 cycles the panels, which edit the scene by running commands you can see in the console. Typing always reaches the console; Esc brings the focus back to it.

`stw sessions/NAME.stw` replays a session; with --step, F6 runs it line by line and F7 runs the rest. A command typed while it replays waits for its end (so the file's own lines run on the scene it builds); print, show and help answer at once. Ctrl+P opens the command palette."""

CONSOLE_KEYS = (("Enter", "run the line"), ("Up / Down", "previous / next command"),
                ("Tab", "complete a command, name or setting"), ("PgUp/PgDn", "scroll the log"),
                ("Esc", "drop an open linkage block"))


class SearchField(Input):
    """The search field: it lets the screen have q (close) while it is empty."""

    def check_consume_key(self, key: str, character: str | None) -> bool:
        """Let q through to the screen (close) while the field is empty."""
        if key == "q" and not self.value:
            return False
        return super().check_consume_key(key, character)


@dataclass(frozen=True)
class HelpSection:
    """One titled block of the help screen."""

    title: str
    body: str

    def matches(self, query: str) -> bool:
        """Whether ``query`` occurs in the title or the body, ignoring case."""
        query = query.lower()
        return query in self.title.lower() or query in self.body.lower()

    def excerpt(self, query: str, whole: int = 6) -> str:
        """The body, or for a long one whose title does not match, only its lines with ``query``
        (each under its group's heading, the last unindented line before it)."""
        lines = self.body.splitlines()
        query = query.lower()
        if not query or len(lines) <= whole or query in self.title.lower():
            return self.body
        kept, heading, shown_heading = [], None, None
        for line in lines:
            if line and not line[0].isspace():
                heading = line
            if query in line.lower():
                if heading is not None and heading is not line and heading is not shown_heading:
                    kept.append(heading)
                shown_heading = heading
                kept.append(line)
        return "\n".join(kept)


def _key_lines(app: "App", bindings: Iterable[Binding]) -> list[str]:
    """A line per binding: its key, its description (as the key hints show it, short) and, where
    it has one, its tooltip (the longer text)."""
    rows = []
    for binding in bindings:
        if isinstance(binding, Binding) and binding.description:
            more = f": {binding.tooltip}" if binding.tooltip else ""
            rows.append(f"  {app.get_key_display(binding):<10} {binding.description}{more}")
    return rows


def column_sections(areas: Iterable[tuple[str, type]]) -> str:
    """What each panel's abbreviated column headings stand for (their COLUMN_HELP)."""
    lines: list[str] = []
    for title, cls in areas:
        explained = getattr(cls, "COLUMN_HELP", {})
        if explained:
            lines += ([""] if lines else []) + [title] + [f"  {name:<10} {what}" for name, what in explained.items()]
    return "\n".join(lines)


def key_sections(app: "App", areas: Iterable[tuple[str, type]]) -> str:
    """Every key of the app and of each area's widget class, from their BINDINGS."""
    lines = ["Everywhere"] + _key_lines(app, type(app).BINDINGS) + [f"  {'^p':<10} Command palette"]
    lines += ["", "Console"] + [f"  {key:<10} {what}" for key, what in CONSOLE_KEYS]
    for title, cls in areas:
        own = [b for b in cls.BINDINGS if isinstance(b, Binding)]
        if own:
            lines += ["", title] + _key_lines(app, own)
    return "\n".join(lines)


def help_sections(app: "App", areas: Iterable[tuple[str, type]]) -> list[HelpSection]:
    """The tutorial, the keys, the command list, then one section per command."""
    from stw_tui.sym.language.help import COMMAND_HELP, help_text   # here: the language loads sympy

    areas = list(areas)
    sections = [HelpSection("Getting started", TUTORIAL), HelpSection("Keys", key_sections(app, areas)),
                HelpSection("Panel columns", column_sections(areas)), HelpSection("Commands", help_text())]
    sections += [HelpSection(f"{name}", help_text(name)) for name in COMMAND_HELP]
    return sections


class HelpScreen(Screen[None]):
    """Full-screen help. Typing searches (only the sections that match stay, matches marked);
    Up/Down/PgUp/PgDn scroll; Esc closes (q too, when the search field is empty).

    Args:
        sections: what to show, in order.
        blink: blink the search field's cursor.
    """

    BINDINGS = [
        Binding("escape", "close", "Close"),
        # Priority, or the search field would type it; the field keeps it inside a search.
        Binding("q", "close", "Close", show=False, priority=True),
        Binding("up", "scroll(-1)", "Scroll", show=False),
        Binding("down", "scroll(1)", "Scroll", show=False),
        Binding("pageup", "page(-1)", "Page up", show=False),
        Binding("pagedown", "page(1)", "Page down", show=False),
        Binding("ctrl+home", "jump(0)", "Top", show=False),
        Binding("ctrl+end", "jump(1)", "End", show=False),
    ]

    def __init__(self, sections: list[HelpSection], blink: bool = True):
        super().__init__()
        self.sections = sections
        self._blink = blink

    def compose(self) -> ComposeResult:
        with Horizontal(id="help-bar"):
            yield Label(" Help ", id="help-title")
            field = SearchField(placeholder="type to search", id="help-search", select_on_focus=False)
            field.cursor_blink = self._blink
            yield field
            yield Label("", id="help-count")
        with VerticalScroll(id="help-body", can_focus=False):
            for index, section in enumerate(self.sections):
                yield Static(id=f"help-{index}", classes="help-section", markup=False)
        yield Label(" Esc closes · type to search · ↑ ↓ PgUp PgDn scroll · `help CMD` at the console",
                    id="help-hint")

    def on_mount(self) -> None:
        self.show_matches("")
        self.query_one("#help-search", Input).focus()

    @property
    def query_text(self) -> str:
        """What the search field holds, without surrounding blanks."""
        return self.query_one("#help-search", Input).value.strip()

    def show_matches(self, query: str) -> list[HelpSection]:
        """Show only the sections containing ``query`` (all when empty), matches highlighted."""
        shown = []
        for index, section in enumerate(self.sections):
            widget = self.query_one(f"#help-{index}", Static)
            visible = not query or section.matches(query)
            widget.display = visible
            if visible:
                shown.append(section)
                text = Text.assemble((section.title, "bold underline"), "\n", section.excerpt(query))
                if query:
                    text.highlight_words([query], "reverse", case_sensitive=False)
                widget.update(text)
        count = "" if not query else f"{len(shown)} section(s) match" if shown else "no match"
        self.query_one("#help-count", Label).update(count)
        self.query_one("#help-body").scroll_home(animate=False)
        return shown

    def on_input_changed(self, event: Input.Changed) -> None:
        event.stop()
        self.show_matches(event.value.strip())

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()

    def action_close(self) -> None:
        self.dismiss(None)


    def action_scroll(self, lines: int) -> None:
        body = self.query_one("#help-body")
        body.scroll_to(y=body.scroll_y + lines, animate=False)

    def action_page(self, pages: int) -> None:
        body = self.query_one("#help-body")
        body.scroll_to(y=body.scroll_y + pages * max(1, body.size.height - 1), animate=False)

    def action_jump(self, end: int) -> None:
        body = self.query_one("#help-body")
        (body.scroll_end if end else body.scroll_home)(animate=False)
