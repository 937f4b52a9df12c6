"""Console history and Tab completion, as plain logic (no widgets) so they are tested directly."""

from __future__ import annotations

import os
import re

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from stw_tui.sos.scene import Scene

_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_.]*$")


class History:
    """Commands typed at the console, browsed with up/down like a shell."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self._index = 0
        self._draft = ""

    def add(self, line: str) -> None:
        if line.strip() and (not self.lines or self.lines[-1] != line):
            self.lines.append(line)
        self._index = len(self.lines)

    def previous(self, current: str) -> str:
        """The line before the one shown (keeps what was being typed as a draft)."""
        if self._index == len(self.lines):
            self._draft = current
        self._index = max(0, self._index - 1)
        return self.lines[self._index] if self.lines else current

    def next(self) -> str:
        self._index = min(len(self.lines), self._index + 1)
        return self.lines[self._index] if self._index < len(self.lines) else self._draft


def scene_names(scene: "Scene | None") -> list[str]:
    """Every name a command may refer to."""
    if scene is None:
        return []
    return [*scene.dofs, *scene.constants, *scene.lets, *scene.derived, *scene.constraints,
            *scene.objectives, *scene.windows, *scene.verbs]


def candidates(text: str, scene: "Scene | None", backends: list[str] = ()) -> tuple[str, list[str]]:
    """What the last word of ``text`` could complete to.

    Returns:
        The partial word and the sorted, distinct candidates that start with it.
    """
    from stw_tui.sos.scene import DEFAULT_SETTINGS
    from stw_tui.sym.language import COMMAND_NAMES     # the core loads in the worker; see app.StwApp

    match = _WORD.search(text)
    partial = match.group(0) if match else ""
    if match is None and text and not text[-1].isspace():
        return "", []
    before = text[:len(text) - len(partial)].split()
    if not before or before == ["help"]:
        pool = list(COMMAND_NAMES)
    elif before[0] == "backend" and len(before) == 1:
        pool = list(backends)
    elif before[0] == "set" and len(before) == 1:
        pool = ["samples", *DEFAULT_SETTINGS]
    else:
        pool = scene_names(scene) + ["t", "pi"]
    found = sorted({name for name in pool if name.startswith(partial)})
    return partial, found


def complete(text: str, scene: "Scene | None", backends: list[str] = ()) -> tuple[str, list[str]]:
    """Complete the last word of ``text``.

    Returns:
        The new text (the unique completion plus a space, or the longest common prefix) and the
        candidates to list when there are several.
    """
    partial, found = candidates(text, scene, backends)
    if not found:
        return text, []
    stem = text[:len(text) - len(partial)]
    if len(found) == 1:
        return stem + found[0] + " ", []
    return stem + os.path.commonprefix(found), found
