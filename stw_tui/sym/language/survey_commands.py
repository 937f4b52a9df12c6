"""The survey commands: `survey N [option=value…]`, `adopt K` and `set scheduler ADDRESS`.

`survey` and `adopt` are parsed with the command parser like the others. A scheduler address
(``tcp://10.0.0.5:8786``) is not a token of the language, so :func:`parse_scheduler_command`
reads `set scheduler …` as plain text, with a regular expression, never evaluating it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import sympy as sp

from stw_tui.sym.errors import SourceError
from stw_tui.sym.language.tokens import NAME

SOURCES = ("shake", "sketch", "random")     # as stw_tui.session.survey.SOURCES (the core imports nothing here)
MAX_STARTS = 100_000
MAX_WORKERS = 4096
MAX_SEED = 2**63 - 1
SURVEY_OPTIONS = ("seed", "from", "amplitude", "window", "workers", "iterate")


@dataclass(frozen=True)
class SurveyCmd:
    """`survey N [OPTION=VALUE…]`: solve N starts made from the scene and rank their optima."""

    n: int
    seed: int = 0
    source: str = "shake"
    amplitude: sp.Expr | None = None
    window: str | None = None
    workers: int | None = None
    iterations: int | None = None
    text: str = ""


@dataclass(frozen=True)
class AdoptCmd:
    """`adopt K`: make optimum K of the last survey the scene."""

    rank: int
    text: str = ""


@dataclass(frozen=True)
class SchedulerCmd:
    """`set scheduler ADDRESS`: where `survey` sends its starts."""

    address: str           # a Dask scheduler; "pool", "serial", "batch"; or "" (local: Dask's LocalCluster, else a pool)
    text: str = ""
    line: int | None = None   # its line in a session file or journal being replayed; None when typed

    @property
    def remote(self) -> bool:
        """Whether the address is a cluster's (one that runs code in this process), not this machine."""
        return self.address not in ("", *LOCAL_SCHEDULERS)


def p_survey(p) -> SurveyCmd:
    """`survey N [seed=S] [from=shake|sketch|random] [amplitude=A] [window=W] [workers=K] [iterate=M]`."""
    n = p.integer("a number of starts", MAX_STARTS)
    if n < 1:
        raise p.error("a survey needs at least one start", p.tokens[p.pos - 1], expected="N >= 1")
    found: dict[str, object] = {}
    while p.token.kind == NAME:
        key = p.token
        if key.text not in SURVEY_OPTIONS:
            raise p.error(f"unknown survey option '{key.text}'", key,
                          expected=", ".join(f"{o}=" for o in SURVEY_OPTIONS))
        if key.text in found:
            raise p.error(f"'{key.text}' given twice", key)
        p.advance()
        p.expect_op("=", f"'=' after {key.text}")
        found[key.text] = _option_value(p, key.text)
    return SurveyCmd(n, found.get("seed", 0), found.get("from", "shake"), found.get("amplitude"),
                     found.get("window"), found.get("workers"), found.get("iterate"), p.text)


def _option_value(p, key: str):
    if key == "seed":
        return p.integer("a whole number for seed", MAX_SEED)
    if key == "amplitude":
        return p.number_expr()
    if key == "workers":
        token = p.token
        value = p.integer("a number of worker processes", MAX_WORKERS)
        if value < 1:
            raise p.error("workers must be at least 1", token, expected="K >= 1")
        return value
    if key == "iterate":
        return p.integer("a number of iterations per start", limit_name="iterations")
    token = p.name("a window name" if key == "window" else " or ".join(SOURCES))
    if key == "from" and token.text not in SOURCES:
        raise p.error(f"from={token.text}: a start comes from {', '.join(SOURCES)}", token,
                      expected=" or ".join(SOURCES))
    return token.text


def p_adopt(p) -> AdoptCmd:
    """`adopt K`, with K a rank of the last survey (from 1)."""
    token = p.token
    rank = p.integer("the rank of an optimum of the last survey", MAX_STARTS)
    if rank < 1:
        raise p.error("ranks start at 1", token, expected="K >= 1")
    return AdoptCmd(rank, p.text)


# host: a name, an IPv4 address or a bracketed IPv6 address; then a port
_ADDRESS = re.compile(r"(tcp|tls)://([A-Za-z0-9.-]+|\[[0-9A-Fa-f:]+\]):([0-9]{1,5})\Z")
# local: an embedded Dask cluster (a process pool without Dask); pool: a process pool even with
# Dask; serial: one start after another in this process (to debug, and the benchmark's baseline);
# batch: the starts as one batch on the torch backend (vectorized over starts; cuda when there is one)
LOCAL_SCHEDULERS = ("local", "pool", "serial", "batch")
_SET_SCHEDULER = re.compile(r"\s*set\s+scheduler(?=\s|#|\Z)")


def parse_scheduler_command(text: str, line: int | None = None) -> SchedulerCmd | None:
    """`set scheduler tcp://HOST:PORT|local|pool|serial|batch`; None for any other line.

    Raises:
        SourceError: a malformed address, with its column.
    """
    match = _SET_SCHEDULER.match(text)
    if match is None:
        return None
    rest = text[match.end():].split("#", 1)[0]
    words = rest.split()
    column = match.end() + len(rest) - len(rest.lstrip()) + 1
    expected = "tcp://HOST:PORT (a Dask scheduler), local, pool, serial or batch"
    if len(words) != 1:
        raise SourceError("set scheduler needs one address" if not words else
                          f"unexpected '{words[1]}' after the address", line=line, column=column,
                          source=text, expected=expected)
    address = words[0]
    if address in LOCAL_SCHEDULERS:
        return SchedulerCmd("" if address == "local" else address, text.strip(), line)
    found = _ADDRESS.fullmatch(address)
    if found is None or not 0 < int(found.group(3)) < 65536:
        raise SourceError(f"'{address[:60]}' is not a scheduler address", line=line, column=column,
                          source=text, expected=expected)
    return SchedulerCmd(address, text.strip(), line)


SURVEY_PARSERS = {"survey": p_survey, "adopt": p_adopt}
