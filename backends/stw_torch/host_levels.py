"""A host program run on a (registers, n) array it keeps: fewer, cheaper numpy and torch calls.

A tape (host.py) makes one numpy call per instruction, and one torch round trip per function
(``from_numpy``, the function, ``.numpy()``). On a few dozen instances a call costs its overhead,
not its numbers: arm_throw's 17 programs spent most of their time calling. Here each value the
program computes has a row in an array kept between calls, so

- instructions at the same depth of the program's graph with the same operator (+, -, *, /,
  negation) run as one numpy call on their rows (operands gathered with ``take`` where their rows
  are not consecutive), where the cost model below says that is cheaper than one call each;
- the others write into their rows through views made once (``out=``), and torch's functions of
  one array (sin, cos, ...) write through tensor views of the same memory: no conversion.

The numbers do not change: +, -, *, / and negation are correctly rounded elementwise whatever the
layout, and a torch function writes what it would return (same kernel, same length). Everything
else (comparisons, several arguments, what depends on parameters alone) runs as the tape does, on
the same values. Which instructions may use rows is read from one run of the tape itself
(:class:`LevelPlan`): those whose operands and result are float64 arrays of the instances'
length, or numbers beside them.
"""

from __future__ import annotations

import threading

import numpy as np
import torch

GROUPED = {"add": np.add, "sub": np.subtract, "mul": np.multiply, "truediv": np.true_divide,
           "neg": np.negative}
_EXACT_INT = 2**53          # a Python int up to this size is the same number as a float64
# The cost model, in units of one numpy call on rows through views made before: a grouped call
# costs about 1.4 of them, and each operand gathered by ``take`` about 1 more (measured: 0.66 µs
# a call, 0.9 µs grouped, 0.65 µs a gather, on 84 instances).
GROUP_CALL, GATHER = 1.4, 1.0
WORKSPACE_FLOATS = 1 << 20  # rows x n kept per program at most (8 MB); larger ones are not kept


def _is_row(v, n: int) -> bool:
    return v.__class__ is np.ndarray and v.dtype == np.float64 and v.shape == (n,)


def _is_scalar(v) -> bool:
    """A number that numpy puts beside an array as the float64 it is."""
    if v.__class__ is float or v.__class__ is np.float64:
        return True
    if v.__class__ is int:
        return abs(v) <= _EXACT_INT
    return v.__class__ is np.ndarray and v.dtype == np.float64 and v.shape == ()


def _consecutive(rows: list[int]) -> bool:
    return all(b == a + 1 for a, b in zip(rows, rows[1:]))


def signature(values: tuple) -> tuple:
    """What a plan depends on: each argument's type, dtype and number of dimensions."""
    return tuple((v.__class__, getattr(v, "dtype", None), getattr(v, "ndim", None)) for v in values)


