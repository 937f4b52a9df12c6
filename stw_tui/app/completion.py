"""Console history and Tab completion, as plain logic (no widgets) so they are tested directly."""

from __future__ import annotations

import os
import re
from pathlib import Path

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from stw_tui.sos.scene import Scene

_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_.]*$")
# The word being typed as a path: a quoted one (may hold spaces, not closed yet) or a plain one.
_PATH_WORD = re.compile(r'(?:"[^"]*|[^\s"]*)$')


class History:
    """Commands typed at the console, browsed with up/down like a shell."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self._index = 0
        self._draft = ""

    def add(self, line: str) -> None:
        """Remember ``line`` (not blanks, not a repeat of the last one) and go back to the end."""
        if line.strip() and (not self.lines or self.lines[-1] != line):
            self.lines.append(line)
        self._index = len(self.lines)

    def extend(self, lines) -> None:
        """Remember earlier commands, oldest first (a resumed session's)."""
        for line in lines:
            self.add(line)

    def previous(self, current: str) -> str:
        """The line before the one shown (keeps what was being typed as a draft)."""
        if self._index == len(self.lines):
            self._draft = current
        self._index = max(0, self._index - 1)
        return self.lines[self._index] if self.lines else current

    def next(self) -> str:
        """The line after the one shown; past the newest, what was being typed."""
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

    path = _path_context(text)
    if path is not None:
        partial, suffix = path
        if suffix is None:
            from stw_tui.sym.language.session_commands import EXPORT_FORMATS
            return partial, [f for f in EXPORT_FORMATS if f.startswith(partial)]
        return partial, path_candidates(partial, suffix)
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
    if _path_context(text) is not None:
        return _complete_path(stem, found)
    if len(found) == 1:
        return stem + found[0] + " ", []
    return stem + os.path.commonprefix(found), found


# --- file paths after `open`, `save` and `export FORMAT` --------------------------------------
def _path_context(text: str) -> tuple[str, str | None] | None:
    """Whether the word being typed is a file path (or an export format).

    Returns:
        None when it is neither; else the partial word and the suffix of the files to list first
        (``.stw`` for `open` and `save`, ``.csv`` for `export csv`), or None as the suffix when
        the word is the format of `export`.
    """
    from stw_tui.sym.language.session_commands import EXPORT_FORMATS

    partial = _PATH_WORD.search(text).group(0)
    before = text[:len(text) - len(partial)]
    if before and not before[-1].isspace():
        return None
    words = before.split()
    if words in (["open"], ["save"], ["save", "--journal"]):
        return partial, ".stw"
    if words == ["export"]:
        return partial, None
    if len(words) == 2 and words[0] == "export" and words[1] in EXPORT_FORMATS:
        return partial, "." + words[1]
    return None


def path_candidates(partial: str, suffix: str = ".stw", cwd: str | Path | None = None) -> list[str]:
    """Files and directories whose path starts with ``partial``, as ``partial`` would be completed.

    Relative paths are read from ``cwd`` (the current directory by default), where the session
    opens them; ``~`` is expanded to look, and kept as typed. Directories end with ``/``. Files
    ending with ``suffix`` come first, then everything else, each group sorted; hidden entries are
    listed only when the name typed starts with a dot. A leading ``"`` (a path with spaces) is kept.

    Returns:
        The candidates, each the whole word to put in place of ``partial``; none when the directory
        cannot be read.
    """
    quote = '"' if partial.startswith('"') else ""
    typed = partial[len(quote):]
    if typed.startswith("~") and "/" not in typed:       # the home directory, not other users'
        return [quote + "~/"] if typed == "~" else []
    directory, slash, start = typed.rpartition("/")
    head = directory + slash
    where = Path(os.path.expanduser(head or "."))
    if not where.is_absolute() and cwd is not None:
        where = Path(cwd) / where
    try:
        entries = [(entry.name, entry.is_dir()) for entry in os.scandir(where)
                   if entry.name.startswith(start) and (start.startswith(".") or not entry.name.startswith("."))]
    except OSError:
        return []
    entries.sort(key=lambda e: (e[1] or not e[0].endswith(suffix), e[0]))
    found = [head + name + ("/" if is_dir else "") for name, is_dir in entries]
    if any(" " in path for path in found):
        quote = '"'             # all or none quoted, so their common prefix keeps what was typed
    return [quote + path for path in found]


def _complete_path(stem: str, found: list[str]) -> tuple[str, list[str]]:
    """Put the one path in (a file closes its quote and takes a space, a directory waits for
    more), or the longest common prefix, listing the names without their directory part."""
    if len(found) == 1:
        path = found[0]
        if path.endswith("/"):
            return stem + path, []
        return stem + path + ('" ' if path.startswith('"') else " "), []
    prefix = os.path.commonprefix(found)
    cut = prefix.rfind("/") + 1
    return stem + prefix, [path[cut:] for path in found]
