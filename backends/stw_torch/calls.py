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

import gc
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from .host_levels import LevelPlan, fits
from .lower import LoweredTerm, as_row, unoptimized


@dataclass(eq=False)
class Call:
    """One lowered term over the instances of all its groups."""

    term: LoweredTerm
    params: list
    times: torch.Tensor     # (N,) the instances' times, group after group
    k: int                  # variables per instance
    pairs: int              # second derivatives per instance
    start: int              # where its (k, N) inputs begin in the gathered inputs
    n: int                  # N: its instances
    host_times: np.ndarray | None = None   # on the CPU: times and params as numpy (host programs)
    host_params: list | None = None


@dataclass(eq=False)
class CallPlan:
    """The calls of a problem's groups and the index arrays that put their outputs in place."""

    calls: list[Call]
    inputs: torch.Tensor    # the slot of every input, call after call
    f_order: torch.Tensor   # instance -> its value's place among the calls' values
    h_order: torch.Tensor   # (group, pair, instance) entry -> its place among the calls' pairs
    n_slots: int
    autograd: bool = False  # derivatives by torch's autograd on the value programs (local())
    host: tuple | None = None   # on the CPU: inputs, f_order, h_order as numpy (values_host, local_host)
    # on the CPU: (program kind, dtype of the slot values) -> the calls' programs run together
    together: dict = field(default_factory=dict)
    # on the CPU: the same keys -> where the outputs lie in the rows (None: they cannot be read there)
    layouts: dict = field(default_factory=dict)

    @classmethod
    def build(cls, groups, n_slots: int, device: torch.device, autograd: bool = False) -> "CallPlan":
        """Merge ``groups`` (evaluate._Group) by lowered term and constants, in first-seen order."""
        by_key: dict[tuple, list] = {}
        for g in groups:
            key = (id(g.term), tuple(float(p) for p in g.params))
            by_key.setdefault(key, []).append(g)
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
            calls.append(Call(first.term, first.params, times, k, len(first.pairs), start, n))
            start += k * n
        cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0, np.int64)  # noqa: E731
        as_t = lambda a: torch.as_tensor(a, dtype=torch.int64, device=device)  # noqa: E731
        plan = cls(calls, as_t(cat(inputs)), as_t(np.argsort(cat(f_dest), kind="stable")),
                   as_t(np.argsort(cat(h_dest), kind="stable")), n_slots, autograd)
        if device.type == "cpu":
            plan.host = (plan.inputs.numpy(), plan.f_order.numpy(), plan.h_order.numpy())
            for c in calls:
                c.host_times, c.host_params = c.times.numpy(), [p.numpy() for p in c.params]
        return plan

    def values(self, v: torch.Tensor) -> torch.Tensor:
        """(instances,): every group's values at slot values ``v``, in the groups' layout."""
        x = v[self.inputs]
        with unoptimized():
            parts = [c.term.values(x[c.start:c.start + c.k * c.n].view(c.k, c.n), c.times, c.params)
                     for c in self.calls]
        return torch.cat(parts)[self.f_order] if parts else v.new_zeros(0)

    def local(self, v: torch.Tensor, second: bool = True):
        """Values (instances,), gradients per slot (slots,) and, with ``second``, second
        derivatives (entries,) at slot values ``v``, in the groups' layout (else None)."""
        x = v[self.inputs]
        f, g, h = [], [], []
        with unoptimized():
            for c in self.calls:
                X = x[c.start:c.start + c.k * c.n].view(c.k, c.n)
                if self.autograd:
                    rows = autograd_rows(c.term, X, c.times, c.params, second)
                else:
                    rows = (c.term.rows if second else c.term.first_rows)(X, c.times, c.params)
                f.append(rows[0])
                g += rows[1:1 + c.k]
                h += rows[1 + c.k:]
        empty = v.new_zeros(0)
        g_slot = v.new_zeros(self.n_slots)
        g_slot[self.inputs] = torch.cat(g) if g else empty
        return (torch.cat(f)[self.f_order] if f else empty, g_slot,
                (torch.cat(h)[self.h_order] if h else empty) if second else None)

    # --- on the CPU: the same numbers, the glue in numpy ---------------------------------------
    # A torch op on the CPU costs several microseconds whatever its size, a numpy one about one:
    # around the programs (gathers, concatenations, scatters) the torch glue cost more than the
    # programs themselves on small problems (particle_jet). The programs run on tensors sharing
    # the arrays' memory; gathers, scatters and concatenations move numbers without arithmetic.

    def _host_blocks(self, v: np.ndarray):
        """Each call with its (k, N) input block of the gathered slot values."""
        x = v[self.host[0]]
        return [(c, x[c.start:c.start + c.k * c.n].reshape(c.k, c.n)) for c in self.calls]

    def _host_rows(self, kind: str, v: np.ndarray) -> list[list[np.ndarray]]:
        """Each call's rows of its program ``kind`` at numpy slot values ``v``: the host programs
        of all calls run on rows together (:class:`Together`) from the second evaluation on."""
        inputs = [[*X, c.host_times, *c.host_params] for c, X in self._host_blocks(v)]
        key = (kind, v.dtype)
        together = self.together.get(key)
        if together is None:
            programs = [c.term.program(kind, host=True) for c in self.calls]
            rows, self.together[key] = Together.first(programs, inputs, [c.host_times for c in self.calls])
            return rows
        return together.run(inputs)

    def _read_in_place(self, kind: str, v: np.ndarray) -> dict | None:
        """The outputs of every call's ``kind`` program at ``v``, the arguments scattered into
        the rows of the programs run together (:class:`RowInputs`) and the outputs gathered
        from them straight into the arrays the callers return ("f": values per instance, "g":
        gradients per slot, "h": second derivatives; :class:`RowLayout`), instead of each
        call's inputs and rows copied in and out one by one (the same numbers, moved once:
        arm_throw's 17 programs 186/314/425 -> 141/226/312 µs for values/first/full). None
        before the programs run together (their first call) and where it cannot be done."""
        key = (kind, v.dtype)
        together = self.together.get(key)
        if together is None:
            return None
        if key not in self.layouts:
            self.layouts[key] = RowLayout.of(self, together)
        layout = self.layouts[key]
        if layout is None:
            return None
        out = layout.outputs(kind, self.n_slots)
        with np.errstate(all="ignore"):   # inf and nan come out silently, as from TorchScript
            for (plan, _), read, given in zip(together.buckets, layout.readers(out), layout.inputs):
                if plan.run_filled(given.lengths, lambda workspace, given=given: given.fill(workspace, v),
                                   read) is None:
                    return None   # another thread runs it: the rows' numbers are not ours
        return out

    def values_host(self, v: np.ndarray) -> np.ndarray:
        """:meth:`values` of numpy slot values, as numpy (CPU only)."""
        direct = self._read_in_place("value", v)
        if direct is not None:
            return direct["f"]
        parts = [rows[0] for rows in self._host_rows("value", v)]
        return np.concatenate(parts)[self.host[1]] if parts else np.zeros(0)

    def local_host(self, v: np.ndarray, second: bool = True):
        """:meth:`local` of numpy slot values, as numpy arrays (CPU only)."""
        if not self.autograd:
            direct = self._read_in_place("full" if second else "first", v)
            if direct is not None:
                return direct["f"], direct["g"], direct["h"] if second else None
        f, g, h = [], [], []
        if self.autograd:
            with unoptimized():
                every = [[r.numpy() for r in autograd_rows(c.term, torch.from_numpy(X), c.times, c.params, second)]
                         for c, X in self._host_blocks(v)]
        else:
            every = self._host_rows("full" if second else "first", v)
        for c, rows in zip(self.calls, every):
            f.append(rows[0])
            g += rows[1:1 + c.k]
            h += rows[1 + c.k:]
        g_slot = np.zeros(self.n_slots)
        if g:
            g_slot[self.host[0]] = np.concatenate(g)
        return (np.concatenate(f)[self.host[1]] if f else np.zeros(0), g_slot,
                (np.concatenate(h)[self.host[2]] if h else np.zeros(0)) if second else None)

    # --- a batch of B starts: slot values (B, slots) -----------------------------------------
    def _tile(self, X: torch.Tensor, c: Call) -> torch.Tensor:
        """A call's inputs of every start side by side: (k, B·N), start-major."""
        B = X.shape[0]
        block = X[:, c.start:c.start + c.k * c.n].reshape(B, c.k, c.n)
        return block.permute(1, 0, 2).reshape(c.k, B * c.n)

    def values_batch(self, V: torch.Tensor) -> torch.Tensor:
        """(B, instances): :meth:`values` of every start, one call per term for the batch."""
        B = V.shape[0]
        X = V[:, self.inputs]
        parts = [c.term(self._tile(X, c), c.times.repeat(B), c.params).reshape(B, c.n)
                 for c in self.calls]
        return torch.cat(parts, 1)[:, self.f_order] if parts else V.new_zeros(B, 0)

    def local_batch(self, V: torch.Tensor):
        """:meth:`local` of every start: (B, instances), (B, slots), (B, entries)."""
        B = V.shape[0]
        X = V[:, self.inputs]
        f, g, h = [], [], []
        for c in self.calls:
            out = c.term.full(self._tile(X, c), c.times.repeat(B), c.params)
            rows = out.reshape(-1, B, c.n).permute(1, 0, 2)          # (B, 1 + k + pairs, N)
            f.append(rows[:, 0])
            g.append(rows[:, 1:1 + c.k].reshape(B, -1))
            if c.pairs:
                h.append(rows[:, 1 + c.k:].reshape(B, -1))
        empty = V.new_zeros(B, 0)
        g_slot = V.new_zeros(B, self.n_slots)
        g_slot[:, self.inputs] = torch.cat(g, 1) if g else empty
        return (torch.cat(f, 1)[:, self.f_order] if f else empty, g_slot,
                torch.cat(h, 1)[:, self.h_order] if h else empty)


