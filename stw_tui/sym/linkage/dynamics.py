"""Equations of motion of a linkage by the recursive Newton–Euler algorithm, in sympy.

The generalized force ``tau_<DOF>`` of every DOF (base DOF included) is the left-hand side of
``M(q) q'' + C(q, q') q' + G(q) = tau``, as one sympy expression in the DOF symbols ``q, q', q''``
and the gravity constant ``g``.

Why Newton–Euler rather than Lagrange (or sympy.physics.mechanics):

* It is the paper's route (Cohen 1992, 3.4: "symbolic equations of motion through a Newton–Euler
  formulation").
* It needs no symbolic differentiation at all: one outward pass of velocities and accelerations, one
  inward pass of forces and moments, each a handful of products per step. Lagrange must differentiate
  the kinetic energy twice (d/dt dL/dq'), which in sympy is the slow part (DESIGN.md: seconds for a
  3-link arm) and produces larger expressions.
* The recursion is built in symengine (numbers distributed over sums as sympy would, so the trees
  are the same as a pure-sympy build) and converted to sympy once. Measured cold (fresh process,
  after imports): planar 3-link arm ~5 ms, a 6-DOF 3-D creature ~10-30 ms; the same recursion in
  sympy took ~0.12 s and ~0.9 s (every sympy product queries assumptions).
  tests/test_linkage.py prints the time.
* Working in local link frames (each quantity expressed in the frame of the step it belongs to)
  keeps the expressions small: a planar arm's angular velocity stays ``(0, 0, q1'+q2'+...)``, and
  nothing is ever multiplied by a full world rotation. Shared subtrees are left shared for the
  consumer's CSE; we never call expand/simplify/trigsimp.

The chain is the one of :mod:`.kinematics`: elementary rotations/translations about local axes, base
axes first, links attached to their DH frames, the base's own mass and inertia (``base_mass=``,
``base_inertia=``) at the frame after the base axes. Gravity enters by the usual trick of giving the
world frame an upward acceleration ``-g_vec``. The correctness checks (closed-form double pendulum, an
independent Lagrangian, energy balance in 3-D with base DOF and a prismatic joint) are in
tests/test_linkage.py; a cart-pole with a massive cart in tests/test_base_mass.py.
"""

from __future__ import annotations

import sympy as sp

from stw_tui.sym.linkage.kinematics import (SYMENGINE, Chain, Lib, Vec, add, chain, cross, gravity_vector,
                         link_inertia_sym, matvec, num, scale, step_transform, step_value, tmatvec,
                         to_sympy, unit, zero_vec)
from stw_tui.sym.linkage.spec import LinkageSpec, base_rotation_axis, link_com


def generalized_forces(spec: LinkageSpec, ch: Chain | None = None) -> dict[str, sp.Expr]:
    """``{"tau_<DOF>": expr}`` for every DOF of the linkage, base DOF first, as sympy expressions.

    Built in symengine and converted to sympy once at the end (see the module docstring).
    """
    raw = generalized_forces_raw(spec, ch, SYMENGINE)
    memo: dict = {}
    return {name: to_sympy(expr, memo) for name, expr in raw.items()}


def generalized_forces_raw(spec: LinkageSpec, ch: Chain | None = None, lib: Lib = SYMENGINE) -> dict:
    """:func:`generalized_forces` as expressions of ``lib`` (symengine or sympy)."""
    ch = ch or chain(spec)
    ZERO = zero_vec(lib)
    steps = ch.steps
    n = len(steps)

    # bodies attached to frames; the base's own (base_mass=, base_inertia=) at the base frame,
    # which no link shares (every joint takes at least its own step past it)
    bodies: dict[int, tuple[sp.Expr, Vec, tuple]] = {}
    for joint, k in zip(spec.joints, ch.link_frames):
        bodies[k] = (num(joint.mass, lib), tuple(num(c, lib) for c in link_com(joint)),
                     link_inertia_sym(joint, lib))
    if spec.base_body:
        bodies[len(spec.base)] = (num(spec.base_mass, lib), ZERO, _base_inertia(spec, lib))

    # outward pass: angular velocity w, angular acceleration dw, linear acceleration a of the frame
    # origin (gravity included), each in its own frame's coordinates
    w, dw, a = [ZERO], [ZERO], [scale(lib.integer(-1), gravity_vector(spec, lib))]
    transforms = []
    for k, step in enumerate(steps):
        rot, p = step_transform(step, lib)
        transforms.append((rot, p))
        e = unit(step.axis, lib)
        v1, v2 = step_value(step, 1, lib), step_value(step, 2, lib)
        up = ch.parent(k)
        wp, dwp, ap = w[up], dw[up], a[up]
        if step.kind == "revolute":
            w_rel = scale(v1, e)
            w.append(tmatvec(rot, add(wp, w_rel)))
            dw.append(tmatvec(rot, add(dwp, scale(v2, e), cross(wp, w_rel))))
            a.append(tmatvec(rot, ap))
        else:
            w.append(wp)
            dw.append(dwp)
            a.append(add(ap, cross(dwp, p), cross(wp, cross(wp, p)),
                         scale(lib.integer(2) * v1, cross(wp, e)), scale(v2, e)))

    # inward pass: force f and moment m (about the frame origin) that frame k-1 exerts on everything
    # from frame k outward, in frame k coordinates
    def body_wrench(k: int) -> tuple[Vec, Vec]:
        if k not in bodies:
            return ZERO, ZERO
        mass, c, inertia = bodies[k]
        ac = add(a[k], cross(dw[k], c), cross(w[k], cross(w[k], c)))
        force = scale(mass, ac)
        moment = add(matvec(inertia, dw[k]), cross(w[k], matvec(inertia, w[k])), cross(c, force))
        return force, moment

    # each frame's wrench gathers its body's and those its child frames pass on; children come
    # after their parents, so one backward sweep sees every child before its parent
    wrench = {k: body_wrench(k) for k in range(n + 1)}
    taus: dict[str, sp.Expr] = {}
    for k in range(n, 0, -1):
        step = steps[k - 1]
        rot, p = transforms[k - 1]
        f, m = wrench[k]
        if step.kind == "revolute":
            if step.dof is not None:
                taus[step.dof] = m[step.axis]  # e . (R m) = (R^T e) . m = e . m
            f, m = matvec(rot, f), matvec(rot, m)
        else:
            if step.dof is not None:
                taus[step.dof] = f[step.axis]
            m = add(m, cross(p, f))
        up = ch.parent(k - 1)
        pf, pm = wrench[up]
        wrench[up] = (f, m) if pf is ZERO else (add(pf, f), add(pm, m))

    order = [b.dof for b in spec.base] + [j.name for j in spec.joints]
    return {f"tau_{name}": taus[name] for name in order}


def _base_inertia(spec: LinkageSpec, lib: Lib) -> tuple:
    """The base's inertia tensor in the base frame: ``base_inertia`` about its one rotation axis.

    Nothing about the other two axes: the base only ever turns about that one, so they never act.
    """
    axis = base_rotation_axis(spec) if spec.base_inertia else None
    return tuple(tuple(num(spec.base_inertia, lib) if r == c == axis else lib.zero for c in range(3))
                 for r in range(3))
