"""Limits on what one line may ask for, as data.

Every size a command line can request (knot spans, samples, DOF, joints, expression size and
nesting, literal size, exponents, filter passes, iterations) has a documented limit here. Each is
checked *before* the work starts, and going over it is an error that names the limit, so no line
can hang the program or exhaust its memory. ``help limits`` lists them; ``set limit NAME VALUE``
changes one for the session, up to a hard ceiling that no session can raise.

A scene keeps its own overrides (``Scene.limits``, journalled like every other change); the
session makes them the *active* limits while it applies a line (:func:`active`), so the parser
and the compiler read them with :func:`value` without being handed the scene.
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Iterator, Mapping

from stw_tui.sym.errors import LimitError, StwError


@dataclass(frozen=True)
class Limit:
    """One limit: its default, the ceiling ``set limit`` may raise it to, what it bounds, and the
    floor it may not be lowered below (so that no value locks the session: `set limit` and `undo`
    must still parse)."""

    name: str
    default: int
    ceiling: int
    bounds: str
    floor: int = 1


LIMITS: dict[str, Limit] = {limit.name: limit for limit in (
    Limit("line_length", 10_000, 1_000_000, "characters in one command line (checked before parsing)", 200),
    Limit("nesting", 60, 100, "nesting levels of parentheses, calls, signs and powers in an expression", 10),
    Limit("digits", 300, 4_000, "digits of an integer literal", 20),
    Limit("number_bits", 8_192, 14_000, "bits of an exact number computed while parsing", 128),
    Limit("exponent", 1_000_000, 2**31 - 1, "magnitude of a numeric exponent (x^N, 10^N, 1.5^N)", 10),
    Limit("expression_size", 30_000, 2_000_000,
          "nodes of an expression once its subexpressions are substituted", 100),
    Limit("knots", 1_000, 20_000, "knot spans of one DOF (time/dof knots=, and after refine)"),
    Limit("samples", 5_000, 1_000_000, "constraint instances per animation span (samples=, set samples)"),
    Limit("dofs", 100, 2_000, "DOF in a scene (linkage joints included)"),
    Limit("joints", 6, 16, "joints of one linkage (its equations of motion grow ~4x a joint)"),
    Limit("filter_passes", 10_000, 1_000_000, "passes of one `filter`"),
    Limit("iterations", 1_000_000, 100_000_000, "iterations of one `iterate` (it reports each and can be stopped)"),
    Limit("adapt_rounds", 100, 10_000, "adaptive re-solves of one `iterate` (adapt=, adaptive_rounds)"),
    Limit("memory", 500, 1_000_000, "megabytes one command may allocate, estimated from its sizes before "
          "it starts (an `iterate`'s window problem and its solve)", 10),
)}

_ACTIVE: ContextVar[Mapping[str, int] | None] = ContextVar("stw_limits", default=None)


def value(name: str, overrides: Mapping[str, int] | None = None) -> int:
    """The limit ``name`` in force: from ``overrides`` (a scene's) if given, else the active
    scene's (see :func:`active`), else the default."""
    table = overrides if overrides is not None else (_ACTIVE.get() or {})
    return int(table.get(name, LIMITS[name].default))


def value_or_ceiling(name: str) -> int:
    """The limit in force while a line is applied; outside one (a front end drawing a curve of
    a term that a line already accepted) only the hard ceiling applies."""
    return value(name) if _ACTIVE.get() is not None else LIMITS[name].ceiling


@contextmanager
def active(overrides: Mapping[str, int]) -> Iterator[None]:
    """Make a scene's ``overrides`` the limits in force inside the block (this thread only)."""
    token = _ACTIVE.set(dict(overrides))
    try:
        yield
    finally:
        _ACTIVE.reset(token)


def over(name: str, requested: object, what: str | None = None,
         overrides: Mapping[str, int] | None = None) -> str:
    """The message for ``requested`` going over limit ``name``: names the limit and how to raise it."""
    limit, current = LIMITS[name], value(name, overrides)
    text = f"{what or limit.bounds} {requested} is over the limit {name} = {current}"
    if current < limit.ceiling:
        text += f" (`set limit {name} N` raises it, up to {limit.ceiling})"
    return text


def check(name: str, requested: int | float, what: str | None = None) -> None:
    """Raise StwError when ``requested`` exceeds the limit ``name`` in force.

    Raises:
        LimitError: naming the limit, its value and its ceiling.
    """
    if requested > value(name):
        raise LimitError(over(name, requested, what))


MB = 1_000_000


def check_memory(estimate: float, what: str, limit: int | None = None) -> None:
    """Refuse a command whose allocation ``estimate`` (bytes, worked out from its sizes before it
    allocates) is over the limit ``memory`` in force (megabytes; ``limit`` instead where given);
    outside a line's application only the ceiling holds (:func:`value_or_ceiling`).

    Raises:
        LimitError: with the estimate, the limit and how to raise it.
    """
    most = value_or_ceiling("memory") if limit is None else limit
    if estimate > most * MB:
        raise LimitError(over("memory", f"about {estimate / MB:,.0f} MB, which", what) + "; the scene is unchanged")


def validated(name: str, requested: int) -> int:
    """A new value for limit ``name`` (for ``set limit``), checked against its ceiling.

    Raises:
        StwError: unknown limit, or a value below its floor or over its ceiling.
    """
    if name not in LIMITS:
        raise StwError(f"unknown limit '{name}' (limits: {', '.join(LIMITS)})")
    limit = LIMITS[name]
    if not limit.floor <= requested <= limit.ceiling:
        raise StwError(f"limit {name} must be between its floor {limit.floor} and its ceiling {limit.ceiling}, "
                       f"not {requested}")
    return requested


def help_text(overrides: Mapping[str, int] | None = None) -> str:
    """A table of the limits: name, value in force, ceiling, and what each bounds."""
    values = dict(_ACTIVE.get() or {}) if overrides is None else dict(overrides)
    width = max(len(n) for n in LIMITS)
    lines = ["Limits (set limit NAME VALUE changes one, from its floor up to its ceiling):"]
    for limit in LIMITS.values():
        now = int(values.get(limit.name, limit.default))
        lines.append(f"  {limit.name:<{width}}  {now:>9}  (floor {limit.floor:>3}, ceiling {limit.ceiling:>10})"
                     f"  {limit.bounds}")
    return "\n".join(lines)
