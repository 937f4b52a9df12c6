"""Motion verbs: a line an animator thinks in, expanded into ordinary named constraints and
objectives (which the journal does not keep: it keeps the verb, and replays it). The scene keeps
each as a group (``scene.verbs``: name -> its line and what it made): `delete NAME` removes it
whole, and no part of it is deleted or redefined alone (:func:`owned_by_verb`).

- ``hold P at arm.tip on [A, B] [mass=M]``: the object P (DOF PX, PY[, PZ]) is the linkage point
  while held: every expression reads PX as arm.tip.x there (stw_tui.sos.attachments), so it is in
  the hand at every time, not at samples. Its own curve meets the point's position and velocity
  exactly at A (caught; unless A is the start) and at B (let go). Its mass loads the linkage's
  generalized forces while held. (A constraint "P = point on [A, B]" could not hold between its
  samples: the point is trigonometry of the joint curves, P a cubic spline.)
- ``ballistic P on [A, B]``: free flight under g along -y: PX'' = 0, PY'' + g = 0 (PZ'' = 0),
  linear in the DOF, so it holds exactly everywhere on [A, B].
- ``contact acro.FOOT on ground [y=H] on [A, B] x=X0 [friction=MU] [support=[L, R]]``: the point
  is planted at (X0, H) by construction: over the stance the base DOF (CX, CY with ``com=``) are
  attached to where the point stays, so the creature hangs from it (stw_tui.sos.attachments), and
  the point cannot slide, sink or move. Their own curves (the flight's) meet it at rest at the
  touchdown and the lift-off. The ground's force on a creature with a free base is the
  generalized force of the base's translations (tau_X, tau_Y): whatever else acts inside, only
  external forces move the base. So the push is ``tau_Y >= 0``, the friction cone
  ``MU*tau_Y >= |tau_X|`` (MU = 1 by default) and the centre of pressure ``L*tau_Y <= tau_FOOT <=
  R*tau_Y`` (a point foot by default: no moment). They hold at instances, and between them to 1%
  of the creature's weight (and weight x size for the moment), or to dense_tol=D.
- ``flight acro on [A, B]``: nothing outside acts on the creature: the generalized forces of its
  base DOF vanish (``acro_flight``; linear and exact with ``com=``), and so do the torques of the
  joints that hang the first massive link on the base, which has nothing to push against in the
  air unless it has an inertia, base_inertia= (``acro_spin``: to 1% of weight x size between
  instances, or dense_tol=D).
- ``avoid fig.LARM fig.TRUNK [by=D]`` / ``avoid fig.LARM ground [y=H] [by=D]``: two links (or a
  link and the ground) kept at least D apart: each end of one stays D from the other link, ends
  they share left out (``LARM_TRUNK_apart``), held between instances to 1 mm or dense_tol=E.
"""

from __future__ import annotations

import math

from stw_tui.session.verb_text import (fresh_name, friction_line, number_text as _t, pressure_line,
                                      tolerance_text as _tol)
from stw_tui.sym.errors import StwError


def verb_of(scene, name: str) -> str | None:
    """The verb group that made the constraint or objective ``name`` (None: one written by hand)."""
    return next((group for group, (_, members) in scene.verbs.items() if name in members), None)


def owned_by_verb(scene, name: str) -> str:
    """Why ``name`` cannot be deleted or redefined on its own: a verb made it ("" when no verb did).

    A verb is one journal line and one group: deleting or redefining one of its parts would leave
    a `hold` that no longer holds, and its heading in the Eqns panel and `show` would say otherwise.
    """
    group = verb_of(scene, name)
    if group is None:
        return ""
    line = scene.verbs[group][0]
    return (f"'{name}' is part of the verb `{line}` (group {group}): `delete {group}` removes the "
            f"whole group; to change one part, delete the group and write its lines by hand "
            f"(`show {group}` prints them), or `weight {name} W` to reweigh it")


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


