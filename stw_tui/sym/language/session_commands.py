"""Commands on the session rather than the scene: history (`undo`, `redo`), named snapshots
(`snapshot`, `restore`, `snapshots`, `diff`), the symbolic console (`show`, `cse`), which only
reads the scene, and files (`export`, `save`).

The history and snapshot commands are parsed like every other command (see
:mod:`.commands`). `export` and `save` take a file path, which is not a token of the language
(``../out.csv``, ``~/motion.json``, a quoted name with spaces), so :func:`parse_file_command`
reads their line as plain text, never evaluating it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from stw_tui.sym.errors import SourceError, printable
from stw_tui.sym.language.survey_commands import SURVEY_PARSERS, AdoptCmd, SchedulerCmd, SurveyCmd, parse_scheduler_command

__all__ = ["UndoCmd", "RedoCmd", "SnapshotCmd", "RestoreCmd", "SnapshotsCmd", "DiffCmd", "ExportCmd",
           "SaveCmd", "ShowCmd", "CseCmd", "JournalCmd", "AcceptCmd", "RejectCmd", "OpenCmd", "SurveyCmd",
           "AdoptCmd", "SchedulerCmd", "SESSION_PARSERS", "FILE_COMMANDS", "EXPORT_FORMATS",
           "parse_file_command"]

EXPORT_FORMATS = ("csv", "json", "bvh")
MAX_FPS = 10_000


@dataclass(frozen=True)
class UndoCmd:
    """`undo`: take back the last command that changed the scene."""

    text: str = ""


@dataclass(frozen=True)
class RedoCmd:
    """`redo`: do again what `undo` took back."""

    text: str = ""


@dataclass(frozen=True)
class SnapshotCmd:
    """`snapshot NAME`: keep the scene as it is now under NAME."""

    name: str
    text: str = ""


@dataclass(frozen=True)
class RestoreCmd:
    """`restore NAME`: make the scene what it was at `snapshot NAME`."""

    name: str
    text: str = ""


@dataclass(frozen=True)
class SnapshotsCmd:
    """`snapshots`: list the snapshots with their objective and violation."""

    text: str = ""


@dataclass(frozen=True)
class DiffCmd:
    """`diff NAME`: compare the scene with snapshot NAME."""

    name: str
    text: str = ""


@dataclass(frozen=True)
class ExportCmd:
    """`export csv|json|bvh FILE [fps=N] [what=NAME,…] [overwrite]`: write the sampled motion to a file."""

    format: str          # one of EXPORT_FORMATS
    path: str
    fps: int = 30
    text: str = ""
    what: tuple[str, ...] = ()   # subexpressions to add as columns (tau_ELBOW, arm.tip.x')
    overwrite: bool = False      # replace FILE if it exists (else refused)
    line: int | None = None      # its line in a session file being replayed; None when typed


@dataclass(frozen=True)
class SaveCmd:
    """`save FILE [--journal] [overwrite]`: write the session so far as a replayable .stw file."""

    path: str
    text: str = ""
    overwrite: bool = False      # replace FILE if it exists (else refused)
    line: int | None = None      # its line in a session file being replayed; None when typed
    journal: bool = False        # the whole journal (failed lines, undo, print…), not the clean session


@dataclass(frozen=True)
class ShowCmd:
    """`show NAME` (what a definition is) or `show EXPR [@ T]` (its symbolic form, and value)."""

    name: str | None                # a constraint, objective, verb group, DOF, …; None: an expression
    expr: object = None             # sp.Expr of `show EXPR`
    expr_text: str = ""
    at: object = None               # sp.Expr of `@ T`, or None
    text: str = ""
    wrt: object = None              # `show diff(EXPR, VAR)`: the symbol (x, x', x'', t, a constant)


@dataclass(frozen=True)
class CseCmd:
    """`cse NAME|EXPR`: the common subexpressions the compiler shares in a term."""

    name: str | None
    expr: object = None
    expr_text: str = ""
    text: str = ""


@dataclass(frozen=True)
class JournalCmd:
    """`journal`: where this session's journal (and its checkpoints) are kept."""

    text: str = ""


@dataclass(frozen=True)
class OpenCmd:
    """`open FILE`: run a session file's lines as if typed (the session does it, see Session.execute)."""

    path: str
    text: str = ""