@dataclass(eq=False)
class RowLayout:
    """Where a kind's outputs lie once its programs have run on rows together (Together): for
    each bucket, the (row, column) of every output entry in the bucket's workspace, the outputs
    that are in no row (LevelPlan.loose: read from its registers, made (n,) float64 as
    Program.finish makes them), and their places in the output arrays ("f", "g", "h" as
    CallPlan.local_host returns them); and the entries that are numbers (a program's constant
    rows) with their places. Only where every call's program runs in a bucket; else :meth:`of`
    gives None and the rows are copied out as before."""

    sizes: dict                 # "f", "h" -> its length (the gradient "g" is the slots')
    gathers: list               # per bucket: (rows, columns, [(target, places, start, stop)], loose)
    numbers: list               # (target, places, values)
    inputs: list                # per bucket: its RowInputs
    # (bucket, the workspace's width) -> each entry's index in the flattened workspace
    flat: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, plan: CallPlan, together: "Together") -> "RowLayout | None":
        """The layout of ``together``'s outputs in ``plan``'s arrays, or None."""
        inputs, f_order, h_order = plan.host
        place = {"f": np.argsort(f_order, kind="stable"), "g": inputs,
                 "h": np.argsort(h_order, kind="stable")}   # concatenated entry -> its place
        bucket_of = {i: (b, j) for b, (_, members) in enumerate(together.buckets) for j, i in enumerate(members)}
        inputs = [RowInputs.of(plan, levels, members) for levels, members in together.buckets]
        if len(bucket_of) != len(plan.calls) or None in inputs:
            return None
        # per bucket: the (row, column, place) of every entry in a row, by target; the loose ones
        entries = [({"f": [], "g": [], "h": []}, []) for _ in together.buckets]
        numbers = {"f": [], "g": [], "h": []}
        start = {"f": 0, "g": 0, "h": 0}   # each target concatenates the calls' rows call by call
        row_of = [{reg: row for reg, row, _ in levels.output_rows} for levels, _ in together.buckets]
        for i, (call, program) in enumerate(zip(plan.calls, together.programs)):
            b, j = bucket_of[i]
            levels = together.buckets[b][0]
            loose = set(levels.loose[j])
            computed = iter(enumerate(program.host_fn.outputs))
            in_rows, in_registers = entries[b]
            for r in range(program.rows):
                target = "f" if r == 0 else "g" if r <= call.k else "h"
                at = start[target] + np.arange(call.n)
                start[target] += call.n
                if r in program.constants:
                    numbers[target].append((at, np.full(call.n, float(program.constants[r]))))
                    continue
                q, k = next(computed)
                if q in loose:
                    in_registers.append((target, place[target][at], levels.offsets[j] + k, call.n))
                    continue
                in_rows[target].append((np.full(call.n, row_of[b][levels.offsets[j] + k]), np.arange(call.n), at))
        cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0, np.int64)  # noqa: E731
        gathers = []
        for in_rows, in_registers in entries:
            spans, rows, columns, at = [], [], [], 0
            for target in ("f", "g", "h"):   # the gathered values target after target
                where = cat([a for _, _, a in in_rows[target]])
                rows += [r for r, _, _ in in_rows[target]]
                columns += [c for _, c, _ in in_rows[target]]
                if where.size:
                    spans.append((target, place[target][where], at, at + where.size))
                at += where.size
            gathers.append((cat(rows), cat(columns), spans, in_registers))
        return cls({"f": start["f"], "h": start["h"]}, gathers,
                   [(t, place[t][cat([a for a, _ in parts])], cat([v for _, v in parts]))
                    for t, parts in numbers.items() if parts], inputs)

    def outputs(self, kind: str, n_slots: int) -> dict:
        """The arrays to fill: values and second derivatives, and (but for values alone) the
        slots' gradient, zeros where no program's gradient lands as local_host's; the numbers
        already in place."""
        out = {"f": np.empty(self.sizes["f"]), "g": np.zeros(n_slots if kind != "value" else 0),
               "h": np.empty(self.sizes["h"])}
        for target, places, values in self.numbers:
            out[target][places] = values
        return out

    def readers(self, out: dict):
        """Per bucket, the ``read`` of LevelPlan.run_filled: its entries gathered from the rows,
        and its outputs in no row taken from the registers."""
        def reader(bucket, rows, columns, spans, in_registers):
            def read(R, registers):
                flat = self.flat.get((bucket, R.shape[1]))
                if flat is None:   # worked out once per width, not at every evaluation
                    flat = self.flat[(bucket, R.shape[1])] = rows * R.shape[1] + columns
                values = R.take(flat)
                for target, places, a, b in spans:
                    out[target][places] = values[a:b]
                for target, places, reg, n in in_registers:
                    value = registers[reg]
                    # a float64 number (0-d) is put in place as it is: as_row's broadcast view of
                    # it costs more (np.broadcast_to's checks) than the assignment, same numbers
                    out[target][places] = value if _is_float64(value, n) else as_row(value, n)
                return True
            return read
        return [reader(bucket, *gather) for bucket, gather in enumerate(self.gathers)]