def hold_lines(scene, point: str, at: str, a: float, b: float,
               mass: float | None = None) -> tuple[str, list[str], tuple[Attachment, ...]]:
    """(group name, command lines, attachments) of ``hold``: while held the object is the point
    (each of its DOF attached to the point's coordinate), caught and let go with the point's
    position and velocity, and its mass (if any) loads the holder's generalized forces."""
    from stw_tui.sos.attachments import Attachment, all_attachments
    from stw_tui.sym.symbols import dof_symbol, named_symbol

    axes = point_axes(scene, point)
    coords = linkage_point(scene, at, axes)
    dofs = {dof for _, dof in axes}
    if any(dof_symbol(d, k) in scene.expand(named_symbol(c)).free_symbols for c in coords for d in dofs
           for k in range(3)):
        raise StwError(f"{at} moves with {point} itself: an object cannot hold itself")
    for part in all_attachments(scene):
        if part.target in dofs and part.a < b and a < part.b:
            raise StwError(f"{point} is already held on [{part.a:g}, {part.b:g}], which overlaps [{a:g}, {b:g}]")
    if mass is not None and not mass >= 0:
        raise StwError(f"the held mass {mass:g} must be at least 0")
    group = fresh_name(scene, f"{point}_held")
    closed = {"closed_a": a <= scene.t0, "closed_b": b >= scene.t1}
    parts = [Attachment(dof, named_symbol(c), a, b, **closed) for (_, dof), c in zip(axes, coords)]
    if mass:
        parts += [Attachment(f"tau_{u}", load, a, b, adds=True, **closed)
                  for u, load in _point_mass_loads(scene, at, coords, mass)]
    match = lambda: ", ".join([f"{dof} = {c}" for (_, dof), c in zip(axes, coords)]
                              + [f"{dof}' = {c}'" for (_, dof), c in zip(axes, coords)])
    lines = []
    if a > scene.t0:
        lines.append(f"constraint {fresh_name(scene, f'{point}_caught')}: {match()} @ {_t(a)}")
    if b < scene.t1:
        lines.append(f"constraint {fresh_name(scene, f'{point}_released')}: {match()} @ {_t(b)}")
    return group, lines, tuple(parts)


def _point_mass_loads(scene, at: str, coords: list[str], mass: float) -> list[tuple]:
    """[(u, Q_u)]: the generalized force a point mass at ``at`` asks of each coordinate u of its
    linkage (base variables, then joints), by virtual work: Q_u = m (dp/du) . (p'' - gravity).
    The partials are taken of the linkage's own point expressions, in its own coordinates (with
    ``com=`` the base variables are subexpressions, and dp/dX must hold the joints, not the
    centre of mass, fixed)."""
    import sympy as sp

    from stw_tui.sym.linkage import dof_names
    from stw_tui.sym.symbols import dof_symbol, named_symbol

    spec = scene.linkages[at.split(".")[0]]
    g = named_symbol("g")
    loads = []
    for u in dof_names(spec):
        q = dof_symbol(u)
        total = sp.S.Zero
        for c in coords:
            axis = "xyz".index(c.rsplit(".", 1)[1])
            gravity = spec.gravity_sign * g if spec.gravity_axis == axis else 0
            total += sp.diff(scene.derived[c], q) * (named_symbol(c + "''") - gravity)
        loads.append((u, sp.Float(mass) * total))
    return loads


def ballistic_lines(scene, point: str, a: float, b: float) -> tuple[str, list[str]]:
    """(group name, command lines) of ``ballistic``."""
    axes = point_axes(scene, point)
    if "g" not in scene.constants:
        raise StwError("ballistic flight falls under g: declare it first, e.g. `const g = 9.81`")
    group = fresh_name(scene, f"{point}_flight")
    relations = [f"{dof}'' + g = 0" if axis == "y" else f"{dof}'' = 0" for axis, dof in axes]
    return group, [f"constraint {group}: {', '.join(relations)} on [{_t(a)}, {_t(b)}]"]


