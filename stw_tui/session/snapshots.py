"""Measuring and comparing scenes, for `snapshots` and `diff NAME`.

A scene is measured as a solve over the window `all` would see it: the weighted objective
(quadrature over the whole animation), the largest constraint violation at the instances, and the
continuous-time check's largest violation between them (:func:`~stw_tui.sos.continuous.check_scene`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from stw_tui.sos.continuous import check_scene
from stw_tui.sos.scene import Scene
from stw_tui.sos.window import WindowProblem
from stw_tui.sym.errors import StwError

GRID_POINTS = 2001     # uniform points of the comparison grid, besides every knot and 8 per span
PER_SPAN = 8


@dataclass(frozen=True)
class Measures:
    """How good a scene's motion is; None where it cannot be measured (no DOF, a broken term)."""

    objective: float | None = None
    violation: float | None = None     # at the constraint instances
    dense: float | None = None         # anywhere (the continuous-time check)
    problem: str = ""                  # why it could not be measured

    def describe(self) -> str:
        """One line for `snapshots` and `diff`: objective and violations, or why not measurable."""
        if self.objective is None:
            return f"not measurable ({self.problem})" if self.problem else "not measurable"
        return (f"objective {self.objective:.6g}, max violation {self.violation:.2e} "
                f"(dense {self.dense:.2e})")


def measure(scene: Scene) -> Measures:
    """Objective and violations of the scene's current curves (nothing is solved)."""
    if not scene.dofs:
        return Measures(problem="no DOF")
    try:
        problem = WindowProblem(scene, "all")
        values = problem.merit_values(problem.initial())
        dense = check_scene(scene).dense_violation
    except StwError as exc:
        return Measures(problem=str(exc))
    violation = WindowProblem.max_violation(values)
    return Measures(float(values.objective), float(violation), float(max(dense, violation)))


@dataclass(frozen=True)
class DofChange:
    """How far one DOF's curve moved between a snapshot and now, and where."""

    name: str
    max_abs: float          # largest |new - old| of the curve on the comparison grid
    at: float | None        # where (None: it did not change)
    knots_changed: bool


@dataclass(frozen=True)
class SceneDiff:
    """What differs between a snapshot (old) and the scene now (new)."""

    dofs: list[DofChange]
    added_dofs: list[str]
    removed_dofs: list[str]
    changed: dict[str, list[str]]      # kind -> names added (+), removed (-) or changed (~)
    span: tuple[float, float]

    @property
    def changed_dofs(self) -> list[DofChange]:
        """The DOF whose curve or knots changed."""
        return [d for d in self.dofs if d.max_abs > 0 or d.knots_changed]


def comparison_grid(old_curve, new_curve, a: float, b: float) -> np.ndarray:
    """Uniform points, every knot of both curves, and PER_SPAN points in each span of either."""
    knots = np.unique(np.concatenate([old_curve.knots, new_curve.knots]))
    knots = knots[(knots >= a) & (knots <= b)]
    cuts = np.unique(np.concatenate([[a, b], knots]))
    fractions = np.linspace(0.0, 1.0, PER_SPAN + 1)
    spans = (cuts[:-1, None] + (cuts[1:] - cuts[:-1])[:, None] * fractions[None, :]).ravel()
    return np.unique(np.concatenate([np.linspace(a, b, GRID_POINTS), knots, spans]))


def _table_changes(old: dict, new: dict) -> list[str]:
    return ([f"+{n}" for n in new if n not in old] + [f"-{n}" for n in old if n not in new]
            + [f"~{n}" for n in new if n in old and new[n] != old[n]])


def diff_scenes(old: Scene, new: Scene) -> SceneDiff:
    """Compare two scenes: each common DOF's largest change over the span both cover, and which
    constants, definitions, windows and settings were added, removed or changed."""
    a, b = max(old.t0, new.t0), min(old.t1, new.t1)
    dofs = []
    for name in (n for n in new.dofs if n in old.dofs):
        c0, c1 = old.dofs[name].curve, new.dofs[name].curve
        knots_changed = not np.array_equal(np.asarray(c0.knots), np.asarray(c1.knots))
        if not knots_changed and np.array_equal(c0.coef, c1.coef):
            dofs.append(DofChange(name, 0.0, None, False))
            continue
        if not a < b:
            dofs.append(DofChange(name, float("inf"), None, knots_changed))
            continue
        grid = comparison_grid(c0, c1, a, b)
        delta = np.abs(c1.evaluate(grid) - c0.evaluate(grid))
        worst = int(np.argmax(delta))
        dofs.append(DofChange(name, float(delta[worst]), float(grid[worst]) if delta[worst] > 0 else None,
                              knots_changed))
    changed = {}
    for kind in ("constants", "lets", "constraints", "objectives", "windows", "settings", "extra_instances"):
        found = _table_changes(getattr(old, kind), getattr(new, kind))
        if found:
            changed[kind] = found
    for f in fields(Scene):
        if f.name in ("t0", "t1", "knots", "samples", "active_window", "backend", "backend_options"):
            if getattr(old, f.name) != getattr(new, f.name):
                changed.setdefault("scene", []).append(
                    f"~{f.name} {getattr(old, f.name)!r} -> {getattr(new, f.name)!r}")
    bounds = [f"~{n}" for n in new.dofs if n in old.dofs and
              (old.dofs[n].lo, old.dofs[n].hi, old.dofs[n].damp, old.dofs[n].keys)
              != (new.dofs[n].lo, new.dofs[n].hi, new.dofs[n].damp, new.dofs[n].keys)]
    if bounds:
        changed["dof bounds, damping or keys"] = bounds
    return SceneDiff(dofs, [n for n in new.dofs if n not in old.dofs],
                     [n for n in old.dofs if n not in new.dofs], changed, (a, b))


def describe_diff(name: str, d: SceneDiff, before: Measures, after: Measures) -> str:
    """The text of `diff NAME`: which DOF moved, what else changed, and both scenes' measures."""
    lines = [f"now against snapshot {name}:"]
    moved = d.changed_dofs
    if moved:
        for c in sorted(moved, key=lambda c: -c.max_abs):
            where = f" at t={c.at:.4g}" if c.at is not None else ""
            knots = " (knots changed)" if c.knots_changed else ""
            lines.append(f"  {c.name}: max |change| {c.max_abs:.3e}{where}{knots}")
    same = [c.name for c in d.dofs if c not in moved]
    if same:
        lines.append(f"  unchanged: {', '.join(same)}")
    if d.added_dofs:
        lines.append(f"  new DOF: {', '.join(d.added_dofs)}")
    if d.removed_dofs:
        lines.append(f"  DOF only in the snapshot: {', '.join(d.removed_dofs)}")
    for kind, names in d.changed.items():
        lines.append(f"  {kind}: {', '.join(names)}")
    lines.append(f"  before: {before.describe()}")
    lines.append(f"  now:    {after.describe()}")
    return "\n".join(lines)
