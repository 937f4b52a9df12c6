"""Symbolic forward kinematics of a :class:`LinkageSpec`.

A linkage is lowered to a chain of *elementary steps*, each a rotation about or a translation along
one axis of the current frame, by a constant or by ``DOF + constant``: first the base axes, then for
every DH row ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` (steps with a constant zero are dropped, which keeps
the expressions small). Frame i of the DH convention is the frame after the last step of row i;
link i is attached to it. Both the kinematics here and the Newton–Euler recursion in
:mod:`.dynamics` walk the same steps.

The algebra is written once for either symbolic library: sympy (:data:`SYMPY`) or symengine
(:data:`SYMENGINE`, ~10x faster at building the expressions because it does not query assumptions
on every product). :func:`to_sympy` brings symengine results back to the project's sympy symbols.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import reduce
from operator import add as _plus

import symengine as se
import sympy as sp

from stw_tui.sym.symbols import dof_symbol, named_symbol

from stw_tui.sym.linkage.spec import LinkageSpec, link_com, link_inertia, parent_indices

Vec = tuple
Mat = tuple


@dataclass(frozen=True)
class Lib:
    """The few constructors the algebra needs from a symbolic library."""

    name: str
    zero: object
    one: object
    cos: object
    sin: object
    integer: object
    real: object
    pi: object
    symbol: object  # name -> symbol


SYMPY = Lib("sympy", sp.S.Zero, sp.S.One, sp.cos, sp.sin, sp.Integer, sp.Float, sp.pi,
            lambda name: sp.Symbol(name, real=True))
SYMENGINE = Lib("symengine", se.Integer(0), se.Integer(1), se.cos, se.sin, se.Integer, se.RealDouble,
                se.pi, se.Symbol)


def zero_vec(lib: Lib = SYMPY) -> Vec:
    """The zero 3-vector in ``lib``'s numbers."""
    return (lib.zero, lib.zero, lib.zero)


def identity(lib: Lib = SYMPY) -> Mat:
    """The 3x3 identity matrix in ``lib``'s numbers."""
    o, z = lib.one, lib.zero
    return ((o, z, z), (z, o, z), (z, z, o))


ZERO: Vec = zero_vec(SYMPY)
IDENTITY: Mat = identity(SYMPY)


def num(value: float, lib: Lib = SYMPY):
    """A float as a symbolic number: exact integers stay integers (so 1*x is x and 0 vanishes)."""
    value = float(value)
    if value == int(value) and abs(value) < 2**53:
        return lib.integer(int(value))
    return lib.real(value)


def angle_const(value: float, lib: Lib = SYMPY):
    """A constant angle, exact at multiples of pi/2 so that cos/sin of it fold away."""
    quarter = value / (math.pi / 2)
    k = round(quarter)
    if abs(quarter - k) < 1e-9:
        return lib.integer(k) * lib.pi / 2
    return lib.real(value)


def to_sympy(expr, memo: dict | None = None) -> sp.Expr:
    """A symengine expression as sympy, with the project's (real) DOF and constant symbols.

    symengine already holds its sums and products flattened and canonical, so they are rebuilt with
    ``evaluate=False`` (sympy would otherwise re-derive every product's assumptions: most of the
    derivation time). Shared subtrees are converted once (``memo``, may be shared between calls).
    """
    memo = {} if memo is None else memo
    return _to_sympy(expr, memo)


_SE_FUNCS = {"sin": sp.sin, "cos": sp.cos, "acos": sp.acos, "atan2": sp.atan2}


def _to_sympy(e, memo):
    hit = memo.get(e)
    if hit is not None:
        return hit
    if isinstance(e, se.Symbol):
        out = sp.Symbol(e.name, real=True)
    elif isinstance(e, se.Integer):
        out = sp.Integer(int(e))
    elif isinstance(e, se.Rational):
        p, q = e.get_num_den()
        out = sp.Rational(int(p), int(q))
    elif isinstance(e, se.RealDouble):
        out = sp.Float(float(e))
    elif isinstance(e, se.Add):
        out = sp.Add(*(_to_sympy(a, memo) for a in e.args), evaluate=False)
    elif isinstance(e, se.Mul):
        out = sp.Mul(*(_to_sympy(a, memo) for a in e.args), evaluate=False)
    elif isinstance(e, se.Pow):
        base, exponent = e.args
        out = sp.Pow(_to_sympy(base, memo), _to_sympy(exponent, memo), evaluate=False)
    elif type(e).__name__ in _SE_FUNCS:
        out = _SE_FUNCS[type(e).__name__](*(_to_sympy(a, memo) for a in e.args), evaluate=False)
    else:  # pi and anything unforeseen: symengine's own conversion (numbers, constants)
        out = e._sympy_()
        out = out.xreplace({s: sp.Symbol(s.name, real=True) for s in out.free_symbols})
    memo[e] = out
    return out