def _free_linkage(scene, name: str, what: str):
    """The linkage ``name``, which must have a free base (a creature that can leave the ground)."""
    spec = scene.linkages.get(name)
    if spec is None:
        known = ", ".join(scene.linkages) or "none; add a linkage"
        raise StwError(f"'{name}' is not a linkage (linkages: {known})")
    if not spec.base:
        raise StwError(f"linkage {name} has a fixed base: {what} needs a free one, "
                       f"e.g. `linkage {name} base=tx:X,ty:Y`")
    return spec


def physical_scale(scene, spec) -> tuple[float, float]:
    """(weight in N, size in m) of a creature: what its default tolerances are fractions of (1% of
    its weight for forces, 1% of weight x size for moments). The size is its reach, the sum of
    its links' lengths and offsets."""
    mass = sum(j.mass for j in spec.joints) + spec.base_mass
    size = sum(abs(j.a) + abs(j.d) for j in spec.joints) or 1.0
    return mass * float(scene.constants.get("g", 9.81)), size


def contact_lines(scene, point: str, height: float, a: float, b: float,
                  friction: float | None, x: float | None, dense_tol: float | None = None,
                  support: tuple[float, float] | None = None, force: str | None = None,
                  angle: float | None = None) -> tuple[str, list[str], tuple]:
    """(group name, command lines, attachments) of ``contact``: the point is planted by
    construction (the creature hangs from it: its base is attached to where the point stays),
    it meets the ground at rest and leaves it at rest (its own curves match position and
    velocity at the switches), and the ground only pushes, within the friction cone, with its
    centre of pressure on the support."""
    import sympy as sp

    from stw_tui.sos.attachments import Attachment, all_attachments
    from stw_tui.sym.symbols import dof_symbol, named_symbol

    spec = _free_linkage(scene, point.split(".")[0], "a contact with the ground")
    if f"{point}.y" not in scene.derived:
        points = sorted({n.rsplit(".", 1)[0] for n in scene.derived if n.startswith(spec.name + ".")})
        raise StwError(f"'{point}' is not a point of linkage {spec.name} (points: {', '.join(points)})")
    if (spec.gravity_axis, spec.gravity_sign) != (1, -1):
        raise StwError(f"the ground is y = H under gravity along -y; linkage {spec.name} falls along "
                       f"{'none' if spec.gravity_axis is None else 'xyz'[spec.gravity_axis]}")
    axes = {axis.axis: axis.dof for axis in spec.base}
    if "ty" not in axes:
        raise StwError(f"the ground pushes linkage {spec.name} up through a base translation along y, "
                       f"and it has none: give it one, e.g. `base=tx:X,ty:Y`")
    if "tz" in axes:
        raise StwError(f"contact plants a point of a planar creature; linkage {spec.name} moves along z")
    friction = 1.0 if friction is None else friction
    if not friction >= 0:
        raise StwError(f"friction coefficient {friction:g} must be at least 0")
    weight, size = physical_scale(scene, spec)
    force_tol = dense_tol if dense_tol is not None else 0.01 * weight
    moment_tol = (dense_tol if dense_tol is not None else 0.01 * weight) * size
    if point != f"{spec.name}.{spec.joints[0].name}" or force is not None:
        # not where the creature hangs from: a second foot, planted through its branch's joints
        from stw_tui.session.planted_branch import branch_contact_lines

        return branch_contact_lines(scene, spec, point, height, a, b, friction, x, force, angle, support,
                                    force_tol, moment_tol, _tol)
    if angle is not None:
        raise StwError(f"angle= sets a second foot's angle; {point}, where {spec.name} hangs from, keeps "
                       f"whatever angle its curves give (constrain it, e.g. `constraint flat: "
                       f"{spec.joints[0].name} = 2.7 on [{a:g}, {b:g}]`)")
    if "tx" in axes and x is None:
        raise StwError(f"x=X0 says where {point} is planted: give it, e.g. `x=0` (it is planted "
                       f"there exactly, the creature hanging from it)")
    for part in all_attachments(scene):
        if part.target == axes["ty"] or part.target in spec.com:
            if part.a < b and a < part.b:
                raise StwError(f"linkage {spec.name} is already planted on [{part.a:g}, {part.b:g}], "
                               f"which overlaps [{a:g}, {b:g}]")
    # The DOF that carry the base along x and y: the centroidal ones with com=, else the base's.
    carriers = dict(zip([ax.axis for ax in spec.base], spec.com or [ax.dof for ax in spec.base]))
    closed = {"closed_a": a <= scene.t0, "closed_b": b >= scene.t1}
    where = {"tx": (x, f"{point}.x"), "ty": (height, f"{point}.y")}
    parts = tuple(Attachment(carriers[ax], sp.Float(value) + dof_symbol(carriers[ax]) - named_symbol(coord), a, b,
                             **closed) for ax, (value, coord) in where.items() if ax in axes)
    short = point.rsplit(".", 1)[-1]
    on = f"on [{_t(a)}, {_t(b)}]"
    rest = ", ".join([f"{coord} = {value!r}" for ax, (value, coord) in where.items() if ax in axes]
                     + [f"{coord}' = 0" for ax, (_, coord) in where.items() if ax in axes])
    normal = f"tau_{axes['ty']}"
    lines = []
    if a > scene.t0:
        lines.append(f"constraint {fresh_name(scene, f'{short}_touchdown')}: {rest} @ {_t(a)}")
    if b < scene.t1:
        lines.append(f"constraint {fresh_name(scene, f'{short}_liftoff')}: {rest} @ {_t(b)}")
    lines.append(f"constraint {fresh_name(scene, f'{short}_push')}: {normal} >= 0 {on}{_tol(force_tol)}")
    if "tx" in axes:
        tangent = f"tau_{axes['tx']}"
        lines.append(friction_line(scene, short, normal, tangent, friction, on, force_tol))
    lines += _support_lines(scene, spec, point, short, normal, support or (0.0, 0.0), on, moment_tol)
    return fresh_name(scene, f"{short}_contact"), lines, parts