def _is_float64(value, n: int) -> bool:
    """Whether ``value`` is a float64 number or (n,) array: one that as_row leaves as it is or
    only repeats."""
    return value.__class__ is float or (value.__class__ is np.ndarray and value.dtype == np.float64
                                        and value.shape in ((), (n,)))


class RowInputs:
    """How one bucket of programs run together (Together) gets its arguments straight from the
    slot values: the DOF arguments' rows of the workspace written by one scatter of ``v``'s
    entries, the times and constants by another, and the registers copied from a template that
    already holds every argument (views of its row, the times, the constants): instead of the
    calls' input blocks gathered, listed and copied row by row (LevelPlan.run_reading)."""

    def __init__(self, plan: CallPlan, levels, members: list, lengths: tuple):
        self.plan, self.levels, self.members, self.lengths = plan, levels, members, lengths
        self._for = None    # the workspace the arrays below were made for

    @classmethod
    def of(cls, plan: CallPlan, levels, members: list) -> "RowInputs | None":
        """The inputs of ``levels`` (a LevelPlan of the calls ``members``, whose lengths are
        those of the run it was read from: the same calls), or None when a program takes other
        arguments than its call's blocks, times and constants, or has no instance count."""
        if any(levels.programs[j].n_args != plan.calls[i].k + 1 + len(plan.calls[i].host_params)
               for j, i in enumerate(members)) or min(levels.lengths) < 0:
            return None
        return cls(plan, levels, members, tuple(levels.lengths))

    def _bind(self, workspace: tuple) -> None:
        R = workspace[0]
        width, rows = R.shape[1], self.levels.arguments_on_rows()
        template = list(self.levels.template)
        dest, src, fixed_dest, fixed, gathered = [], [], [], [], []
        for j, i in enumerate(self.members):
            call, o, n = self.plan.calls[i], self.levels.offsets[j], self.lengths[j]
            for a in range(self.levels.programs[j].n_args):
                at = rows.get((j, a))
                if a < call.k:
                    slots = self.plan.host[0][call.start + a * call.n:call.start + (a + 1) * call.n]
                    if at is None:
                        gathered.append((o + a, slots))
                        continue
                    template[o + a] = R[at, :n]
                    dest.append(at * width + np.arange(n))
                    src.append(slots)
                    continue
                value = call.host_times if a == call.k else call.host_params[a - call.k - 1]
                template[o + a] = value
                if at is not None:
                    fixed_dest.append(at * width + np.arange(n))
                    fixed.append(np.broadcast_to(np.asarray(value, np.float64), (n,)))
        cat = lambda parts, kind=np.int64: np.concatenate(parts) if parts else np.zeros(0, kind)  # noqa: E731
        self._template, self._gathered = template, gathered
        self._dest, self._src = cat(dest), cat(src)
        self._fixed_dest, self._fixed = cat(fixed_dest), cat(fixed, np.float64)
        self._for = R

    def fill(self, workspace: tuple, v: np.ndarray) -> list:
        """What LevelPlan.run_filled asks: the arguments at slot values ``v`` in the workspace's
        rows; the registers with them."""
        R = workspace[0]
        if self._for is not R:
            self._bind(workspace)
        flat = R.reshape(-1)             # a view: LevelPlan's workspace is one np.zeros block
        flat[self._dest] = v[self._src]
        flat[self._fixed_dest] = self._fixed
        r = self._template.copy()
        for reg, slots in self._gathered:
            r[reg] = v[slots]
        return r


