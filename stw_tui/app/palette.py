"""The command palette (Ctrl+P): the app's actions, the session commands, and the scene's names.

The app's actions are :class:`~textual.app.SystemCommand` entries (see ``StwApp.get_system_commands``);
this module adds a provider for what the scene holds (a DOF or equation to plot) and for the
commands of the language (choosing one starts it at the console prompt).
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, Iterator

from textual.command import DiscoveryHit, Hit, Hits, Provider

from .messages import ItemChosen
from .values import equation_names

if TYPE_CHECKING:
    from ..scene import Scene


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


class SceneCommands(Provider):
    """DOF and equations of the scene (plot one), and the language's commands (start one)."""

    def _entries(self) -> list[tuple[str, str, object]]:
        from ..language.help import COMMAND_HELP   # here: the language loads sympy

        app = self.app
        entries = [(title, help, partial(app.post_message, ItemChosen(kind, name)))
                   for title, help, kind, name in scene_entries(getattr(app, "scene", None))]
        for command, info in COMMAND_HELP.items():
            # Help is markup to the palette: synopses hold [brackets].
            entries.append((f"Command {command}", info.synopsis.replace("[", "\\["), partial(self._start, command)))
        return entries

    def _start(self, command: str) -> None:
        """Put ``command`` at the console prompt for the user to complete."""
        field = self.app.repl.input
        field.value = f"{command} "
        field.cursor_position = len(field.value)
        field.focus()

    async def discover(self) -> Hits:
        for title, help, callback in self._entries():
            if title.startswith("Plot "):
                yield DiscoveryHit(title, callback, help=help)

    async def search(self, query: str) -> Hits:
        matcher = self.matcher(query)
        for title, help, callback in self._entries():
            score = matcher.match(title)
            if score > 0:
                yield Hit(score, matcher.highlight(title), callback, text=title, help=help)
