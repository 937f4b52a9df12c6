"""Term groups merged into calls: all the groups of one lowered term (with the same constants)
are evaluated by one call of its program over all their instances side by side (a linkage's
torque as an objective and as a flight constraint; acrobat: 13 groups in 8 calls), and one
TorchScript driver per plan makes every call: it gathers the inputs from the slot values and
puts the outputs back in the groups' layout (values per instance, gradients per slot, second
derivatives per group and pair) by fixed index arrays.
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
    autograd: tuple | None = None   # derivatives=autograd: masks and index arrays (local())
    drivers: dict = field(default_factory=dict)    # (kind, device) -> driver, fixed arguments

    @classmethod
    def build(cls, groups, n_slots: int, device: torch.device, autograd: bool = False) -> "CallPlan":
        """Merge ``groups`` (evaluate._Group) by lowered term and constants, in first-seen order."""
        by_key: dict[tuple, list] = {}
        for g in groups:
            by_key.setdefault((id(g.term), tuple(g.params.tolist())), []).append(g)
        calls, inputs, f_dest, h_dest = [], [], [], []
        h_offsets, offset, h_a, h_b = {}, 0, [], []
        masks = np.zeros((max([g.term.k for g in groups], default=0), n_slots))
        for g in groups:                      # the groups' own layout of second derivatives
            h_offsets[id(g)] = offset
            offset += len(g.pairs) * g.n
            for a in range(g.term.k):         # the slots of each instance's a-th variable
                masks[a, g.slot + a * g.n:g.slot + (a + 1) * g.n] = 1.0
            for a, b in g.pairs:              # second derivative (a, b): at the b-th slot
                h_a += [a] * g.n
                h_b.append(g.slot + b * g.n + np.arange(g.n))
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
        derived = (torch.as_tensor(masks, dtype=torch.float64, device=device), as_t(h_a), as_t(cat(h_b)))
        return cls(calls, as_t(cat(inputs)), as_t(np.argsort(cat(f_dest), kind="stable")),
                   as_t(np.argsort(cat(h_dest), kind="stable")), n_slots, derived if autograd else None)

    def _driver(self, kind: str, device: torch.device, one: bool):
        """A TorchScript function of V (B, slots; ``one``: B = 1) that runs every call's program
        ``kind`` and puts its outputs in place, and its fixed arguments on ``device``, compiled
        once (3-20 ms): one call from Python per evaluation, not one per term (15-19 µs each)."""
        if (kind, device, one) not in self.drivers:
            programs = {f"p{i}": c.term.program(kind) for i, c in enumerate(self.calls)}
            lines = ["def plan(V: torch.Tensor, inputs: torch.Tensor, T: List[torch.Tensor], P: List[torch.Tensor], "
                     "A: List[List[torch.Tensor]], f_order: torch.Tensor, h_order: torch.Tensor, n_slots: int):",
                     "    B = V.shape[0]", "    X = torch.index_select(V, 1, inputs)",
                     "    f: List[torch.Tensor] = []", "    g: List[torch.Tensor] = []", "    h: List[torch.Tensor] = []"]
            for i, c in enumerate(self.calls):    # a call's (k, B·N) inputs, start-major, and its rows
                pairs, block, r = len(c.term.term.hessian_pairs) if kind == "full" else 0, f"{c.start}:{c.start + c.k * c.n}", "r[:, "
                lines.append(f"    r = p{i}(X[0, {block}].view({c.k}, {c.n}), T[{i}], P[{i}], A[{i}])" if one else
                             f"    r = p{i}(X[:, {block}].reshape(B, {c.k}, {c.n}).transpose(0, 1).reshape({c.k}, B * {c.n}), "
                             f"T[{i}].repeat([B]), P[{i}], A[{i}]).reshape(-1, B, {c.n}).transpose(0, 1)")
                r = "r[" if one else r
                lines += [f"    f.append({r}0:1].reshape(B, {c.n}))"]
                lines += [f"    g.append({r}1:{1 + c.k}].reshape(B, {c.k * c.n}))"] if kind != "value" else []
                lines += [f"    h.append({r}{1 + c.k}:].reshape(B, {pairs * c.n}))"] if pairs else []
            lines += ["    F = torch.cat(f, 1)[:, f_order]", "    G = V.new_zeros([B, n_slots])",
                      "    if len(g):", "        G[:, inputs] = torch.cat(g, 1)",
                      "    H = torch.cat(h, 1)[:, h_order] if len(h) else V.new_zeros([B, 0])", "    return F, G, H"]
            unit = torch.jit.CompilationUnit()
            unit.define("\n".join(lines) + "\n", rcb=lambda name: programs[name].fn if name in programs else torch)
            self.drivers[(kind, device, one)] = unit.plan, (
                self.inputs, [c.times for c in self.calls], [c.params for c in self.calls],
                [c.term.program(kind).arrays_on(device) for c in self.calls], self.f_order, self.h_order, self.n_slots)
        return self.drivers[(kind, device, one)]

    def _run(self, kind: str, V: torch.Tensor):
        """The driver of ``kind`` at slot values V: values, gradients per slot, second derivatives."""
        if not self.calls:
            return V.new_zeros(V.shape[0], 0), V.new_zeros(V.shape[0], self.n_slots), V.new_zeros(V.shape[0], 0)
        driver, arguments = self._driver(kind, V.device, V.shape[0] == 1)
        with unoptimized():   # the graph executor's optimizing took 0.5 s for the arm's plan, and saved nothing
            return driver(V, *arguments)

    def values(self, V: torch.Tensor) -> torch.Tensor:
        """(B, instances): every group's values at slot values V (B, slots), in the groups' layout."""
        return self._run("value", V)[0]

    def local(self, V: torch.Tensor, second: bool = True):
        """Values (B, instances), gradients per slot (B, slots) and, with ``second``, second
        derivatives (B, entries) at slot values V (B, slots), in the groups' layout (else None)."""
        if self.autograd is None:
            f, g, h = self._run("full" if second else "first", V)
            return f, g, h if second else None
        # derivatives=autograd: torch's autograd on the value programs alone, independent of the
        # symbolic derivatives. An instance's value depends on its own slots only, so the gradient
        # of the values' sum is each instance's gradient at its slots; one more backward pass from
        # the gradient at the slots of every instance's a-th variable gives each ∂²f/∂v_a∂v_b at
        # the instance's b-th slot.
        masks, h_a, h_b = self.autograd
        with torch.enable_grad():
            V = V.detach().requires_grad_(True)
            f = self._run("value", V)[0]
            grad = torch.autograd.grad(f.sum(), V, create_graph=second, allow_unused=True)[0] if f.requires_grad else None
            g = V.new_zeros(V.shape) if grad is None else grad
            if not second:
                return f.detach(), g.detach(), None
            if not h_a.numel():
                return f.detach(), g.detach(), V.new_zeros(V.shape[0], 0)
            rows = [torch.autograd.grad((g * mask).sum(), V, retain_graph=True, allow_unused=True)[0]
                    if g.requires_grad else None for mask in masks]
        H = torch.stack([V.new_zeros(V.shape) if r is None else r.detach() for r in rows])
        return f.detach(), g.detach(), H[h_a, :, h_b].T
