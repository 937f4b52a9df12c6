"""User-facing errors. Every error the user can cause is a StwError with a clear message."""

from __future__ import annotations


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
        where = []
        if self.line is not None:
            where.append(f"line {self.line}")
        if self.column is not None:
            where.append(f"column {self.column}")
        text = self.message
        if self.expected:
            text += f" (expected {self.expected})"
        return f"{', '.join(where)}: {text}" if where else text

    def caret(self) -> str:
        """The source line with a caret under the offending column ('' if unknown)."""
        if self.source is None or self.column is None:
            return ""
        return f"{self.source}\n{' ' * (self.column - 1)}^"

    def at_line(self, line: int) -> "SourceError":
        """Copy of this error placed at a session line number."""
        return SourceError(self.message, line=line, column=self.column, source=self.source,
                           expected=self.expected)


class LimitError(StwError):
    """A line asked for more than a limit of stw_tui.limits allows (the message names the limit)."""


class SolveError(StwError):
    """A solve failed (non-finite values, backend exception); the scene was left as it was."""
