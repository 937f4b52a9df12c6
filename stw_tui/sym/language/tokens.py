"""Tokenizer of the session language. Nothing here evaluates text: tokens are plain data."""

from __future__ import annotations

import re
from dataclasses import dataclass

from stw_tui.sym.errors import SourceError

NUMBER, NAME, OP, END = "number", "name", "op", "end"

_TOKEN = re.compile(r"""
    (?P<space>[ \t\r]+)
  | (?P<comment>\#.*)
  | (?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)
  | (?P<op>\*\*|==|!=|>=|<=|''|[-+*/^()\[\],:@=<>'])
""", re.VERBOSE | re.ASCII)   # ASCII: \d must not match other scripts' digits


@dataclass(frozen=True)
class Token:
    """One token of a line: its kind (number, name, op or end), its text and its 1-based column."""

    kind: str
    text: str
    column: int  # 1-based

    def is_op(self, *ops: str) -> bool:
        """Whether this is one of the operators ``ops``."""
        return self.kind == OP and self.text in ops

    def is_word(self, *words: str) -> bool:
        """Whether this is a name and one of ``words`` (keywords such as ``on``, ``when``)."""
        return self.kind == NAME and self.text in words


def tokenize(text: str, *, line: int | None = None, column_offset: int = 0) -> list[Token]:
    """Split one line into tokens, ending with an END token.

    Raises:
        SourceError: a character the language does not use, or a name containing '__'.
    """
    tokens: list[Token] = []
    pos = 0
    while pos < len(text):
        match = _TOKEN.match(text, pos)
        column = column_offset + pos + 1
        if match is None:
            raise SourceError(f"unexpected character {text[pos]!r}", line=line, column=column,
                              source=text, expected="a name, number or operator")
        kind = match.lastgroup
        if kind == "comment":
            text = text[:pos]
            break
        if kind != "space":
            value = match.group()
            if kind == NAME and "__" in value:
                raise SourceError(f"names with '__' are not allowed ({value!r})", line=line,
                                  column=column, source=text)
            tokens.append(Token(kind, value, column))
        pos = match.end()
    tokens.append(Token(END, "", column_offset + len(text.rstrip()) + 1))
    return tokens


def strip_comment(text: str) -> str:
    """The line without its trailing comment and whitespace."""
    return text.split("#", 1)[0].rstrip()


@dataclass(frozen=True)
class CommandLine:
    """What a line of the session language is, told from its words alone: it never fails, so
    callers may classify lines that do not parse (a journal being replayed, a script's next line).

    ``words`` are the whitespace-separated words before any comment; ``verb`` is the first.
    """

    words: tuple[str, ...]

    @property
    def verb(self) -> str | None:
        """The command word (`iterate`, `linkage`, `end` …); None for a blank or comment line."""
        return self.words[0] if self.words else None

    @property
    def is_blank(self) -> bool:
        """Nothing but white space and a comment: nothing to run."""
        return not self.words


# First words of the commands that only read the scene and the session (queries), and of those
# that write files from it: neither kind changes the scene. Here, with the classifier, so the TUI
# can tell them apart before the solver stack is imported.
QUERIES = frozenset({"print", "help", "show", "cse", "journal", "snapshots", "diff"})
WRITERS = frozenset({"export", "save", "survey"})


def classify_line(text: str) -> CommandLine:
    """The :class:`CommandLine` of one line of text."""
    return CommandLine(tuple(strip_comment(text).split()))
