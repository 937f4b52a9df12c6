"""The printed torch programs run on numpy arrays, on the CPU, without Python evaluating anything.

A program's TorchScript source (lower.py prints it from symengine trees) is straight-line
arithmetic: assignments ``xN = expr`` and a returned list. :func:`tape_of` reads that source's
syntax tree (``ast.parse``: parsing, no evaluation) and turns the few kinds of node the printer
writes into a tape of instructions on registers; anything else is refused, and the program then
runs through torch. :func:`host_function` binds a tape to its functions. Nothing is handed to
``eval``, ``exec`` or ``compile``.

The numbers are TorchScript's: each node does the operation its source does, in the order Python
would (the tree is that order), with +, -, *, / and comparisons by numpy (correctly rounded, as
torch's) and the functions (sin, cos, pow, where, ...) by torch itself on the arrays' memory.
On the CPU a TorchScript op costs about 0.7 µs on a few hundred numbers, a numpy op about 0.35.
From its second call with arguments of the same kinds, a program of ON_ROWS_FROM instructions or
more runs on rows (host_levels.py): the same numbers in fewer, cheaper calls.
"""

from __future__ import annotations

import ast
import functools
import operator

import numpy as np
import torch

from .host_levels import GROUPED as _GROUPED, LevelPlan, signature as _signature

HOST_FUNCTIONS_KEPT = 512   # host programs kept by source (a few MB of source at most)
PLANS_KEPT = 8              # plans on rows a host program keeps, one per kind of arguments
ON_ROWS_FROM = 8            # instructions from which a program runs on rows (host_levels)


def _to_torch(a):
    """A numpy array or scalar as a tensor sharing its memory; anything else as it is."""
    if isinstance(a, np.ndarray):
        return torch.from_numpy(a)
    if isinstance(a, np.generic):
        return torch.from_numpy(np.asarray(a))
    return a


def _through_torch(fn):
    """``fn`` (a torch function) of numpy arguments, its result as numpy."""
    def call(*args, **kwargs):
        if not kwargs and len(args) == 1 and args[0].__class__ is np.ndarray:   # sin(x), cos(x), ...
            return fn(torch.from_numpy(args[0])).numpy()
        return fn(*map(_to_torch, args), **kwargs).numpy()
    return call


def _host_pow(base, exponent):
    # torch's pow by the scalar 2 is base * base (its pow_tensor_scalar kernel): the same product
    # here, without the round trip through torch; any other exponent goes through torch's pow
    if exponent.__class__ is int and exponent == 2:
        return base * base
    if base.__class__ in (int, float) and exponent.__class__ in (int, float):
        # two numbers (a power of numbers that cse named), which torch.pow refuses: TorchScript
        # folds it with C's pow, as numpy's power computes it (nan and inf included, no error)
        return float(np.power(float(base), float(exponent)))
    return _through_torch(torch.pow)(base, exponent)


@functools.cache
def host_functions(names: tuple[str, ...]) -> dict:
    """What the printed programs may call as ``torch.NAME``: torch's own function of each name
    (``pow`` by 2 as the product torch computes), on numpy arguments. Made once per set of
    names and shared by every program bound to it (read, never changed)."""
    table = {name: _through_torch(getattr(torch, name)) for name in names}
    table["pow"] = _host_pow
    return table


_BINARY = {ast.Add: "add", ast.Sub: "sub", ast.Mult: "mul", ast.Div: "truediv", ast.Lt: "lt",
           ast.LtE: "le", ast.Eq: "eq", ast.NotEq: "ne", ast.Gt: "gt", ast.GtE: "ge"}
_CONSTANTS = ("float64",)   # torch.float64, full_like's dtype: the only keyword value printed


def _negative(a, _):
    return -a


def _reciprocal_times(a, b):
    return np.reciprocal(a) * b


