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


def friction_line(scene, short: str, normal: str, tangent: str, friction: float, on: str, tol) -> str:
    """A contact's friction cone, MU*N - T >= 0 and MU*N + T >= 0, as a constraint line."""
    return (f"constraint {fresh_name(scene, f'{short}_friction')}: {friction!r}*{normal} - {tangent} >= 0, "
            f"{friction!r}*{normal} + {tangent} >= 0 {on}{tolerance_text(tol)}")


def pressure_line(scene, short: str, moment: str, normal: str, lo: float, hi: float, on: str, tol) -> str:
    """A contact's centre of pressure on the sole [lo, hi] about its point, lo*N <= M <= hi*N, as
    a constraint line (a term of 0*N left out: -M >= 0 reads better)."""
    heel = f"{moment} + {-lo!r}*{normal}" if lo < 0 else f"{moment} - {lo!r}*{normal}" if lo > 0 else moment
    toe = f"{hi!r}*{normal} - {moment}" if hi != 0 else f"-{moment}"
    return f"constraint {fresh_name(scene, f'{short}_pressure')}: {heel} >= 0, {toe} >= 0 {on}{tolerance_text(tol)}"