def _support_lines(scene, spec, point: str, short: str, normal: str, support, on: str, tol: float) -> list[str]:
    """The centre of pressure on the sole [L, R] (along x, about the planted point): the ground's
    moment about the point is c * Fy with c in [L, R]. That moment is what the joint at the
    point passes on (the base has no mass to take any of it), so L*Fy <= tau_J <= R*Fy; with
    several joints on the base (a tree), the sum of their torques."""
    lo, hi = support
    if not lo <= hi:
        raise StwError(f"support [{lo:g}, {hi:g}] is empty: its start must not be after its end")
    first = spec.joints[0]
    if point != f"{spec.name}.{first.name}" or first.kind != "revolute" or any(
            ax.kind != "prismatic" for ax in spec.base):
        raise StwError(f"the centre of pressure is bounded through the joint at the planted point: plant "
                       f"{spec.name}.{first.name}, the first joint (a revolute one on a base of translations)")
    from stw_tui.sym.linkage import base_children

    ankle = " + ".join(f"tau_{r}" for r in base_children(spec))
    if " + " in ankle:
        ankle = f"({ankle})"
    return [pressure_line(scene, short, ankle, normal, lo, hi, on, tol)]


AVOID_DISTANCE = 0.01     # m: how far apart `avoid` keeps two links unless by= says
AVOID_TOL = 1e-3          # m: how far inside that distance the links may come between instances


