"""Motion verbs: a line an animator thinks in, expanded into ordinary named constraints and
objectives (which the journal does not keep: it keeps the verb, and replays it).

- ``hold P at arm.tip on [A, B]``: the object P (DOF PX, PY[, PZ]) is carried by a linkage point.
  It has the point's position and velocity exactly at A (picked up; unless A is the start) and
  at B (let go), and a tracking objective carries it in between. A constraint "P = point on
  [A, B]" could not hold between its samples (the point is trigonometry of the joint curves, P a
  cubic spline), and a ball tied only at samples leaves the hand with the wrong velocity.
- ``ballistic P on [A, B]``: free flight under g along -y: PX'' = 0, PY'' + g = 0 (PZ'' = 0),
  linear in the DOF, so it holds exactly everywhere on [A, B].
"""

from __future__ import annotations

from .errors import StwError

HOLD_WEIGHT = 1e4


def point_axes(scene, point: str) -> list[tuple[str, str]]:
    """[(axis, DOF)] of the point object ``point``: DOF PX, PY (and PZ), or Px, Py (and Pz)."""
    for x, y, z in (("X", "Y", "Z"), ("x", "y", "z")):
        if point + x in scene.dofs and point + y in scene.dofs:
            axes = [("x", point + x), ("y", point + y)]
            return axes + ([("z", point + z)] if point + z in scene.dofs else [])
    raise StwError(f"'{point}' is not a point object: declare its DOF first, e.g. `dof {point}X, {point}Y`")


def linkage_point(scene, at: str, axes: list[tuple[str, str]]) -> list[str]:
    """Names of the linkage point's coordinates, one per axis (``arm.tip`` -> arm.tip.x, …)."""
    names = [f"{at}.{axis}" for axis, _ in axes]
    missing = [n for n in names if n not in scene.derived]
    if missing:
        points = sorted({n.rsplit(".", 1)[0] for n in scene.derived if n.count(".") == 2})
        raise StwError(f"'{at}' is not a linkage point (points: {', '.join(points) or 'none; add a linkage'})")
    return names


def fresh_name(scene, base: str) -> str:
    """``base``, or ``base2``, ``base3``… when taken."""
    taken = set(scene.constraints) | set(scene.objectives) | set(scene.verbs)
    if scene.kind_of(base) is None and base not in taken:
        return base
    k = 2
    while scene.kind_of(f"{base}{k}") is not None or f"{base}{k}" in taken:
        k += 1
    return f"{base}{k}"


def _t(value: float) -> str:
    return repr(float(value))


def hold_lines(scene, point: str, at: str, a: float, b: float, weight: float | None) -> tuple[str, list[str]]:
    """(group name, command lines) of ``hold``."""
    axes = point_axes(scene, point)
    coords = linkage_point(scene, at, axes)
    group = fresh_name(scene, f"{point}_held")
    match = lambda: ", ".join([f"{dof} = {c}" for (_, dof), c in zip(axes, coords)]
                              + [f"{dof}' = {c}'" for (_, dof), c in zip(axes, coords)])
    lines = [f"objective {group}: " + ", ".join(f"{c} - {dof}" for (_, dof), c in zip(axes, coords))
             + f" on [{_t(a)}, {_t(b)}] weight={weight if weight is not None else HOLD_WEIGHT!r}"]
    if a > scene.t0:
        lines.append(f"constraint {fresh_name(scene, f'{point}_caught')}: {match()} @ {_t(a)}")
    if b < scene.t1:
        lines.append(f"constraint {fresh_name(scene, f'{point}_released')}: {match()} @ {_t(b)}")
    return group, lines


def ballistic_lines(scene, point: str, a: float, b: float) -> tuple[str, list[str]]:
    """(group name, command lines) of ``ballistic``."""
    axes = point_axes(scene, point)
    if "g" not in scene.constants:
        raise StwError("ballistic flight falls under g: declare it first, e.g. `const g = 9.81`")
    group = fresh_name(scene, f"{point}_flight")
    relations = [f"{dof}'' + g = 0" if axis == "y" else f"{dof}'' = 0" for axis, dof in axes]
    return group, [f"constraint {group}: {', '.join(relations)} on [{_t(a)}, {_t(b)}]"]