@contextmanager
def collector_paused():
    """Python's cyclic garbage collector off for a while: plans allocate tens of thousands of
    small tuples, and each collection they trigger walks the millions of objects torch's import
    left (basketball's plans: 0.22-0.28 s to build with it, 0.07-0.08 s without). Nothing built
    meanwhile holds a reference cycle that must be freed at once."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


TOGETHER_WIDTH = 256   # rows this wide cost what one instance's do: any calls up to it share them


class Together:
    """The host programs of one kind of a problem's calls, run on rows together
    (host_levels.LevelPlan of several parts): an evaluation makes a numpy call per depth and
    operator across all its terms, not one per term and instruction (arm_throw: 17 programs per
    evaluation).

    Calls share rows in buckets by instance count: a bucket's rows are as wide as its longest
    call's, and a call joins while its count is at least a quarter of that width, or the width is
    at most TOGETHER_WIDTH. Calls without a host program run as before."""

    def __init__(self, programs: list, times: list, buckets: list[tuple[LevelPlan, list[int]]]):
        self.programs, self.times = programs, times   # each call's program of this kind, its times
        self.buckets = buckets

    @classmethod
    def first(cls, programs: list, inputs: list, times: list) -> tuple[list, "Together"]:
        """The calls' rows, each host program's tape run instruction by instruction (and read
        for the plans), and the Together that runs them from then on."""
        with collector_paused():
            return cls._first(programs, inputs, times)

    @classmethod
    def _first(cls, programs: list, inputs: list, times: list) -> tuple[list, "Together"]:
        rows, traced = [], {}
        with np.errstate(all="ignore"):   # inf and nan come out silently, as from TorchScript
            for i, (program, values, t) in enumerate(zip(programs, inputs, times)):
                if program.host_fn is None:
                    rows.append(program.host(values, t))
                    continue
                traced[i] = program.host_fn.registers(values)
                rows.append(program.finish([traced[i][k] for k in program.host_fn.outputs], t.shape[0]))
        order = sorted(traced, key=lambda i: -times[i].shape[0])
        buckets, members = [], []
        for i in order:
            n = times[i].shape[0]
            if members and not (n * 4 >= times[members[0]].shape[0] or times[members[0]].shape[0] <= TOGETHER_WIDTH):
                buckets.append(members)
                members = []
            members.append(i)
        if members:
            buckets.append(members)
        plans = []
        while buckets:   # halved while its registers (more than its rows) might not fit (basketball)
            members = sorted(buckets.pop())
            if len(members) > 1 and not fits(sum(len(traced[i]) for i in members), [times[i].shape[0] for i in members]):
                buckets += [members[:len(members) // 2], members[len(members) // 2:]]
                continue
            plan = LevelPlan([(programs[i].host_fn, inputs[i], traced[i]) for i in members])
            if plan.rows and plan.fits():
                plans.append((plan, members))
        return rows, cls(programs, times, plans)

    def run(self, inputs: list) -> list:
        """Each call's rows of its program at its ``inputs``, the planned calls on rows."""
        rows: list = [None] * len(self.programs)
        with np.errstate(all="ignore"):   # inf and nan come out silently, as from TorchScript
            for plan, members in self.buckets:
                for i, out, loose in zip(members, plan.run([inputs[i] for i in members]), plan.loose):
                    rows[i] = self.programs[i].finish(out, self.times[i].shape[0], loose)
        return [row if row is not None else program.host(values, t)
                for row, program, values, t in zip(rows, self.programs, inputs, self.times)]


def autograd_rows(term: LoweredTerm, X: torch.Tensor, times: torch.Tensor, params: list,
                  second: bool) -> list[torch.Tensor]:
    """What :meth:`LoweredTerm.rows` (``second``) or ``first_rows`` give, by torch's autograd on
    the term's value program alone (``derivatives=autograd``): derivatives found independently
    of the symbolic ones, to hold them against. An instance's value depends on its own column of
    X only, so the gradient of the sum is every instance's gradient; each first derivative that
    a Hessian pair needs takes one more backward pass."""
    k, n = X.shape
    with torch.enable_grad():
        X = X.detach().requires_grad_(True)
        f = term.values(X, times, params)
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
    return rows