@dataclass(frozen=True)
class Step:
    """One elementary motion of the chain."""

    kind: str  # "revolute" (rotation) or "prismatic" (translation)
    axis: int  # 0, 1, 2: about / along local x, y, z
    offset: float  # constant angle or distance
    dof: str | None  # the DOF added to the offset, or None for a constant step


@dataclass(frozen=True)
class Chain:
    """A linkage lowered to elementary steps, with the frames where joints sit and links attach.

    Frame 0 is the world and step k makes frame k + 1 from frame ``parents[k]``: for a serial chain
    ``parents[k] == k``; a branched linkage (rows with ``parent=``) starts a row's steps from the
    frame of the link it hangs from. Parents always come before their children.
    """

    steps: tuple[Step, ...]
    joint_frames: tuple[int, ...]  # index (into frames 0..len(steps)) where joint i sits
    link_frames: tuple[int, ...]  # index of the frame link i is attached to (DH frame i)
    parents: tuple[int, ...] = ()  # frame each step starts from (empty: the serial chain, k)

    def parent(self, k: int) -> int:
        """The frame step ``k`` starts from."""
        return self.parents[k] if self.parents else k


def chain(spec: LinkageSpec) -> Chain:
    """Lower a linkage to its elementary steps: the base axes, then each DH row's nonzero steps,
    each row starting from the frame of the link it hangs from."""
    steps: list[Step] = [Step(b.kind, b.index, 0.0, b.dof) for b in spec.base]
    parents = list(range(len(steps)))
    joint_frames, link_frames = [], []
    for j, up in zip(spec.joints, parent_indices(spec)):
        start = len(spec.base) if up < 0 else link_frames[up]
        joint_frames.append(start)
        revolute = j.kind == "revolute"
        candidates = [
            Step("revolute", 2, j.theta, j.name if revolute else None),
            Step("prismatic", 2, j.d, None if revolute else j.name),
            Step("prismatic", 0, j.a, None),
            Step("revolute", 0, j.alpha, None),
        ]
        frame = start
        for s in candidates:
            if s.dof is not None or s.offset != 0.0:
                parents.append(frame)
                steps.append(s)
                frame = len(steps)
        link_frames.append(frame)
    serial = all(p == k for k, p in enumerate(parents))
    return Chain(tuple(steps), tuple(joint_frames), tuple(link_frames), () if serial else tuple(parents))


# ------------------------------------------------------------------------------- small 3-D algebra


def add(*vs: Vec) -> Vec:
    """The sum of 3-vectors."""
    return tuple(reduce(_plus, (v[i] for v in vs)) for i in range(3))


def mul(a, b):
    """a * b, distributing a number over a sum as sympy does (``2*(x+y)`` -> ``2*x + 2*y``).

    symengine keeps ``2*(x+y)`` whole; distributing lets like terms from different links combine
    (the inward pass adds up m_i * a_i with shared terms), which keeps the symengine-built expressions
    as small as sympy's. sympy objects already do this and pass straight through.
    """
    if isinstance(a, se.Number) and isinstance(b, se.Add):
        return se.Add(*(a * t for t in b.args))
    if isinstance(b, se.Number) and isinstance(a, se.Add):
        return se.Add(*(b * t for t in a.args))
    return a * b


def neg(a):
    """``-a``, distributed over a symengine sum as sympy does (see :func:`mul`)."""
    return se.Add(*(-t for t in a.args)) if isinstance(a, se.Add) else -a


def scale(k, v: Vec) -> Vec:
    """``k v`` for a 3-vector ``v``."""
    return (mul(k, v[0]), mul(k, v[1]), mul(k, v[2]))


def dot(u: Vec, v: Vec):
    """The dot product of two 3-vectors."""
    return mul(u[0], v[0]) + mul(u[1], v[1]) + mul(u[2], v[2])


def cross(u: Vec, v: Vec) -> Vec:
    """The cross product ``u × v`` of two 3-vectors."""
    return (mul(u[1], v[2]) + neg(mul(u[2], v[1])), mul(u[2], v[0]) + neg(mul(u[0], v[2])),
            mul(u[0], v[1]) + neg(mul(u[1], v[0])))


def matvec(m: Mat, v: Vec) -> Vec:
    """``m v`` for a 3x3 matrix and a 3-vector."""
    return tuple(dot(row, v) for row in m)


def tmatvec(m: Mat, v: Vec) -> Vec:
    """m^T v."""
    return tuple(dot((m[0][c], m[1][c], m[2][c]), v) for c in range(3))


def matmul(a: Mat, b: Mat) -> Mat:
    """``a b`` for two 3x3 matrices."""
    return tuple(tuple(dot(a[r], (b[0][c], b[1][c], b[2][c])) for c in range(3)) for r in range(3))


