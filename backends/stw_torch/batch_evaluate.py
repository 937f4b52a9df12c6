"""Evaluation of many starts' window problems at once: one pass over the term groups for the whole
batch, instead of one per start.

Starts of one survey solve window problems of the same structure (same free variables, term
groups, instance times and basis matrices); only their control points differ, and the fixed ones
too when the window leaves some DOF out. Stacked, the slot values of B starts are a (B, slots)
matrix ``V = V_fixed + (Pf Sᵀ)ᵀ``; a group's (k, n) input block becomes a (k, B·n) block with the
instance times repeated B times, so its lowered torch program of values and local derivatives
runs once for the batch (every instance still depends on its own slots only). Gradients, constraint values and Jacobian and
Hessian values on the fixed patterns are then per-start rows of (B, ·) tensors; each start gets
an ordinary :class:`~.evaluate.TorchEvaluation` of its own, so the SQP cannot tell the difference.
"""

from __future__ import annotations

import hashlib

import numpy as np
import torch

from stw_tui.sos.window import EQ, GE, OBJ, MeritValues

from .evaluate import TorchEvaluation, TorchProblem


def problem_key(problem, device: torch.device, host_linear: bool) -> str:
    """A digest of everything of a window problem but its control points: problems with equal
    keys share one lowering (:meth:`TorchProblem.with_problem`) and batch together. Compiled terms
    are named by identity (the core caches them, so the starts of a survey share them; printing
    an arm's torque expressions to hash them took 0.3 s)."""
    h = hashlib.sha256(repr((str(device), host_linear, type(problem.Pf).__name__, problem.Pf.shape,
                             sorted(problem.row_counts.items()))).encode())
    Pf = problem.Pf
    for array in (Pf.indptr, Pf.indices, Pf.data) if hasattr(Pf, "indptr") else (Pf.toarray(),):
        h.update(np.ascontiguousarray(array).tobytes())
    h.update(np.asarray(problem.free, np.int64).tobytes())
    h.update(np.ascontiguousarray(problem.damping, float).tobytes())
    for g in problem.groups:
        leaves = [(str(node), id(term), offset, tuple(problem.term_parameters(term)))
                  for node, term, offset in g.condition.leaves] if g.condition is not None else []
        h.update(repr((g.label, str(g.kind), g.n, g.slot_offset, g.row_offset, id(g.term),
                       tuple(float(p) for p in g.params),
                       str(g.condition.tree) if g.condition is not None else "", leaves)).encode())
        h.update(np.ascontiguousarray(g.times, float).tobytes())
        h.update(np.ascontiguousarray(g.weights, float).tobytes())
    return h.hexdigest()


def _slot_values(tp: TorchProblem, members: list[TorchProblem], S: torch.Tensor) -> torch.Tensor:
    """(B, slots): each start's fixed slot values plus its free control points' share."""
    fixed = torch.stack([m.v_fixed for m in members])
    return fixed + (tp.Pf @ S.T.contiguous()).T


def _tile(V: torch.Tensor, g, k: int, offset: int) -> torch.Tensor:
    """A group's (k, n) input block of every start side by side: (k, B·n), start-major."""
    B = V.shape[0]
    return V[:, offset:offset + k * g.n].reshape(B, k, g.n).permute(1, 0, 2).reshape(k, B * g.n)


def _conditions(tp: TorchProblem, V: torch.Tensor) -> dict[str, torch.Tensor]:
    """Every start's ``when`` masks, (B, rows) per kind: the problem's own walk over tiled leaves."""
    B = V.shape[0]

    def leaf(g, term, offset, params):
        return term(_tile(V, g, term.k, offset), g.times.repeat(B), params)

    def filled(n):
        return lambda flag: torch.full((B * n,), flag, dtype=torch.bool, device=tp.device)
    return tp._conditions(lambda rows: torch.ones(B, rows, dtype=torch.bool, device=tp.device), filled, leaf)


def merit_values_batch(members: list[TorchProblem], points: list[np.ndarray]) -> list[MeritValues]:
    """:meth:`TorchProblem.merit_values` of every (problem, point), the problems of one structure."""
    tp = members[0]
    B = len(members)
    with torch.no_grad():
        S = torch.as_tensor(np.stack(points), **tp._dev)
        V = _slot_values(tp, members, S)
        f = tp.plan.values_batch(V)
        c = {kind: tp.row_weight[kind] * f[:, tp.row_inst[kind]] for kind in (EQ, GE)}
        r = f[:, tp.row_inst[OBJ]]
        objective = (tp.row_weight[OBJ] * r * r).sum(1)
        masks = _conditions(tp, V)
    host = [objective.cpu().numpy(), c[EQ].cpu().numpy(), c[GE].cpu().numpy(),
            masks[EQ].cpu().numpy(), masks[GE].cpu().numpy()]
    return [MeritValues(float(host[0][b]), host[1][b], host[2][b], host[3][b], host[4][b]) for b in range(B)]


def _pattern_values(pattern, source: torch.Tensor) -> torch.Tensor:
    """:meth:`Pattern.values` for (B, n_src) sources: (B, nnz)."""
    if pattern.operator is not None:
        return (pattern.operator @ source.T.contiguous()).T
    ext = torch.cat([source, source.new_zeros(source.shape[0], 1)], 1)
    return (pattern.coef_pad * ext[:, pattern.src_pad]).sum(-1)


def evaluate_batch(members: list[TorchProblem], points: list[np.ndarray]) -> list[TorchEvaluation]:
    """:meth:`TorchProblem.evaluate` of every (problem, point), the problems of one structure."""
    tp = members[0]
    B = len(members)
    S = torch.as_tensor(np.stack([np.asarray(p, float) for p in points]), **tp._dev)
    with torch.no_grad():
        V = _slot_values(tp, members, S)
        f_all, g_slot, h_flat = tp.plan.local_batch(V)
    obj = tp.is_obj
    w_f = tp.w_inst * f_all
    r = f_all[:, tp.row_inst[OBJ]]
    objective = (tp.row_weight[OBJ] * r * r).sum(1)
    scale = torch.cat([torch.where(obj, 2.0 * w_f, 0.0), V.new_zeros(B, 1)], 1)[:, tp.slot_owner]
    gradient = (tp.PfT @ (g_slot * scale).T.contiguous()).T
    gw = g_slot * tp.w_slot
    c = {kind: tp.row_weight[kind] * f_all[:, tp.row_inst[kind]] for kind in (EQ, GE)}
    J = {kind: _pattern_values(tp.jac[kind], gw) for kind in (EQ, GE)}
    masks = _conditions(tp, V)
    host = {name: t.cpu().numpy() for name, t in (("objective", objective), ("gradient", gradient),
                                                  ("c_eq", c[EQ]), ("c_ge", c[GE]),
                                                  ("active_eq", masks[EQ]), ("active_ge", masks[GE]))}
    out = []
    for b, member in enumerate(members):
        out.append(TorchEvaluation(
            tp=member, s=np.asarray(points[b], float).copy(), objective=float(host["objective"][b]),
            gradient=host["gradient"][b], c_eq=host["c_eq"][b], c_ge=host["c_ge"][b],
            active_eq=host["active_eq"][b], active_ge=host["active_ge"][b],
            t_J={kind: J[kind][b] for kind in (EQ, GE)},
            t_local={"f": f_all[b], "g": g_slot[b], "h": h_flat[b]}))
    return out