def avoid_lines(scene, first: str, second: str, a: float, b: float, by: float | None = None,
                height: float | None = None, dense_tol: float | None = None) -> tuple[str, list[str]]:
    """(group name, command lines) of ``avoid``. Two links joined at a joint keep their angle in a
    range (:func:`_joint_range`); two others keep each end ``by`` from the other link (the
    point-to-segment distance, its projection clamped to the segment: in the plane, links that
    start apart cross only after an end has met the other link). Against the ground, both ends
    stay ``by`` above it."""
    by = AVOID_DISTANCE if by is None else by
    if not by > 0:
        raise StwError(f"avoid keeps links a distance apart: by={by:g} must be more than 0")
    one = _link(scene, first)
    on = f"on [{_t(a)}, {_t(b)}]"
    tol = _tol(AVOID_TOL if dense_tol is None else dense_tol)
    if second == "ground":
        h = height or 0.0
        relations = [f"{p}.y - {h + by!r} >= 0" for p, _ in one]
        label = "ground"
    else:
        other = _link(scene, second)
        if one == other:
            raise StwError(f"avoid needs two different links, not {first} twice")
        same = first.split(".")[0] == second.split(".")[0]
        relations = _joint_range(scene, first, second, one, other, by, a) if same else None
        if relations is None:
            relations = [_apart(p, *(q for q, _ in other), by) for p, _ in one]
            relations += [_apart(p, *(q for q, _ in one), by) for p, _ in other]
        label = second.rsplit(".", 1)[-1]
    name = first.rsplit(".", 1)[-1]
    group = fresh_name(scene, f"{name}_{label}_avoid")
    return group, [f"constraint {fresh_name(scene, f'{name}_{label}_apart')}: {', '.join(relations)} {on}{tol}"]


def _link(scene, name: str) -> tuple[tuple[str, int], tuple[str, int]]:
    """The ends of the link named by its joint (``fig.LARM``), or a clear error."""
    from stw_tui.sym.linkage import link_ends

    linkage, _, joint = name.partition(".")
    spec = scene.linkages.get(linkage)
    if spec is None or joint not in {j.name for j in spec.joints}:
        links = ", ".join(f"{s.name}.{j.name}" for s in scene.linkages.values() for j in s.joints)
        raise StwError(f"'{name}' is not a link (a link is named by its joint: {links or 'no linkage yet'})")
    return link_ends(spec, joint)


def _joint_range(scene, first: str, second: str, one, other, by: float, a: float) -> list[str] | None:
    """Two planar links that share a joint, kept ``by`` apart as a range of their angle, or None
    when they share none. Their ends' distances would not do: a link folding through the other
    between two instances is at a safe distance at both, one side and then the other (the angle
    wraps). The range cannot wrap, so the angle cannot pass the fold.

    Parent and child (an elbow): the child's angle q + theta stays in [-pi + e, pi - e], e =
    asin(D / shorter link). Siblings (two arms on a shoulder): the difference of their angles stays
    in [e, 2 pi - e]. Each range is taken on the branch (2 pi k) where the curves are at ``a``; it
    is in radians, and so is its dense_tol (1e-3 rad is 1 mm at 1 m).
    """
    spec = scene.linkages[first.split(".")[0]]
    joints = {j.name: j for j in spec.joints}
    j1, j2 = joints[first.split(".", 1)[1]], joints[second.split(".", 1)[1]]
    (_, s1), (_, e1) = one
    (_, s2), (_, e2) = other
    if e2 == s1:
        j1, j2, s1, e1, s2, e2 = j2, j1, s2, e2, s1, e1      # j1 is the parent
    if e1 == s2:
        kind = "elbow"
    elif s1 == s2:
        kind = "siblings"
    else:
        return None
    if any(j.kind != "revolute" or j.alpha or j.d for j in (j1, j2)):
        raise StwError(f"avoid: {first} and {second} share a joint, and are kept apart by their angle, "
                       f"which needs planar revolute links (no alpha= or d=)")
    shorter = min(abs(j1.a), abs(j2.a))
    if not by < shorter:
        raise StwError(f"avoid: by={by:g} is not less than the shorter link ({shorter:g} m): the two "
                       f"links, joined at one end, cannot be that far apart")
    e = math.asin(by / shorter)
    now = {n: float(scene.dofs[n].curve.evaluate([a])[0]) for n in (j1.name, j2.name)}
    if kind == "elbow":
        angle, value, lo, hi = f"{j2.name}", now[j2.name] + j2.theta, -math.pi + e, math.pi - e
        offset = j2.theta
    else:
        angle = f"{j2.name} - {j1.name}"
        value = now[j2.name] + j2.theta - now[j1.name] - j1.theta
        lo, hi, offset = e, 2 * math.pi - e, j2.theta - j1.theta
    k = math.floor((value - lo) / (2 * math.pi))
    lo, hi = lo + 2 * math.pi * k - offset, hi + 2 * math.pi * k - offset
    if not lo <= value - offset <= hi:
        raise StwError(f"avoid: at t = {a:g} {first} and {second} are already closer than {by:g} "
                       f"({angle} = {value - offset:.4g}, outside [{lo:.4g}, {hi:.4g}]): sketch them apart first")
    return [f"{angle} - {lo!r} >= 0", f"{hi!r} - ({angle}) >= 0"]


