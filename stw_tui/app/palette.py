"""The command palette (Ctrl+P): the app's actions, the session commands, and the scene's names.

The app's actions are :class:`~textual.app.SystemCommand` entries (:func:`app_commands`, yielded
by ``StwApp.get_system_commands``); :class:`SceneCommands` provides what the scene holds (a DOF
or equation to plot), the commands of the language and the session files at hand (choosing one
starts it at the prompt).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from textual.app import SystemCommand
from textual.command import DiscoveryHit, Hit, Hits, Provider
from textual.content import Content

from stw_tui.app.messages import ItemChosen
from stw_tui.session.queries import equation_names
from stw_tui.sym.errors import printable

if TYPE_CHECKING:
    from textual.app import App

    from stw_tui.sos.scene import Scene

# (title, help, action) of the app's own entries: its keys' actions, and a few without a key
APP_ACTIONS = (
    ("Help", "F1: tutorial, keys and commands", "help"),
    ("Iterate", "F5: `iterate N`, N from the Opt panel", "iterate"),
    ("Stop", "F4: stop the solve at the next iteration, pause a replay", "stop"),
    ("Panels", "F2: the next panel", "panels"),
    ("Plots", "F3: the next plot", "plots"),
    ("Play", "F8: play the figure", "play"),
    ("Step", "F6: run the session's next line", "step"),
    ("Run rest", "F7: run the rest of the session", "run_rest"),
    ("Compare backends", "solve copies of the scene with each installed backend", "compare"),
    ("Survey gallery", "the optima of the last `survey N`: Enter plays one, a adopts it", "gallery"),
    ("Console", "Esc: back to the console", "escape"),
)


def app_commands(app: "App") -> Iterator[SystemCommand]:
    """The app's actions that are available now, as palette entries."""
    for title, help, action in APP_ACTIONS:
        if app.check_action(action, ()):
            yield SystemCommand(title, help, partial(app.run_action, action))


def scene_entries(scene: "Scene | None") -> Iterator[tuple[str, str, str, str]]:
    """(title, help, kind, name) of each DOF and equation the plots can show."""
    if scene is None:
        return
    for name in scene.dofs:
        yield f"Plot DOF {name}", "its curve over time (Curves plot)", "dof", name
    kinds = {**{n: "objective" for n in scene.objectives}, **{n: "let" for n in scene.lets},
             **{n: "constraint" for n in scene.constraints}}
    for name in equation_names(scene):
        yield f"Plot {kinds.get(name, 'equation')} {name}", "its values over time (Expr plot)", "equation", name


MAX_SESSION_FILES = 200   # a folder of thousands of .stw files must not slow the palette


def session_files(folder: Path | None = None) -> list[Path]:
    """The .stw files in ``folder`` (the current directory) and its ``sessions/``, as relative
    paths that `open` accepts (names with spaces left out: `open` takes one word)."""
    folder = Path.cwd() if folder is None else folder
    found: list[Path] = []
    for where in (folder, folder / "sessions"):
        try:
            found += sorted(p.relative_to(folder) for p in where.glob("*.stw") if p.is_file())
        except OSError:   # unreadable: nothing to offer from there
            continue
    return [p for p in found if not any(c.isspace() for c in str(p))][:MAX_SESSION_FILES]


class SceneCommands(Provider):
    """DOF and equations of the scene (plot one), the language's commands and the session files
    (start one at the prompt)."""

    def _entries(self) -> list[tuple[str, str, object]]:
        """Every entry, gathered once per palette opening (Textual makes a provider for each),
        not on every keystroke: the session files are a folder listing."""
        cached = getattr(self, "_gathered", None)
        if cached is None:
            cached = self._gathered = self._gather()
        return cached

    def _gather(self) -> list[tuple[str, str, object]]:
        from stw_tui.sym.language.help import COMMAND_HELP   # here: the language loads sympy

        app = self.app
        entries = [(title, help, partial(app.post_message, ItemChosen(kind, name)))
                   for title, help, kind, name in scene_entries(getattr(app, "scene", None))]
        for command, info in COMMAND_HELP.items():
            entries.append((f"Command {command}", info.synopsis, partial(self._start, command)))
        for path in session_files():
            entries.append((f"Open session {path}", "`open` it at the prompt: Enter runs its lines here",
                            partial(self._start, f"open {path}")))
        return entries

    def _start(self, command: str) -> None:
        """Put ``command`` at the console prompt for the user to complete (or Enter)."""
        field = self.app.repl.input
        field.value = f"{command} "
        field.cursor_position = len(field.value)
        field.focus()

    async def discover(self) -> Hits:
        """What the palette lists before anything is typed: the plots to show."""
        for title, help, callback in self._entries():
            if title.startswith("Plot "):
                yield DiscoveryHit(Content(title), callback, text=title, help=_literal(help))

    async def search(self, query: str) -> Hits:
        """The entries whose title matches what is typed, scored for the palette to rank."""
        matcher = self.matcher(query)
        for title, help, callback in self._entries():
            score = matcher.match(title)
            if score > 0:
                yield Hit(score, _highlight(matcher, title), callback, text=title, help=_literal(help))


def _literal(text: str) -> Content:
    """``text`` as the palette shows it: never read as markup (synopses and file names hold
    [brackets]), control characters escaped. The palette reads a str help as markup; a Content
    it shows as it is."""
    return Content(printable(text))


def _highlight(matcher, title: str) -> Content:
    """``title`` literally, the characters the query matched highlighted (Matcher.highlight
    would read the title as markup: a session file may be named `a[b].stw`)."""
    title = printable(title)
    content = Content(title)
    _score, offsets = matcher.fuzzy_search.match(matcher.query, title)
    for offset in offsets:
        if not title[offset].isspace():
            content = content.stylize(matcher.match_style, offset, offset + 1)
    return content
