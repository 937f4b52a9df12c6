"""Denavit–Hartenberg creatures: symbolic forward kinematics and equations of motion.

Public API::

    spec = parse_linkage("linkage arm base=fixed", [(2, "SHOULDER revolute a=0.35 mass=2"), ...])
    dof_names(spec)              # ["SHOULDER", ...] (base DOF first)
    exprs = derive(spec)         # {"arm.SHOULDER.x": ..., "arm.tip.y": ..., "arm.com.z": ...,
                                 #  "tau_SHOULDER": ...} sympy expressions in the DOF symbols
                                 #  (stw_tui.sym.symbols.dof_symbol) and the constant g
    segments(spec, {"SHOULDER": 0.3, ...}, {"g": 9.81})   # stick figure, list of (start, end) 3-vectors
    time_derivative(expr, dof_names(spec))                # chain rule, q -> q', q' -> q''
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import lru_cache

import numpy as np
import sympy as sp

from stw_tui.sym.errors import StwError
from stw_tui.sym.symbols import dof_symbol

from stw_tui.sym.linkage.derivative import time_derivative
from stw_tui.sym.linkage.dynamics import generalized_forces
from stw_tui.sym.linkage.kinematics import SYMENGINE, chain, positions, to_sympy
from stw_tui.sym.linkage.spec import (BaseAxis, JointSpec, LinkageSpec, base_children, curve_dofs, dof_names,
                                      parse_linkage)

__all__ = ["BaseAxis", "JointSpec", "LinkageSpec", "base_children", "curve_dofs", "derive", "dof_names", "link_ends",
           "parse_linkage",
           "segments", "time_derivative"]


def derive(spec: LinkageSpec) -> dict[str, sp.Expr]:
    """Every derived subexpression of the linkage, by name.

    ``<linkage>.<JOINT>.x|y|z``: where joint i sits (the origin of DH frame i-1; the base frame for
    the first joint; with ``parent=P``, the end of P's link). ``<linkage>.tip.x|y|z``: where the last
    row's link ends; a branched linkage also has ``<linkage>.<JOINT>.end.x|y|z`` for every link. ``<linkage>.com.x|y|z``:
    centre of mass of the whole linkage (its ``base_mass`` included). ``tau_<DOF>``: generalized force of each DOF, base DOF
    included (recursive Newton–Euler, see :mod:`.dynamics`).
    """
    ch = chain(spec)
    memo: dict = {}
    out = {name: to_sympy(e, memo) for name, e in positions(spec, SYMENGINE).items()}
    out.update(generalized_forces(spec, ch))
    return out


def link_ends(spec: LinkageSpec, joint: str) -> tuple[tuple[str, int], tuple[str, int]]:
    """Where the link of ``joint`` starts and ends: ((point name, frame), (point name, frame)), the
    names as the scene knows them (a chain's link ends at the next joint or the tip, a tree's at
    ``NAME.JOINT.end``) and the frames (:func:`chain`'s indices) to tell shared points apart."""
    ch = chain(spec)
    index = [j.name for j in spec.joints].index(joint)
    start, end = ch.joint_frames[index], ch.link_frames[index]
    if ch.parents:
        end_name = f"{spec.name}.{joint}.end"
    else:
        end_name = f"{spec.name}.{spec.joints[index + 1].name}" if index + 1 < len(spec.joints) else f"{spec.name}.tip"
    return (f"{spec.name}.{joint}", start), (end_name, end)


@lru_cache(maxsize=64)
def _point_function(spec: LinkageSpec):
    """(DOF names, numpy function of the DOF values -> 2 n_joints x 3 points: where each joint sits,
    then where its link ends), once per spec."""
    memo: dict = {}
    pos = positions(spec, SYMENGINE)
    names = dof_names(spec)
    ends = ([f"{spec.name}.{j.name}.end" for j in spec.joints] if f"{spec.name}.{spec.joints[0].name}.end.x" in pos
            else [f"{spec.name}.{j.name}" for j in spec.joints[1:]] + [f"{spec.name}.tip"])
    points = [f"{spec.name}.{j.name}" for j in spec.joints] + ends
    matrix = sp.Matrix([[to_sympy(pos[f"{p}.{axis}"], memo) for axis in "xyz"] for p in points])
    # generated from our own expressions, never from user text
    fn = sp.lambdify([dof_symbol(n) for n in names], matrix, modules="numpy", cse=True)
    return names, fn


def segments(spec: LinkageSpec, values: Mapping[str, float], consts: Mapping[str, float] | None = None
             ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The stick figure at one configuration: one (start, end) pair of 3-vectors per link, in row
    order, from where its joint sits to where the link ends (a chain: joint i to joint i+1, the
    last joint to the tip; the first start is the base frame origin, where joint 1 sits).
    ``values`` maps every DOF of the linkage to its value; ``consts`` is accepted for symmetry
    (positions depend on no constant).
    """
    names, fn = _point_function(spec)
    missing = [n for n in names if n not in values]
    if missing:
        raise StwError(f"linkage {spec.name}: no value for DOF {', '.join(missing)}")
    pts = np.asarray(fn(*(float(values[n]) for n in names)), dtype=float)
    n = len(spec.joints)
    return [(pts[i].copy(), pts[n + i].copy()) for i in range(n)]
