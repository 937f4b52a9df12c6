"""Stick figures of a scene at one time, as plain geometry (the TUI draws them, `--json` lists them).

Linkages give segments (base → joints → tip). Point masses are found by name: a pair of DOF or
subexpressions ``<prefix>x`` and ``<prefix>y`` (or ``X``/``Y``), such as ``x, y``, ``cx, cy``,
``BX, BY`` or the mouse's ``mx, my``, is drawn as a dot labelled with the prefix. A subexpression
counts only if it is a position: a function of the DOF values, time and constants. One that uses a
velocity or an acceleration (``fx = m*x''``, point_mass_2d's thrust) is a force, a speed or a
momentum, whatever its name, and drawing it as a point would put a dot at "height" 9.81 and
squash the motion to the bottom of the plot. A scene with neither (the jet particle's lone ``x``)
is played as its first DOF's height (:func:`player_figure`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stw_tui.sos.scene import Scene
from stw_tui.sym.symbols import named_symbol


@dataclass
class Figure:
    """Segments and dots in the x–y plane (a side view; y is up)."""

    t: float
    segments: list[tuple[tuple[float, float], tuple[float, float]]] = field(default_factory=list)
    points: list[tuple[str, tuple[float, float]]] = field(default_factory=list)

    def bounds(self) -> tuple[float, float, float, float]:
        """The figure's extent (xmin, xmax, ymin, ymax), to fit it in a view."""
        xs = [p[0] for s in self.segments for p in s] + [p[1][0] for p in self.points]
        ys = [p[1] for s in self.segments for p in s] + [p[1][1] for p in self.points]
        if not xs:
            return (-1.0, 1.0, -1.0, 1.0)
        return (min(xs), max(xs), min(ys), max(ys))


def _value(scene: Scene, name: str, t: float) -> float:
    return float(scene.evaluate(named_symbol(name), np.array([t]))[0])


def _uses_motion(scene: Scene, expr, seen: set[str]) -> bool:
    """Whether ``expr`` depends on a velocity or acceleration: a primed symbol (``x'``, ``x''``,
    or ``f'`` of a subexpression), directly or through the subexpressions it names."""
    for symbol in expr.free_symbols:
        name = symbol.name
        if name.endswith("'"):
            return True
        definition = scene.lets.get(name, scene.derived.get(name))
        if definition is not None and name not in seen:
            seen.add(name)
            if _uses_motion(scene, definition, seen):
                return True
    return False


def point_pairs(scene: Scene) -> list[tuple[str, str, str]]:
    """(label, x name, y name) for every name pair that looks like a planar point: DOF, or
    subexpressions that are positions (they use no velocity or acceleration)."""
    names = list(scene.dofs) + [n for n in scene.lets if not _uses_motion(scene, scene.lets[n], {n})]
    forces = _force_dofs(scene)
    names = [n for n in names if n not in forces]
    pairs = []
    for name in names:
        for xs, ys in (("x", "y"), ("X", "Y")):
            if name.endswith(xs) and "." not in name:
                partner = name[:-1] + ys
                if partner in names:
                    pairs.append((name[:-1] or "•", name, partner))
    return pairs


def _force_dofs(scene: Scene) -> set[str]:
    """DOF that are forces, not places: a second foot's ground force (RX, RY: `contact … force=R`)
    loads the generalized forces of its creature (a load attachment reads it)."""
    from stw_tui.sos.attachments import all_attachments
    from stw_tui.sym.linkage import dof_names

    read = {s.name for p in all_attachments(scene) if p.adds for s in p.expr.free_symbols}
    moved = {n for spec in scene.linkages.values() for n in dof_names(spec)}
    return (read & set(scene.dofs)) - moved


def scene_figure(scene: Scene, t: float) -> Figure:
    """The stick figure of every linkage and point mass of ``scene`` at time ``t``."""
    from stw_tui.sym.linkage import dof_names, segments

    t = min(max(t, scene.t0), scene.t1)
    figure = Figure(t)
    for spec in scene.linkages.values():
        values = {n: _value(scene, n, t) for n in dof_names(spec)}
        for start, end in segments(spec, values, scene.constants):
            figure.segments.append(((float(start[0]), float(start[1])), (float(end[0]), float(end[1]))))
    for label, xn, yn in point_pairs(scene):
        figure.points.append((label, (_value(scene, xn, t), _value(scene, yn, t))))
    return figure


def player_figure(scene: Scene, t: float) -> Figure:
    """What the figure player draws at ``t``: :func:`scene_figure`, or, when that is empty, the
    first DOF as a dot at x = 0 and its value as the height."""
    figure = scene_figure(scene, t)
    if not figure.segments and not figure.points and scene.dofs:
        name = next(iter(scene.dofs))
        figure.points.append((name, (0.0, _value(scene, name, figure.t))))
    return figure
