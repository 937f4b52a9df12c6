"""Kinds that cross module and plugin boundaries, as enums rather than bare strings."""

from __future__ import annotations

import enum


class TermKind(enum.StrEnum):
    """What a compiled term makes of its expression: rows ``= 0``, rows ``>= 0``, or an objective
    term squared and integrated. Its values are the strings backends have always read
    (``row_counts["eq"]``), and compare equal to them."""

    EQ = "eq"
    GE = "ge"
    OBJ = "obj"


class Capability(enum.StrEnum):
    """What a backend declares it honours (``Backend.capabilities``); the interpreter warns when
    a scene asks for one that the chosen backend lacks."""

    INEQUALITIES = "inequalities"   # rows >= 0 (and DOF bounds)
    CONDITIONAL = "conditional"     # constraints with `when`
    DAMPING = "damping"             # `damp DOF W`
    WEIGHTS = "weights"             # constraint and objective weights
    ELASTIC = "elastic"             # an elastic QP when the linearized constraints conflict
    AUTOGRAD = "autograd"           # derivatives by automatic differentiation
    GPU = "gpu"                     # can run on a GPU
    BATCH = "batch"                 # solves many starts as one batch (Backend.batch_solver)
