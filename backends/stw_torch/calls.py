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

from dataclasses import dataclass, field

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
    drivers: dict = field(default_factory=dict)    # program kind -> its driver (_driver)
    arguments: dict = field(default_factory=dict)  # (kind, device) -> the driver's fixed arguments

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

    def _driver(self, kind: str, device: torch.device):
        """A TorchScript function of V (B, slots) that runs every call's program ``kind`` and
        puts its outputs in place, and its fixed arguments on ``device``: one call from Python
        per evaluation instead of one per term (a call from Python cost 15-19 µs, one from
        TorchScript 2-3; cat_mouse's 8 programs: 0.47 -> 0.30 ms). Written and compiled once
        per plan and kind (3-20 ms)."""
        if kind not in self.drivers:
            programs = {f"p{i}": c.term.program(kind) for i, c in enumerate(self.calls)}
            lines = ["def plan(V: torch.Tensor, inputs: torch.Tensor, T: List[torch.Tensor], P: List[torch.Tensor], "
                     "A: List[List[torch.Tensor]], f_order: torch.Tensor, h_order: torch.Tensor, n_slots: int):",
                     "    B = V.shape[0]", "    X = torch.index_select(V, 1, inputs)",
                     "    f: List[torch.Tensor] = []", "    g: List[torch.Tensor] = []", "    h: List[torch.Tensor] = []"]
            for i, c in enumerate(self.calls):    # a call's (k, B·N) inputs, start-major, and its rows
                pairs = len(c.term.term.hessian_pairs) if kind == "full" else 0
                lines += [f"    r = p{i}(X[:, {c.start}:{c.start + c.k * c.n}].reshape(B, {c.k}, {c.n}).transpose(0, 1)"
                          f".reshape({c.k}, B * {c.n}), T[{i}].repeat([B]), P[{i}], A[{i}]).reshape(-1, B, {c.n}).transpose(0, 1)",
                          "    f.append(r[:, 0])"]
                lines += [f"    g.append(r[:, 1:{1 + c.k}].reshape(B, {c.k * c.n}))"] if kind != "value" else []
                lines += [f"    h.append(r[:, {1 + c.k}:].reshape(B, {pairs * c.n}))"] if pairs else []
            lines += ["    F = torch.cat(f, 1)[:, f_order]", "    G = V.new_zeros([B, n_slots])",
                      "    if len(g):", "        G[:, inputs] = torch.cat(g, 1)",
                      "    H = torch.cat(h, 1)[:, h_order] if len(h) else V.new_zeros([B, 0])", "    return F, G, H"]
            unit = torch.jit.CompilationUnit()
            unit.define("\n".join(lines) + "\n", rcb=lambda name: programs[name].fn if name in programs else torch)
            self.drivers[kind] = unit.plan
        if (kind, device) not in self.arguments:
            self.arguments[(kind, device)] = (
                self.inputs, [c.times for c in self.calls], [c.params for c in self.calls],
                [c.term.program(kind).arrays_on(device) for c in self.calls], self.f_order, self.h_order, self.n_slots)
        return self.drivers[kind], self.arguments[(kind, device)]

    def _run(self, kind: str, V: torch.Tensor):
        """The driver of ``kind`` at slot values V: values, gradients per slot, second derivatives."""
        if not self.calls:
            return V.new_zeros(V.shape[0], 0), V.new_zeros(V.shape[0], self.n_slots), V.new_zeros(V.shape[0], 0)
        driver, arguments = self._driver(kind, V.device)
        with unoptimized():   # the graph executor's optimizing took 0.5 s for the arm's plan, and saved nothing
            return driver(V, *arguments)

    def values(self, V: torch.Tensor) -> torch.Tensor:
        """(B, instances): every group's values at slot values V (B, slots), in the groups' layout."""
        return self._run("value", V)[0]

    def local(self, V: torch.Tensor, second: bool = True):
        """Values (B, instances), gradients per slot (B, slots) and, with ``second``, second
        derivatives (B, entries) at slot values V (B, slots), in the groups' layout (else None)."""
        if not self.autograd:
            f, g, h = self._run("full" if second else "first", V)
            return f, g, h if second else None
        B = V.shape[0]
        X = V[:, self.inputs]
        f, g, h = [], [], []
        for c in self.calls:
            block = X[:, c.start:c.start + c.k * c.n].reshape(B, c.k, c.n).transpose(0, 1).reshape(c.k, B * c.n)
            rows = autograd_rows(c.term, block, c.times.repeat(B), c.params, second)
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
        with unoptimized():
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