class _Tape:
    """A program as data: instructions ``(op, i, j, k)``, register k = op(register i, register j),
    or with j = -1 a call of the registers listed in i; ``op`` names an operator, ``neg``, or a
    torch function: ("torch1", NAME) of one argument, ("torch", NAME, keywords) of several.
    Registers hold the arguments first, then the numbers of the source, then every intermediate
    value. Being data, a tape is kept in the terms' disk cache beside its source, and a new
    process reads it without parsing."""

    def __init__(self, names: list[str], functions):
        self.slots = {name: i for i, name in enumerate(names)}
        self.functions = functions
        self.registers: list = [None] * len(names)
        self.numbers: dict = {}
        self.instructions: list = []

    def _new(self, value=None) -> int:
        self.registers.append(value)
        return len(self.registers) - 1

    def _number(self, value) -> int:
        key = (type(value), value, str(value))   # 0.0 and -0.0 apart
        if key not in self.numbers:
            self.numbers[key] = self._new(value)
        return self.numbers[key]

    def _emit(self, op, i, j) -> int:
        k = self._new()
        self.instructions.append((op, i, j, k))
        return k

    def node(self, n) -> int:
        """The register of node ``n``'s value, its instructions emitted (operands first)."""
        kind = type(n)
        if kind is ast.Name:
            return self.slots[n.id]          # KeyError: a name not assigned before (refused)
        if kind is ast.Constant and type(n.value) in (int, float):
            return self._number(n.value)
        if kind is ast.UnaryOp and type(n.op) is ast.USub:
            if type(n.operand) is ast.Constant and type(n.operand.value) in (int, float):
                return self._number(-n.operand.value)     # (-0.5): the number Python makes of it
            i = self.node(n.operand)
            return self._emit("neg", i, i)
        if kind is ast.BinOp and type(n.op) in _BINARY:
            return self._emit(_BINARY[type(n.op)], self.node(n.left), self.node(n.right))
        if kind is ast.Compare and len(n.ops) == 1 and type(n.ops[0]) in _BINARY:
            return self._emit(_BINARY[type(n.ops[0])], self.node(n.left), self.node(n.comparators[0]))
        if kind is ast.Call and self._is_torch(n.func) and n.func.attr in self.functions:
            args = tuple(self.node(a) for a in n.args)
            keywords = tuple((k.arg, self._constant(k.value)) for k in n.keywords)
            if len(args) == 1 and not keywords:
                return self._emit(("torch1", n.func.attr), args[0], args[0])
            return self._emit(("torch", n.func.attr, keywords), args, -1)
        raise ValueError(f"not a construct of the printed programs: {ast.dump(n)[:80]}")

    def assign(self, name: str, n) -> None:
        if name in self.slots:                # the printer assigns each name once
            raise ValueError(f"{name} assigned twice")
        self.slots[name] = self.node(n)

    @staticmethod
    def _is_torch(f) -> bool:
        return type(f) is ast.Attribute and type(f.value) is ast.Name and f.value.id == "torch"

    def _constant(self, n) -> str:
        if self._is_torch(n) and n.attr in _CONSTANTS:
            return n.attr
        raise ValueError(f"not a keyword value of the printed programs: {ast.dump(n)[:80]}")


def tape_of(source: str, functions: tuple[str, ...]) -> tuple | None:
    """The tape ``(arguments, registers, instructions, outputs)`` of the program
    ``def program(args): x0 = …; …; return [...]`` of printed TorchScript ``source``, which may
    call torch's ``functions`` (their names); None when the source holds anything the printer
    does not write."""
    try:
        (fn,) = ast.parse(source).body
        if type(fn) is not ast.FunctionDef:
            return None
        args = fn.args
        if fn.decorator_list or args.vararg or args.kwarg or args.kwonlyargs or args.defaults:
            return None
        names = [a.arg for a in args.args]
        tape = _Tape(names, {*functions, "pow"})   # pow: see _host_pow
        *assignments, ret = fn.body
        for statement in assignments:
            if type(statement) is not ast.Assign or len(statement.targets) != 1 \
                    or type(statement.targets[0]) is not ast.Name:
                return None
            tape.assign(statement.targets[0].id, statement.value)
        if type(ret) is not ast.Return or type(ret.value) is not ast.List:
            return None
        outputs = tuple(tape.node(e) for e in ret.value.elts)
    except (ValueError, KeyError, SyntaxError, TypeError):
        return None
    return len(names), tuple(tape.registers), tuple(tape.instructions), outputs


