"""Host programs run on a (registers, n) array they keep: fewer, cheaper numpy and torch calls.

A tape (host.py) makes one numpy call per instruction, and one torch round trip per function
(``from_numpy``, the function, ``.numpy()``). On a few dozen instances a call costs its overhead,
not its numbers: arm_throw's 17 programs spent most of their time calling. Here each value the
programs compute has a row in an array kept between calls, so

- instructions at the same depth of their program's graph with the same operator (+, -, *, /,
  negation), across all the programs run together (a window's terms: calls.Together), run as
  one numpy call on their rows (operands gathered with ``take`` where their rows are not
  consecutive), where the cost model below says that is cheaper than one call each;
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


def fits(rows: int, lengths) -> bool:
    """Whether ``rows`` as wide as the longest of ``lengths`` fit in WORKSPACE_FLOATS."""
    return rows * max(1, *lengths) <= WORKSPACE_FLOATS


def signature(values: tuple) -> tuple:
    """What a plan depends on: each argument's type, dtype and number of dimensions."""
    return tuple((v.__class__, getattr(v, "dtype", None), getattr(v, "ndim", None)) for v in values)


class LevelPlan:
    """How to run one or several host programs (host.HostProgram) on rows, for arguments like
    those of the run it was read from: ``parts`` lists each program with its arguments and every
    register's value in that run (``program.registers``). Several programs share one array, rows
    as wide as the longest one's instances, and their arithmetic of one depth and operator runs
    as one call across them; each program's rows are used up to its own length only."""

    def __init__(self, parts: list):
        self.programs = [program for program, _, _ in parts]
        self.offsets, registers, template, steps, names, functions, constant = [], [], [], [], [], [], set()
        self.lengths, self.length_of, part_of = [], [], []   # part_of: register -> its program
        for c, (program, arguments, traced) in enumerate(parts):
            o = len(registers)
            self.offsets.append(o)
            at = next((a for a, v in enumerate(arguments) if v.__class__ is np.ndarray and v.ndim == 1), None)
            n = -1 if at is None else arguments[at].shape[0]
            self.length_of.append(at)
            self.lengths.append(n)
            registers += traced
            part_of += [c] * len(traced)
            template += program.template
            steps += [(f, tuple(p + o for p in i) if j < 0 else i + o, j if j < 0 else j + o, k + o)
                      for f, i, j, k in program.steps]
            names += program.names
            functions += program.functions
            constant |= {r + o for r in program.constant}
        self.template = template
        made = {k for *_, k in steps}
        arguments = {o + a: (c, a) for c, (o, (program, _, _)) in enumerate(zip(self.offsets, parts))
                     for a in range(program.n_args)}

        # each register once: an (n,) float64 array of its program's length (a row), or a number
        is_row = [_is_row(v, self.lengths[c]) for v, c in zip(registers, part_of)]
        row_valued = [row or _is_scalar(v) for row, v in zip(is_row, registers)]
        level = [0] * len(registers)
        buckets: dict[tuple, list] = {}     # (level, operator) -> its arithmetic steps
        by_level: dict[int, list] = {}      # level -> what runs there, in order
        for step, name, function in zip(steps, names, functions):
            _, i, j, k = step
            level[k] = 1 + (max(level[i], level[j]) if j >= 0 else max((level[r] for r in i), default=0))
            on_rows = is_row[k] and k not in constant
            if name is not None and on_rows and row_valued[i] and row_valued[j]:
                if (level[k], name) not in buckets:
                    by_level.setdefault(level[k], []).append(("arith", name, buckets.setdefault((level[k], name), [])))
                buckets[(level[k], name)].append(step)
            elif function is not None and on_rows and is_row[i]:
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
        self.argument_rows = [(*arguments[r], place(r)) for r in sorted(operands & arguments.keys())]
        fixed = sorted(r for r in operands if r not in arguments and (r in constant or r not in made))
        self.fixed = [(place(r), float(registers[r])) for r in fixed]
        in_rows: set[int] = set()           # registers whose value is in its row only
        schedule = []                       # ("group" | "row" | "torch" | "step", ...) by rows
        for lvl in sorted(by_level):
            for item in by_level[lvl]:
                if item[0] == "step":       # as the tape runs it; its row operands read as views
                    _, i, j, k = item[1]
                    reads = [(r, row[r], part_of[r]) for r in ((i, j) if j >= 0 else i) if r in in_rows]
                    writes = (place(k), part_of[k]) if k in operands and k not in constant else None
                    schedule.append(("step", item[1], reads, writes))
                elif item[0] == "torch":
                    _, function, (_, i, _, k) = item
                    schedule.append(("torch", function, row[i], place(k), part_of[k]))
                    in_rows.add(k)
                else:
                    schedule += self._arith(item[1], item[2], row, place)
                    in_rows.update(k for *_, k in item[2])
        self.schedule = schedule
        self.rows = len(row)
        self.output_rows = [(r, row[r], part_of[r]) for r in sorted(
            {o + k for o, program in zip(self.offsets, self.programs) for k in program.outputs} & in_rows)]
        # each program's outputs that do not come from a row (steps', numbers): the only ones
        # that may not be (n,) float64 arrays
        self.loose = [tuple(i for i, k in enumerate(program.outputs) if o + k not in in_rows)
                      for o, program in zip(self.offsets, self.programs)]
        self._kept: tuple | None = None     # (lengths, workspace) of the last call
        self._lock = threading.Lock()

    def fits(self) -> bool:
        """Whether its rows for the lengths it was read from fit in WORKSPACE_FLOATS."""
        return fits(self.rows, self.lengths)

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

    def _workspace(self, lengths: tuple) -> tuple:
        """The rows for these lengths (zeros past each program's own), the fixed numbers in
        place, and the schedule bound to views of them."""
        width = max(1, *lengths)
        R = np.zeros((self.rows, width))
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
                _, function, i, k, c = item
                bound.append((2, function, T[i, :lengths[c]], T[k, :lengths[c]]))
            else:
                _, step, reads, writes = item
                bound.append((3, step, [(r, R[at, :lengths[c]]) for r, at, c in reads],
                              None if writes is None else R[writes[0], :lengths[writes[1]]]))
        arguments = [(c, a, R[at, :lengths[c]] if lengths[c] >= 0 else R[at]) for c, a, at in self.argument_rows]
        outputs = np.array([at for _, at, _ in self.output_rows], np.intp)
        ends = [lengths[c] for _, _, c in self.output_rows]
        return R, bound, arguments, outputs, ends

    def run(self, values: list) -> list:
        """Each program's outputs for its ``values`` (arguments of this plan's kinds); through the
        tapes as they are while another thread runs this plan."""
        got = self.run_reading(values, self._outputs)
        if got is None:
            return [program.reference(v) for program, v in zip(self.programs, values)]
        return got

    def run_reading(self, values: list, read):
        """``read(workspace, registers)`` after running on rows, while no other thread can write
        the rows: every output of ``output_rows`` lies in its row of the workspace (its
        program's length of it), the others in ``registers``. None where it cannot run on rows
        (another thread runs this plan, or the rows would not fit)."""
        lengths = tuple(-1 if at is None else v[at].shape[0] for at, v in zip(self.length_of, values))
        return self.run_filled(lengths, lambda workspace: self._arguments(workspace, values), read)

    def run_filled(self, lengths: tuple, fill, read):
        """:meth:`run_reading` with the arguments put in place by ``fill(workspace)`` instead:
        it writes the arguments' rows of the workspace (``workspace[0]``) and returns the
        registers (this plan's ``template`` with every argument in it). ``lengths``: each
        program's instance count (-1: none), as :meth:`run_reading` reads them off its values."""
        if not self._lock.acquire(blocking=False):
            return None
        try:
            kept = self._kept
            if kept is None or kept[0] != lengths:
                if not fits(self.rows, lengths):
                    return None
                kept = self._kept = (lengths, self._workspace(lengths))
            r = fill(kept[1])
            self._execute(kept[1], r)
            return read(kept[1][0], r)
        finally:
            self._lock.release()

    def arguments_on_rows(self) -> dict:
        """(program, argument) -> its row, for the arguments the rows read."""
        return {(c, a): at for c, a, at in self.argument_rows}

    def _outputs(self, R: np.ndarray, r: list) -> list:
        """Each program's outputs, out of the rows (copied: they are written again next call)."""
        output_rows, ends = self._kept[1][3:]
        if len(output_rows):
            for (reg, _, _), n, value in zip(self.output_rows, ends, R.take(output_rows, 0)):
                r[reg] = value[:n]
        return [[r[o + k] for k in program.outputs] for o, program in zip(self.offsets, self.programs)]

    def _arguments(self, workspace: tuple, values: list) -> list:
        """Each program's ``values`` in its argument registers and rows: the registers."""
        r = self.template.copy()
        for o, program, v in zip(self.offsets, self.programs, values):
            r[o:o + program.n_args] = v
        for c, a, view in workspace[2]:
            view[...] = values[c][a]
        return r

    def _execute(self, workspace: tuple, r: list) -> None:
        """Run the schedule on the workspace's rows and the registers ``r`` (values not on rows)."""
        R, bound = workspace[0], workspace[1]
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