@dataclass(frozen=True)
class AcceptCmd:
    """`accept`: the proposed motion (`set preview on`) becomes the scene."""

    text: str = ""


@dataclass(frozen=True)
class RejectCmd:
    """`reject`: drop the proposed motion."""

    text: str = ""


# --- parsers of the token-based commands (called with the CommandParser) ----------------------
def _p_undo(p):
    return UndoCmd(p.text)


def _p_redo(p):
    return RedoCmd(p.text)


def _p_snapshot(p):
    return SnapshotCmd(p.name("a snapshot name").text, p.text)


def _p_restore(p):
    return RestoreCmd(p.name("a snapshot name").text, p.text)


def _p_snapshots(p):
    return SnapshotsCmd(p.text)


def _p_diff(p):
    return DiffCmd(p.name("a snapshot name").text, p.text)


def _name_or_expression(p):
    """(name, expr, expr_text): a lone name (a constraint, objective, verb, DOF, subexpression…)
    is kept as a name; anything else is read as an expression, as `print` reads it."""
    from stw_tui.sym.language.tokens import END, NAME

    first = p.token
    if first.kind == NAME and p.tokens[p.pos + 1].kind == END:
        p.advance()
        return first.text, None, first.text
    start = p.token.column
    expr = p.expression()
    return None, expr, printable(p.source[start - 1:p.token.column - 1].strip())


def _diff_call(p):
    """`diff(EXPR, VAR)`: (expr, VAR's symbol, text), VAR one DOF quantity (x, x', x''), t or a
    constant; or None when the line is not such a call."""
    from stw_tui.sym.language.tokens import NAME

    if not (p.token.kind == NAME and p.token.text == "diff" and p.tokens[p.pos + 1].is_op("(")):
        return None
    start = p.token.column
    p.advance()
    p.advance()
    expr = p.expression()
    p.expect_op(",", "',' and the variable to differentiate by")
    var_token = p.token
    var = p.expression()
    if not var.is_Symbol:
        raise p.error("diff differentiates by one variable", var_token,
                      expected="a DOF, its velocity or acceleration (x, x', x''), t or a constant")
    p.expect_op(")", "')'")
    return expr, var, printable(p.source[start - 1:p.token.column - 1].strip())


def _p_show(p):
    call = _diff_call(p)
    if call is not None:
        at = None
        if p.token.is_op("@"):
            p.advance()
            at = p.number_expr()
        return ShowCmd(None, call[0], call[2], at, p.text, call[1])
    name, expr, expr_text = _name_or_expression(p)
    at = None
    if name is None and p.token.is_op("@"):
        p.advance()
        at = p.number_expr()
    return ShowCmd(name, expr, expr_text, at, p.text)


def _p_cse(p):
    name, expr, expr_text = _name_or_expression(p)
    return CseCmd(name, expr, expr_text, p.text)


def _p_journal(p):
    return JournalCmd(p.text)


def _p_accept(p):
    return AcceptCmd(p.text)


def _p_reject(p):
    return RejectCmd(p.text)


def _p_file(p):   # reached only by a line like `export# …`: parse_file_command reads the others
    raise p.error("export and save need a file path after them", p.token,
                  expected="`export csv|json|bvh FILE` or `save FILE`")


SESSION_PARSERS = {"undo": _p_undo, "redo": _p_redo, "snapshot": _p_snapshot, "restore": _p_restore,
                   "snapshots": _p_snapshots, "diff": _p_diff, "export": _p_file, "save": _p_file,
                   "open": _p_file, "show": _p_show, "cse": _p_cse, "journal": _p_journal,
                   "accept": _p_accept, "reject": _p_reject, **SURVEY_PARSERS}
FILE_COMMANDS = ("export", "save", "open")
JOURNAL_FLAG = "--journal"   # `save FILE --journal`: everything, as the journal has it


# --- commands with a file path ---------------------------------------------------------------
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*'{0,2}")
_WORD = re.compile(r'\s*("(?P<quoted>[^"]*)"|(?P<plain>[^\s"#]+))')


def _error(message: str, text: str, line: int | None, column: int, expected: str | None = None):
    return SourceError(message, line=line, column=column, source=text, expected=expected)


