"""A second planted point: the end of a branch of a planar creature (a second foot) held on the
ground by construction, with the ground's force on it as curves of its own.

A creature hangs from its first contact (the root; stw_tui.session.verbs.contact_lines). A tree
cannot hang from two points, and constraints tying the second foot's trigonometry to a spot hold
only at their instances (it slides and sinks between them, and the ground works on it). So over
the stance the branch's last joints *are* what puts the foot there, as an attachment
(stw_tui.sos.attachments): the foot keeps its angle (a sole flat on the ground), which fixes the
ankle, and the two links above it (thigh and shin) reach from the hip to that ankle by the planar
two-link inverse kinematics, on the side the knee is bent to in the curves at the touchdown. With
a point foot (no sole) the point itself is the end of the two links. The foot cannot slide, sink
or turn, and the ground does no work on it.

The ground's force on that foot (FX, FY and, for a sole, its moment FM about the point) are DOF
the user declares; over the stance they load every generalized force by virtual work,
tau_u -= (dp/du).F + (dphi/du) FM, so ``tau_J`` stays the joint's own torque and the base's
forces (tau_X, tau_Y) the first contact's share. Push, friction cone and centre of pressure are
linear in them.
"""

from __future__ import annotations

import math

import numpy as np
import sympy as sp

from stw_tui.sym.errors import StwError

KNEE_MARGIN = 0.05   # rad: how far from straight (and from folded) the two links must stay
REACH_TOL = 1e-4     # m^2: the reach constraint's own continuous-time tolerance


def branch_link(spec, point: str):
    """(index of the link that ends at ``point``) or a clear error. The point is named by where
    the link ends: ``fig.RFOOT.end`` (a tree), or the next joint or ``tip`` (a chain)."""
    from stw_tui.sym.linkage import link_ends
    from stw_tui.sym.linkage.spec import parent_indices

    names = [j.name for j in spec.joints]
    for i, name in enumerate(names):
        if link_ends(spec, name)[1][0] == point:
            return i
    prefix = f"{spec.name}."
    if point.startswith(prefix) and point[len(prefix):] in names:
        i = names.index(point[len(prefix):])
        up = parent_indices(spec)[i]
        if up >= 0:
            return up
    ends = [link_ends(spec, n)[1][0] for n in names]
    raise StwError(f"'{point}' is not where a link of {spec.name} ends: plant the first joint "
                   f"({prefix}{names[0]}), or a second foot at a link's end ({', '.join(ends)})")


def _path(spec, index: int) -> list[int]:
    """The joints from the base to ``index``, in order."""
    from stw_tui.sym.linkage.spec import parent_indices

    up = parent_indices(spec)
    path = []
    while index >= 0:
        path.append(index)
        index = up[index]
    return path[::-1]


def _angle(spec, path: list[int]):
    """The absolute angle of the last link of ``path`` (planar: the sum of the angles on the way)."""
    from stw_tui.sym.symbols import dof_symbol

    return sum((dof_symbol(spec.joints[i].name) + spec.joints[i].theta for i in path), sp.S.Zero)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _nearest(value: float, target: float) -> float:
    """The multiple of 2 pi that brings ``value`` nearest ``target``."""
    return 2 * math.pi * round((target - value) / (2 * math.pi))


def _within_reach(scene, hip: str, ankle, up_len: float, low_len: float, a: float, b: float) -> np.ndarray:
    """The hip at the touchdown; or refuse a stance whose curves put the hip out of the two links'
    reach of the planted ankle: the inverse kinematics has no answer there (the motion would be
    undefined, not just bad)."""
    from stw_tui.sym.symbols import named_symbol

    times = np.linspace(a, b, 201)
    # read as inside the stance (a first foot's contact holds the base there, ends included)
    hx, hy = (scene.evaluator(named_symbol(f"{hip}.{axis}"), scope=(a, b))(times) for axis in "xy")
    span = np.hypot(ankle[0] - hx, ankle[1] - hy)
    lo, hi = abs(up_len - low_len), up_len + low_len
    bad = np.flatnonzero((span <= lo) | (span >= hi))
    if bad.size:
        k = bad[np.argmax(np.abs(span[bad] - (lo + hi) / 2))]
        raise StwError(f"at t = {times[k]:.4g} the curves put {hip} {span[k]:.4g} m from where the ankle is "
                       f"planted, out of reach of its two links ({lo:.4g} to {hi:.4g} m): sketch the "
                       f"stance with the hip within reach (the knee bent) first")
    return np.array([hx[0], hy[0]])