def _bound(op, table: dict):
    """The function an instruction's ``op`` names, taking (register i, register j), or for a
    call of several arguments (registers, their places)."""
    if op == "neg":
        return _negative
    if isinstance(op, str):
        return getattr(operator, op)
    fn = table[op[1]]
    if op[0] == "torch1":
        return lambda a, _: fn(a)
    kw = {k: getattr(torch, v) for k, v in op[2]}
    return lambda registers, places: fn(*[registers[p] for p in places], **kw)


@functools.lru_cache(maxsize=HOST_FUNCTIONS_KEPT)
def host_function(tape: tuple, functions: tuple[str, ...]):
    """The program of ``tape`` (:func:`tape_of`) as a function of numpy arrays."""
    n_args, template, instructions, outputs = tape
    table = host_functions(functions)
    template = list(template)
    made = {k for _, _, _, k in instructions}
    numbers = {r for r in range(n_args, len(template)) if r not in made}
    constant = set(numbers)    # numbers, and what is computed from numbers alone
    for _, i, j, k in instructions:
        if all(r in constant for r in ((i, j) if j >= 0 else i)):
            constant.add(k)
    as_array: dict[int, int] = {}

    def operand(r: int, other: int) -> int:
        # numpy takes a 0-d array beside an array faster than a Python float (0.36 against
        # 0.50 µs on 192 numbers), with the same product; beside another Python number it
        # stays a float (a 0-d array would make a numpy scalar of the result, which a torch
        # function then takes as a tensor: pow by a tensor is not pow by a float)
        if r not in numbers or other in constant or type(template[r]) is not float:
            return r
        if r not in as_array:
            template.append(np.array(template[r]))
            as_array[r] = len(template) - 1
        return as_array[r]

    steps = []
    for op, i, j, k in instructions:
        if op == "truediv" and i in constant and j not in constant:
            # a number over a tensor is torch's rtruediv: the tensor's reciprocal times the
            # number, two roundings (2.4 / x differs from numpy's quotient in a quarter of x)
            steps.append((_reciprocal_times, j, i, k))
            continue
        if isinstance(op, str) and op != "neg":
            i, j = operand(i, j), operand(j, i)
        steps.append((_bound(op, table), i, j, k))

    return HostProgram(n_args, template, steps, instructions, outputs, constant)


class HostProgram:
    """A tape bound to its functions: called with numpy arrays, it returns the outputs. From its
    second call with arguments of the same kinds, one of ON_ROWS_FROM instructions or more runs
    on rows (:class:`host_levels.LevelPlan`); several programs can run on rows together too
    (:class:`host_levels.LevelPlan` of several parts, calls.py)."""

    def __init__(self, n_args: int, template: list, steps: list, instructions, outputs, constant: set):
        self.n_args, self.template, self.steps = n_args, template, steps
        self.outputs, self.constant = tuple(outputs), constant
        # what may run on rows: each step's arithmetic operator, or its torch function of one array
        self.names = [op if isinstance(op, str) and op in _GROUPED and step[0] is not _reciprocal_times
                      else None for (op, *_), step in zip(instructions, steps)]
        self.functions = [getattr(torch, op[1]) if not isinstance(op, str) and op[0] == "torch1"
                          and op[1] != "pow" else None for op, *_ in instructions]
        self.plans: dict = {}    # signature of the arguments -> LevelPlan (None: not worth it)

    def registers(self, values) -> list:
        """Every register's value, the tape run instruction by instruction on ``values``."""
        r = self.template.copy()
        r[:self.n_args] = values
        for f, i, j, k in self.steps:
            r[k] = f(r[i], r[j]) if j >= 0 else f(r, i)
        return r

    def reference(self, values) -> list:
        """The outputs, the tape run instruction by instruction."""
        r = self.registers(values)
        return [r[k] for k in self.outputs]

    def __call__(self, *values) -> list:
        if len(values) != self.n_args:
            raise TypeError(f"program takes {self.n_args} arguments, {len(values)} given")
        if len(self.steps) < ON_ROWS_FROM:
            return self.reference(values)
        key = _signature(values)
        plan = self.plans.get(key, False)
        if plan:
            return plan.run([values])[0]
        r = self.registers(values)
        if plan is False and len(self.plans) < PLANS_KEPT:
            plan = LevelPlan([(self, values, r)])
            self.plans[key] = plan if plan.rows else None
        return [r[k] for k in self.outputs]