def _words(text: str, line: int | None) -> list[tuple[str, int, bool]]:
    """(word, 1-based column, quoted) up to a comment; a quoted word may hold spaces and '#'."""
    words, pos = [], 0
    while pos < len(text):
        rest = text[pos:]
        if not rest.strip() or rest.lstrip().startswith("#"):
            break
        match = _WORD.match(text, pos)
        if match is None:
            column = pos + len(rest) - len(rest.lstrip()) + 1
            raise _error("a quoted path is not closed", text, line, column, expected='a closing "')
        quoted = match.group("quoted") is not None
        word = match.group("quoted") if quoted else match.group("plain")
        words.append((word, match.start(1) + 1, quoted))
        pos = match.end()
    return words


def _path(word: str, column: int, text: str, line: int | None) -> str:
    if not word:
        raise _error("the file path is empty", text, line, column, expected="a file path")
    if any(ord(c) < 32 or c == "\x7f" for c in word):
        raise _error("the file path holds a control character", text, line, column)
    return word


def parse_file_command(text: str, line: int | None = None):
    """Parse `export FORMAT FILE [fps=N] [what=NAME,…]`, `save FILE` or `open FILE`; None for any
    other command.

    Raises:
        SourceError: with line, column and what was expected.
    """
    scheduler = parse_scheduler_command(text, line)   # an address is not a token either
    if scheduler is not None:
        return scheduler
    first = text.split(None, 1)[:1]
    if not first or first[0] not in FILE_COMMANDS:
        return None
    words = _words(text, line)
    command_text = text.strip()
    (word, _, _), rest = words[0], words[1:]
    end = len(text.rstrip()) + 1
    overwrite = word in ("save", "export") and len(rest) > 1 and rest[-1][0] == "overwrite" and not rest[-1][2]
    if overwrite:
        rest = rest[:-1]
    journal = word == "save" and any(w == JOURNAL_FLAG and not quoted for w, _, quoted in rest)
    if journal:   # anywhere after `save` (a file of that name is quoted)
        rest = [w for w in rest if not (w[0] == JOURNAL_FLAG and not w[2])]
    if word in ("save", "open"):
        if not rest:
            raise _error(f"{word} needs a file", text, line, end, expected="a file path")
        if len(rest) > 1:
            raise _error(f"unexpected '{rest[1][0]}' after the file", text, line, rest[1][1],
                         expected="--journal, overwrite or end of line (quote a path with spaces)"
                         if word == "save" else "end of line (quote a path with spaces)")
        path = _path(rest[0][0], rest[0][1], text, line)
        if word == "save":
            return SaveCmd(path, command_text, overwrite, line, journal)
        return OpenCmd(path, command_text)
    if not rest or rest[0][0] not in EXPORT_FORMATS:
        at = rest[0][1] if rest else end
        got = f"unknown export format '{rest[0][0]}'" if rest else "export needs a format"
        raise _error(got, text, line, at, expected=" or ".join(EXPORT_FORMATS))
    if len(rest) < 2:
        raise _error("export needs a file", text, line, end, expected="a file path")
    fmt, (path, path_column, _) = rest[0][0], rest[1]
    fps, what = 30, ()
    for option, option_column, quoted in rest[2:]:
        key, _, value = option.partition("=")
        if quoted or key not in ("fps", "what"):
            raise _error(f"unexpected '{option}'", text, line, option_column,
                         expected="fps=N, what=NAME,… or overwrite (quote a path with spaces)")
        if key == "what":
            what = tuple(value.split(","))
            if not all(_NAME.fullmatch(n) for n in what):
                raise _error(f"what= takes names separated by commas, not '{value}'", text, line,
                             option_column + 5, expected="subexpression names, e.g. what=tau_ELBOW,f")
            continue
        if not (value.isascii() and value.isdigit() and len(value) <= 5 and 1 <= int(value) <= MAX_FPS):
            raise _error(f"fps must be a whole number from 1 to {MAX_FPS}, not '{value}'", text, line,
                         option_column + 4, expected="frames per second")
        fps = int(value)
    return ExportCmd(fmt, _path(path, path_column, text, line), fps, command_text, what, overwrite, line)