def _apart(p: str, q1: str, q2: str, by: float) -> str:
    """``distance(P, segment Q1 Q2) - by >= 0`` as session text (the projection clamped to the
    segment). A link that passes through another between two instances is at a safe distance at
    both; the continuous-time check finds it (the distance reaches 0 there) and adaptive refinement
    adds instances where it did."""
    ux, uy = f"({q2}.x - {q1}.x)", f"({q2}.y - {q1}.y)"
    wx, wy = f"({p}.x - {q1}.x)", f"({p}.y - {q1}.y)"
    along = f"min(max(({wx}*{ux} + {wy}*{uy})/({ux}^2 + {uy}^2), 0), 1)"
    return f"sqrt(({wx} - {along}*{ux})^2 + ({wy} - {along}*{uy})^2) - {by!r} >= 0"


def flight_lines(scene, name: str, a: float, b: float, dense_tol: float | None = None) -> tuple[str, list[str]]:
    """(group name, command lines) of ``flight``: the unactuated DOF's forces vanish on [A, B].
    The base forces are linear with ``com=`` (exact everywhere); the torques hanging the first
    massive link on the massless base are not: they hold to 1% of weight x size between their
    instances (or to dense_tol=D, in N m)."""
    spec = _free_linkage(scene, name, "flight")
    weight, size = physical_scale(scene, spec)
    base = [axis.dof for axis in spec.base]
    hung = []
    # joints up to the first massive link hang on a base that can take no torque (a bare frame, or
    # a point mass); a base with an inertia of its own (base_inertia=) takes the first joint's.
    # Several joints on the base (a tree): the world's moment is the sum of theirs
    from stw_tui.sym.linkage import base_children

    roots = base_children(spec)
    for joint in spec.joints if not spec.base_inertia and len(roots) == 1 else ():
        hung.append(f"tau_{joint.name} = 0")
        if joint.mass > 0:
            break
    if len(roots) > 1 and not spec.base_inertia:
        hung.append(" + ".join(f"tau_{r}" for r in roots) + " = 0")
    group = fresh_name(scene, f"{name}_flight")
    on = f"on [{_t(a)}, {_t(b)}]"
    force_tol = None if spec.com else 0.01 * weight
    spin_tol = dense_tol if dense_tol is not None else 0.01 * weight * size
    lines = [f"constraint {group}: {', '.join(f'tau_{d} = 0' for d in base)} {on}{_tol(force_tol)}"]
    if hung:
        lines.append(f"constraint {fresh_name(scene, f'{name}_spin')}: "
                     f"{', '.join(hung)} {on}{_tol(spin_tol)}")
    return group, lines
