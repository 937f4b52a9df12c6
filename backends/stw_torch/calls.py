"""Term groups merged into calls: all the groups of one lowered term (with the same constants)
are evaluated by one call of its torch program, over all their instances side by side.

A window problem often evaluates one term in several groups: a linkage's torque both as an
objective and as a flight constraint, a contact's expressions over several intervals. A torch op
on the CPU costs microseconds whatever its length, so one call over all of a term's instances
costs what one group's did (acrobat: tau_FOOT in two groups, 13 groups in 8 calls).

Every call's inputs are gathered from the slot values at once (``inputs``: slot indices, call
after call, each call's (k, N) block row-major), and the calls' outputs are put back in the
layout of the groups (values per instance, gradients per slot, second derivatives per group and
pair) by fixed index arrays: a few ops per evaluation whatever the number of groups.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .lower import LoweredTerm, unoptimized


@dataclass(eq=False)
class Call:
    """One lowered term over the instances of all its groups."""

    term: LoweredTerm
    params: torch.Tensor    # (P,) its constants
    times: torch.Tensor     # (N,) the instances' times, group after group
    k: int                  # variables per instance
    start: int              # where its (k, N) inputs begin in the gathered inputs
    n: int                  # N: its instances


@dataclass(eq=False)
class CallPlan:
    """The calls of a problem's groups and the index arrays that put their outputs in place.

    Slot values come as a (B, slots) matrix, a row per start of a batch (one for a solve of its
    own): each call's (k, N) inputs of every start are laid side by side, (k, B·N) start-major,
    and its program runs once for all of them (an instance depends on its own slots only)."""

    calls: list[Call]
    inputs: torch.Tensor    # the slot of every input, call after call
    f_order: torch.Tensor   # instance -> its value's place among the calls' values
    h_order: torch.Tensor   # (group, pair, instance) entry -> its place among the calls' pairs
    n_slots: int
    autograd: bool = False  # derivatives by torch's autograd on the value programs (local())

    @classmethod
    def build(cls, groups, n_slots: int, device: torch.device, autograd: bool = False) -> "CallPlan":
        """Merge ``groups`` (evaluate._Group) by lowered term and constants, in first-seen order."""
        by_key: dict[tuple, list] = {}
        for g in groups:
            by_key.setdefault((id(g.term), tuple(g.params.tolist())), []).append(g)
        calls, inputs, f_dest, h_dest = [], [], [], []
        h_offsets, offset = {}, 0
        for g in groups:                      # the groups' own layout of second derivatives
            h_offsets[id(g)] = offset
            offset += len(g.pairs) * g.n
        start = 0
        for members in by_key.values():
            first = members[0]
            k, n = first.term.k, sum(g.n for g in members)
            for a in range(k):
                inputs += [g.slot + a * g.n + np.arange(g.n) for g in members]
            f_dest += [g.inst + np.arange(g.n) for g in members]
            for p in range(len(first.pairs)):
                h_dest += [h_offsets[id(g)] + p * g.n + np.arange(g.n) for g in members]
            times = torch.cat([g.times for g in members])
            calls.append(Call(first.term, first.params, times, k, start, n))
            start += k * n
        cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0, np.int64)  # noqa: E731
        as_t = lambda a: torch.as_tensor(a, dtype=torch.int64, device=device)  # noqa: E731
        return cls(calls, as_t(cat(inputs)), as_t(np.argsort(cat(f_dest), kind="stable")),
                   as_t(np.argsort(cat(h_dest), kind="stable")), n_slots, autograd)

    def _blocks(self, V: torch.Tensor):
        """Each call with its inputs (k, B·N) and times (B·N,) at slot values V (B, slots)."""
        B = V.shape[0]
        X = V[:, self.inputs]
        for c in self.calls:
            block = X[:, c.start:c.start + c.k * c.n].reshape(B, c.k, c.n).transpose(0, 1)
            yield c, block.reshape(c.k, B * c.n), c.times if B == 1 else c.times.repeat(B)

    def values(self, V: torch.Tensor) -> torch.Tensor:
        """(B, instances): every group's values at slot values V (B, slots), in the groups' layout."""
        B = V.shape[0]
        with unoptimized():
            parts = [c.term.program("value")(X, t, c.params)[0].view(B, c.n) for c, X, t in self._blocks(V)]
        return torch.cat(parts, 1)[:, self.f_order] if parts else V.new_zeros(B, 0)

    def local(self, V: torch.Tensor, second: bool = True):
        """Values (B, instances), gradients per slot (B, slots) and, with ``second``, second
        derivatives (B, entries) at slot values V (B, slots), in the groups' layout (else None)."""
        B = V.shape[0]
        f, g, h = [], [], []
        with unoptimized():
            for c, X, t in self._blocks(V):
                if self.autograd:
                    rows = autograd_rows(c.term, X, t, c.params, second)
                else:
                    rows = c.term.program("full" if second else "first")(X, t, c.params)
                rows = rows.reshape(-1, B, c.n).transpose(0, 1)        # (B, 1 + k + pairs, N)
                f.append(rows[:, 0])
                g.append(rows[:, 1:1 + c.k].reshape(B, -1))
                h.append(rows[:, 1 + c.k:].reshape(B, -1))
        empty = V.new_zeros(B, 0)
        g_slot = V.new_zeros(B, self.n_slots)
        if g:
            g_slot[:, self.inputs] = torch.cat(g, 1)
        return (torch.cat(f, 1)[:, self.f_order] if f else empty, g_slot,
                (torch.cat(h, 1)[:, self.h_order] if h else empty) if second else None)


def autograd_rows(term: LoweredTerm, X: torch.Tensor, times: torch.Tensor, params: torch.Tensor,
                  second: bool) -> torch.Tensor:
    """What the term's program "full" (``second``) or "first" gives, by torch's autograd on the
    term's value program alone (``derivatives=autograd``): derivatives found independently of
    the symbolic ones, to hold them against. An instance's value depends on its own column of
    X only, so the gradient of the sum is every instance's gradient; each first derivative that
    a Hessian pair needs takes one more backward pass."""
    k, n = X.shape
    with torch.enable_grad():
        X = X.detach().requires_grad_(True)
        f = term.program("value")(X, times, params)[0]
        grad = None
        if f.requires_grad:             # else the value is constant: its gradient is zero
            (grad,) = torch.autograd.grad(f.sum(), X, create_graph=second, allow_unused=True)
        grad = X.new_zeros(k, n) if grad is None else grad
        rows = [f.detach(), *grad.detach().unbind(0)]
        if second:
            of_a = {}
            for a, _ in term.term.hessian_pairs:
                if a not in of_a:
                    found = None
                    if grad[a].requires_grad:
                        (found,) = torch.autograd.grad(grad[a].sum(), X, retain_graph=True,
                                                       allow_unused=True)
                    of_a[a] = X.new_zeros(k, n) if found is None else found.detach()
            rows += [of_a[a][b] for a, b in term.term.hessian_pairs]
    return torch.stack(rows)