def unit(axis: int, lib: Lib = SYMPY) -> Vec:
    """The unit vector along ``axis`` (0, 1, 2: x, y, z)."""
    return tuple(lib.one if i == axis else lib.zero for i in range(3))


def rotation(axis: int, angle, lib: Lib = SYMPY) -> Mat:
    """Rotation about local ``axis``: maps child-frame coordinates to parent-frame coordinates."""
    c, s = lib.cos(angle), lib.sin(angle)
    o, z = lib.one, lib.zero
    if axis == 0:
        return ((o, z, z), (z, c, -s), (z, s, c))
    if axis == 1:
        return ((c, z, s), (z, o, z), (-s, z, c))
    return ((c, -s, z), (s, c, z), (z, z, o))


def step_value(step: Step, order: int = 0, lib: Lib = SYMPY):
    """The step's angle or distance (order 0), or its first or second time derivative."""
    if order == 0:
        const = angle_const(step.offset, lib) if step.kind == "revolute" else num(step.offset, lib)
        return const if step.dof is None else lib.symbol(dof_symbol(step.dof).name) + const
    return lib.zero if step.dof is None else lib.symbol(dof_symbol(step.dof, order).name)


def step_transform(step: Step, lib: Lib = SYMPY) -> tuple[Mat, Vec]:
    """(R, p): child frame in parent coordinates."""
    value = step_value(step, 0, lib)
    if step.kind == "revolute":
        return rotation(step.axis, value, lib), zero_vec(lib)
    return identity(lib), scale(value, unit(step.axis, lib))


def gravity_vector(spec: LinkageSpec, lib: Lib = SYMPY) -> Vec:
    """Gravity's acceleration in world coordinates: g along the spec's signed axis (zero for none)."""
    if spec.gravity_axis is None:
        return zero_vec(lib)
    g = lib.symbol(named_symbol("g").name)
    return scale(lib.integer(spec.gravity_sign) * g, unit(spec.gravity_axis, lib))


# ------------------------------------------------------------------------------------ kinematics


def world_frames(spec: LinkageSpec, ch: Chain | None = None, lib: Lib = SYMPY
                 ) -> list[tuple[Mat, Vec]]:
    """World (R, p) of every frame of the chain: frame 0 is the world, frame k follows step k."""
    ch = ch or chain(spec)
    frames = [(identity(lib), zero_vec(lib))]
    for k, step in enumerate(ch.steps):
        r, p = frames[ch.parent(k)]
        value = step_value(step, 0, lib)
        if step.kind == "revolute":
            r = matmul(r, rotation(step.axis, value, lib))
        else:
            p = add(p, scale(value, tuple(r[i][step.axis] for i in range(3))))
        frames.append((r, p))
    return frames


def link_com_world(spec: LinkageSpec, frames, ch: Chain, lib: Lib = SYMPY) -> list[Vec]:
    """World position of every link's centre of mass."""
    out = []
    for joint, k in zip(spec.joints, ch.link_frames):
        r, p = frames[k]
        out.append(add(p, matvec(r, tuple(num(c, lib) for c in link_com(joint)))))
    return out


def link_inertia_sym(joint, lib: Lib = SYMPY) -> Mat:
    """A link's inertia tensor (:func:`link_inertia`) in ``lib``'s numbers."""
    return tuple(tuple(num(c, lib) for c in row) for row in link_inertia(joint))


def positions(spec: LinkageSpec, lib: Lib = SYMPY) -> dict:
    """``NAME.JOINT.x|y|z`` (where each joint sits), ``NAME.tip.x|y|z`` (where the last row's link
    ends) and ``NAME.com.x|y|z`` (of the links and the base's own mass), as expressions of ``lib``
    (see :func:`to_sympy`). A branched linkage also names where each link ends,
    ``NAME.JOINT.end.x|y|z`` (a leaf's end is a hand, a foot or a head)."""
    ch = chain(spec)
    frames = world_frames(spec, ch, lib)
    out: dict = {}
    for joint, k, end in zip(spec.joints, ch.joint_frames, ch.link_frames):
        _put(out, f"{spec.name}.{joint.name}", frames[k][1])
        if ch.parents:   # a branched linkage names where each link ends (a chain: the next joint)
            _put(out, f"{spec.name}.{joint.name}.end", frames[end][1])
    _put(out, f"{spec.name}.tip", frames[ch.link_frames[-1]][1])
    total = spec.total_mass
    coms = link_com_world(spec, frames, ch, lib)
    weighted = add(*(scale(num(j.mass / total, lib), c) for j, c in zip(spec.joints, coms)))
    if spec.base_mass:   # a point at the base frame origin
        weighted = add(weighted, scale(num(spec.base_mass / total, lib), frames[len(spec.base)][1]))
    _put(out, f"{spec.name}.com", weighted)
    return out


def _put(out: dict, prefix: str, v: Vec):
    for axis, value in zip("xyz", v):
        out[f"{prefix}.{axis}"] = value
