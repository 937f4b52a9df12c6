"""User-facing errors. Every error the user can cause is a StwError with a clear message."""

from __future__ import annotations

import unicodedata


def printable(text: str, *, newlines: bool = False) -> str:
    """``text`` safe to show on a terminal: control and other invisible characters (escape
    sequences, carriage returns, tabs, C1 controls such as U+009B, bidi overrides such as
    U+202E, lone surrogates) are written as escapes like \\x1b. Every echo of a command line,
    path, message or plugin text, in the TUI and headless, goes through here.

    Args:
        text: what is to be shown.
        newlines: keep line breaks (``\\n``) as they are, for text of several lines.
    """
    if text.isprintable():
        return text
    if newlines:
        return "\n".join(printable(line) for line in text.split("\n"))
    return "".join(c if c.isprintable() or (c == " ") else _escape(c) for c in text)


def _escape(c: str) -> str:
    if unicodedata.category(c) == "Cs":   # a lone surrogate cannot be encoded at all
        return f"\\u{ord(c):04x}"
    return c.encode("unicode_escape").decode("ascii")


class StwError(Exception):
    """Base class of all errors caused by user input or by a solve; the message is for the user."""


class SourceError(StwError):
    """An error located in a line of session text.

    Args:
        message: what is wrong, in words.
        line: 1-based line number in the session (None when typed at the console).
        column: 1-based column of the offending token.
        source: the text of the line, to draw a caret under the column.
        expected: what the parser expected instead, if known.
    """

    def __init__(self, message: str, *, line: int | None = None, column: int | None = None,
                 source: str | None = None, expected: str | None = None):
        self.message = message
        self.line = line
        self.column = column
        self.source = source
        self.expected = expected
        super().__init__(self.describe())

    def describe(self) -> str:
        """The message with where it happened and what was expected, safe to print."""
        where = []
        if self.line is not None:
            where.append(f"line {self.line}")
        if self.column is not None:
            where.append(f"column {self.column}")
        text = self.message
        if self.expected:
            text += f" (expected {self.expected})"
        return printable(f"{', '.join(where)}: {text}" if where else text)

    def caret(self) -> str:
        """The source line with a caret under the offending column ('' if unknown); control
        characters in the line are shown escaped, never sent to the terminal."""
        if self.source is None or self.column is None:
            return ""
        before = printable(self.source[:self.column - 1])
        return f"{printable(self.source)}\n{' ' * len(before)}^"

    def report(self, prefix: str) -> str:
        """What a command line prints: ``prefix: message``, then the caret lines when known."""
        caret = self.caret()
        return f"{prefix}: {self}" + (f"\n{caret}" if caret else "")

    def at_line(self, line: int) -> "SourceError":
        """Copy of this error placed at a session line number."""
        return SourceError(self.message, line=line, column=self.column, source=self.source,
                           expected=self.expected)


class LimitError(StwError):
    """A line asked for more than a limit of stw_tui.sym.limits allows (the message names the limit)."""


class SolveError(StwError):
    """A solve failed (non-finite values, backend exception); the scene was left as it was."""
