"""How motion verbs write the lines they generate: names not yet taken, times and tolerances as
session text (stw_tui.session.verbs, stw_tui.session.planted_branch)."""

from __future__ import annotations


def fresh_name(scene, base: str) -> str:
    """``base``, or ``base2``, ``base3``… when taken."""
    taken = set(scene.constraints) | set(scene.objectives) | set(scene.verbs)
    if scene.kind_of(base) is None and base not in taken:
        return base
    k = 2
    while scene.kind_of(f"{base}{k}") is not None or f"{base}{k}" in taken:
        k += 1
    return f"{base}{k}"


def number_text(value: float) -> str:
    """A time or value as session text, exactly (its repr)."""
    return repr(float(value))


def tolerance_text(dense_tol: float | None) -> str:
    """A generated constraint's own continuous-time tolerance, as its line states it."""
    return f" dense_tol={float(dense_tol):.6g}" if dense_tol is not None else ""