class LevelPlan:
    """How to run a tape on rows, for arguments like those of the run it was read from.

    ``steps`` are ``(op, i, j, k)`` as host.host_function binds them (op a function of
    registers i and j, or with j = -1 of the register list and places i); ``names`` gives each
    step's arithmetic operator (None: not plain arithmetic) and ``functions`` its torch function
    of one array (None: not one); ``registers`` is every register's value in one run of the tape
    on ``arguments``, and ``constant`` the registers computed from numbers alone."""

    def __init__(self, n_args: int, template: list, steps: list, names: list, functions: list,
                 outputs, registers: list, constant: set, arguments: tuple):
        # the argument that gives the instances' number (None: no array, nothing on rows)
        self.length_of = next((a for a, v in enumerate(arguments) if v.__class__ is np.ndarray and v.ndim == 1), None)
        n = -1 if self.length_of is None else arguments[self.length_of].shape[0]
        self.n_args, self.outputs, self.template = n_args, tuple(outputs), template
        made = {k for *_, k in steps}

        def row_valued(r: int) -> bool:
            return _is_row(registers[r], n) or _is_scalar(registers[r])

        level = [0] * len(registers)
        buckets: dict[tuple, list] = {}     # (level, operator) -> its arithmetic steps
        by_level: dict[int, list] = {}      # level -> what runs there, in order
        for step, name, function in zip(steps, names, functions):
            _, i, j, k = step
            level[k] = 1 + max((level[r] for r in ((i, j) if j >= 0 else i)), default=0)
            on_rows = k not in constant and _is_row(registers[k], n)
            if name is not None and on_rows and row_valued(i) and row_valued(j):
                if (level[k], name) not in buckets:
                    by_level.setdefault(level[k], []).append(("arith", name, buckets.setdefault((level[k], name), [])))
                buckets[(level[k], name)].append(step)
            elif function is not None and on_rows and _is_row(registers[i], n):
                by_level.setdefault(level[k], []).append(("torch", function, step))
            else:
                by_level.setdefault(level[k], []).append(("step", step))
        row: dict[int, int] = {}            # register -> its row

        def place(r: int) -> int:
            if r not in row:
                row[r] = len(row)
            return row[r]

        operands = {r for members in buckets.values() for _, i, j, _ in members for r in (i, j)}
        operands |= {item[2][1] for items in by_level.values() for item in items if item[0] == "torch"}
        self.argument_rows = [(a, place(a)) for a in range(n_args) if a in operands]
        fixed = sorted(r for r in operands if r >= n_args and (r in constant or r not in made))
        self.fixed = [(place(r), float(registers[r])) for r in fixed]
        in_rows: set[int] = set()           # registers whose value is in its row only
        schedule = []                       # ("group" | "row" | "torch" | "step", ...) by rows
        for lvl in sorted(by_level):
            for item in by_level[lvl]:
                if item[0] == "step":       # as the tape runs it; its row operands read as views
                    _, i, j, k = item[1]
                    reads = [(r, row[r]) for r in ((i, j) if j >= 0 else i) if r in in_rows]
                    writes = place(k) if k in operands and k not in constant else -1
                    schedule.append(("step", item[1], reads, writes))
                elif item[0] == "torch":
                    _, function, (_, i, _, k) = item
                    schedule.append(("torch", function, row[i], place(k)))
                    in_rows.add(k)
                else:
                    schedule += self._arith(item[1], item[2], row, place)
                    in_rows.update(k for *_, k in item[2])
        self.schedule = schedule if self.length_of is not None else []
        self.rows = len(row)
        self.output_rows = {r: row[r] for r in set(outputs) & in_rows}
        self._kept: tuple | None = None     # (n, workspace) of the last call
        self._lock = threading.Lock()

    @staticmethod
    def _arith(name: str, members: list, row: dict, place) -> list:
        """One bucket's steps: one grouped call, or one call per instruction, whichever the cost
        model finds cheaper."""
        unary = name == "neg"
        outs = [place(k) for *_, k in members]
        left = [row[i] for _, i, _, _ in members]
        right = None if unary else [row[j] for _, _, j, _ in members]
        gathers = (not _consecutive(left)) + (not unary and not _consecutive(right))
        if len(members) > 1 and GROUP_CALL + GATHER * gathers < len(members):
            return [("group", GROUPED[name], left, right, (outs[0], outs[-1] + 1))]
        return [("row", GROUPED[name], a, None if unary else b, o)
                for a, b, o in zip(left, right or left, outs)]

    def _workspace(self, n: int) -> tuple:
        """The rows for n instances, the fixed numbers in place, and the schedule bound to
        views of them."""
        R = np.empty((self.rows, n))
        T = torch.from_numpy(R)
        for at, value in self.fixed:
            R[at] = value

        def operand(rows):
            if rows is None:
                return None, None
            if _consecutive(rows):
                return R[rows[0]:rows[-1] + 1], None
            return None, np.array(rows, np.intp)

        bound = []
        for item in self.schedule:
            kind = item[0]
            if kind == "group":
                _, ufunc, left, right, (a, b) = item
                bound.append((0, ufunc, *operand(left), *operand(right), R[a:b]))
            elif kind == "row":
                _, ufunc, i, j, k = item
                bound.append((1, ufunc, R[i], None if j is None else R[j], R[k]))
            elif kind == "torch":
                _, function, i, k = item
                bound.append((2, function, T[i], T[k]))
            else:
                _, step, reads, writes = item
                bound.append((3, step, [(r, R[at]) for r, at in reads], R[writes] if writes >= 0 else None))
        arguments = [(a, R[at]) for a, at in self.argument_rows]
        outputs = np.array(list(self.output_rows.values()), np.intp)
        return R, bound, arguments, outputs

    def run(self, values: tuple, reference) -> list:
        """The tape's outputs for ``values`` (arguments of this plan's signature); through
        ``reference`` (the tape as it is) while another thread runs this plan."""
        if not self._lock.acquire(blocking=False):
            return reference(values)
        try:
            n = values[self.length_of].shape[0]
            kept = self._kept
            if kept is None or kept[0] != n:
                if self.rows * max(n, 1) > WORKSPACE_FLOATS:
                    return reference(values)
                kept = self._kept = (n, self._workspace(n))
            R, bound, arguments, output_rows = kept[1]
            r = self.template.copy()
            r[:self.n_args] = values
            for a, view in arguments:
                view[...] = values[a]
            for step in bound:
                kind = step[0]
                if kind == 0:
                    _, ufunc, lv, li, rv, ri, out = step
                    x = lv if li is None else R.take(li, 0)
                    if rv is None and ri is None:
                        ufunc(x, out=out)
                    else:
                        ufunc(x, rv if ri is None else R.take(ri, 0), out=out)
                elif kind == 1:
                    _, ufunc, a, b, out = step
                    if b is None:
                        ufunc(a, out=out)
                    else:
                        ufunc(a, b, out=out)
                elif kind == 2:
                    step[1](step[2], out=step[3])
                else:
                    _, (f, i, j, k), reads, writes = step
                    for reg, view in reads:
                        r[reg] = view
                    value = r[k] = f(r[i], r[j]) if j >= 0 else f(r, i)
                    if writes is not None:
                        writes[...] = value
            if len(output_rows):            # copied out: the rows are written again next call
                for reg, value in zip(self.output_rows, R.take(output_rows, 0)):
                    r[reg] = value
            return [r[k] for k in self.outputs]
        finally:
            self._lock.release()