def branch_contact_lines(scene, spec, point: str, height: float, a: float, b: float,
                         friction: float, x: float | None, force: str | None,
                         angle: float | None, support, force_tol: float, moment_tol: float,
                         text_tol) -> tuple[str, list[str], tuple]:
    """(group name, command lines, attachments) of ``contact`` on the end of a branch."""
    from stw_tui.session.verb_text import fresh_name, friction_line, number_text as _t, pressure_line
    from stw_tui.sos.attachments import Attachment, all_attachments
    from stw_tui.sym.linkage import dof_names
    from stw_tui.sym.linkage.spec import parent_indices
    from stw_tui.sym.symbols import dof_symbol, named_symbol

    end = branch_link(spec, point)
    sole = support is not None
    path = _path(spec, end)
    if len(path) < (3 if sole else 2):
        raise StwError(f"plant {spec.name}.{spec.joints[0].name}, the first joint (the creature hangs from it); "
                       f"a second foot such as {point} is planted through the "
                       f"{'two links above its foot' if sole else 'two links that end there'} (hip and knee), "
                       f"and {spec.name} has {len(path)} link(s) from its base to it")
    if angle is not None and not sole:
        raise StwError(f"angle= is the angle a foot's sole keeps while planted, and {point} has no sole: "
                       f"give it one, support=[L, R] (metres along the ground about the point)")
    feet = path[-1:] if sole else []
    upper, lower = path[-3:-1] if sole else path[-2:]
    for i in path:
        j = spec.joints[i]
        if j.kind != "revolute" or j.alpha or j.d:
            raise StwError(f"a second planted point needs planar revolute links from the base to it "
                           f"(no alpha= or d=, no prismatic joint): {j.name} is not")
    for i in (upper, lower):
        if not spec.joints[i].a > 0:
            raise StwError(f"{spec.joints[i].name} must have a length a > 0 to reach the planted point")
    if any(ax.kind != "prismatic" for ax in spec.base) or "tx" not in {ax.axis for ax in spec.base}:
        raise StwError(f"a second planted point needs a base of translations along x and y: "
                       f"give {spec.name} `base=tx:X,ty:Y`")
    if x is None:
        raise StwError(f"x=X0 says where {point} is planted: give it, e.g. `x=0`")
    if force is None:
        raise StwError(f"{point} is not {spec.name}'s first joint, from which the creature hangs: the "
                       f"ground's force on it needs curves of its own, force=F for DOF FX, FY"
                       f"{', FM' if sole else ''} (declare them first, e.g. `dof FX, FY{', FM' if sole else ''}`)")
    lo, hi = support if sole else (0.0, 0.0)
    if not lo <= hi:
        raise StwError(f"support [{lo:g}, {hi:g}] is empty: its start must not be after its end")
    needs = [force + "X", force + "Y"] + ([force + "M"] if lo < hi else [])
    missing = [n for n in needs if n not in scene.dofs]
    if missing:
        raise StwError(f"force={force} names the ground's force on {point} as DOF {', '.join(needs)}: declare "
                       f"{', '.join(missing)} first, e.g. `dof {', '.join(needs)}`")
    taken = set(dof_names(spec))
    if taken & set(needs):
        raise StwError(f"force={force}: {', '.join(sorted(taken & set(needs)))} moves {spec.name}; name "
                       f"the force's DOF apart from the creature's")
    joints = [spec.joints[i].name for i in (upper, lower, *feet)]
    for part in all_attachments(scene):
        if (part.target in joints or part.target in needs) and part.a < b and a < part.b:
            raise StwError(f"{part.target} is already attached on [{part.a:g}, {part.b:g}], which overlaps "
                           f"[{a:g}, {b:g}]")

    # The curves at the touchdown: which side the knee bends to, the angles' branches (2 pi k).
    now = {spec.joints[i].name: float(scene.dof_values(spec.joints[i].name, [a])[0]) for i in path}
    numeric = lambda e: float(e.subs({dof_symbol(n): v for n, v in now.items()}))
    hip = f"{spec.name}.{spec.joints[upper].name}"
    parent_angle = _angle(spec, path[:path.index(upper)])
    up_len, low_len = spec.joints[upper].a, spec.joints[lower].a
    if sole:
        foot = spec.joints[feet[0]]
        phi = numeric(_angle(spec, path)) if angle is None else float(angle)
        ankle = (x - foot.a * math.cos(phi), height - foot.a * math.sin(phi))
    else:
        phi, ankle = None, (x, height)
    h = _within_reach(scene, hip, ankle, up_len, low_len, a, b)
    ref = math.atan2(ankle[1] - h[1], ankle[0] - h[0])
    bend = _wrap(numeric(_angle(spec, path[:path.index(upper) + 1])) - numeric(_angle(spec, path[:path.index(lower) + 1])))
    side = 1.0 if bend >= 0 else -1.0

    hx, hy = named_symbol(f"{hip}.x"), named_symbol(f"{hip}.y")
    dx, dy = sp.Float(ankle[0]) - hx, sp.Float(ankle[1]) - hy
    d2 = dx ** 2 + dy ** 2
    c, s = sp.Float(math.cos(ref)), sp.Float(math.sin(ref))
    towards = sp.Float(ref) + sp.atan2(c * dy - s * dx, c * dx + s * dy)   # its cut opposite ref
    at_hip = sp.acos((up_len ** 2 + d2 - low_len ** 2) / (2 * up_len * sp.sqrt(d2)))
    at_knee = sp.acos((up_len ** 2 + low_len ** 2 - d2) / (2 * up_len * low_len))
    up_phi = towards + side * at_hip
    low_phi = up_phi - side * (sp.pi - at_knee)
    targets = [(spec.joints[upper], up_phi - parent_angle), (spec.joints[lower], low_phi - up_phi)]
    if sole:
        targets.append((foot, sp.Float(phi) - low_phi))
    closed = {"closed_a": a <= scene.t0, "closed_b": b >= scene.t1}
    label = (f"{', '.join(joints)} put {point} at ({x:g}, {height:g})"
             + (f" with {spec.joints[feet[0]].name} at {phi:.6g} rad" if sole else "")
             + f" (two-link inverse kinematics, bent {'counterclockwise' if side > 0 else 'clockwise'})")
    parts = []
    for joint, expr in targets:
        expr = expr - joint.theta
        expr = expr + _nearest(numeric(expr.subs({hx: h[0], hy: h[1]})), now[joint.name])
        parts.append(Attachment(joint.name, expr, a, b, note=label, **closed))

    # The ground's force and moment load every coordinate by virtual work.
    fx, fy = dof_symbol(force + "X"), dof_symbol(force + "Y")
    moment = (dof_symbol(force + "M") if lo < hi else sp.Float(lo) * fy) if sole else sp.S.Zero
    px, py = scene.derived[f"{point}.x"], scene.derived[f"{point}.y"]
    turning = {spec.joints[i].name for i in path}
    for u in dof_names(spec):
        q = dof_symbol(u)
        load = -(sp.diff(px, q) * fx + sp.diff(py, q) * fy + (moment if u in turning else 0))
        if load != 0:
            parts.append(Attachment(f"tau_{u}", load, a, b, adds=True, **closed))

    short = point.split(".")[1]
    on = f"on [{_t(a)}, {_t(b)}]"
    theta = sum(spec.joints[i].theta for i in path)
    turn = " + ".join(spec.joints[i].name for i in path)
    rest = [f"{point}.x = {x!r}", f"{point}.y = {height!r}", f"{point}.x' = 0", f"{point}.y' = 0"]
    if sole:
        level = phi - theta
        rest += [f"{turn} = {level + _nearest(level, sum(now[spec.joints[i].name] for i in path))!r}",
                 " + ".join(f"{spec.joints[i].name}'" for i in path) + " = 0"]
    lines = []
    if a > scene.t0:
        lines.append(f"constraint {fresh_name(scene, f'{short}_touchdown')}: {', '.join(rest)} @ {_t(a)}")
    if b < scene.t1:
        lines.append(f"constraint {fresh_name(scene, f'{short}_liftoff')}: {', '.join(rest)} @ {_t(b)}")
    # the two links stay between folded and straight, where the inverse kinematics has a slope
    span = f"({ankle[0]!r} - {hip}.x)^2 + ({ankle[1]!r} - {hip}.y)^2"
    near = up_len ** 2 + low_len ** 2 + 2 * up_len * low_len * math.cos(KNEE_MARGIN)
    far = up_len ** 2 + low_len ** 2 - 2 * up_len * low_len * math.cos(KNEE_MARGIN)
    lines.append(f"constraint {fresh_name(scene, f'{short}_reach')}: {near!r} - ({span}) >= 0, "
                 f"{span} - {far!r} >= 0 {on}{text_tol(REACH_TOL)}")
    fxn, fyn = force + "X", force + "Y"
    lines.append(f"constraint {fresh_name(scene, f'{short}_push')}: {fyn} >= 0 {on}{text_tol(force_tol)}")
    lines.append(friction_line(scene, short, fyn, fxn, friction, on, force_tol))
    if sole and lo < hi:
        lines.append(pressure_line(scene, short, force + "M", fyn, lo, hi, on, moment_tol))
    return fresh_name(scene, f"{short}_contact"), lines, tuple(parts)
