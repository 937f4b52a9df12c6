"""A seeded fuzzer of the session language: no line may hang, crash or lie.

Lines come from three sources, all drawn from one ``random.Random(seed)``, so a run is
reproducible line for line:

* the grammar: every command with random names, numbers (tiny, huge, negative, long) and nested
  expressions of every function and operator;
* real session lines from ``sessions/*.stw`` (a ``linkage`` block stays whole);
* mutations of either: characters deleted, duplicated or inserted (control characters, lone
  surrogates, non-ASCII letters, ``__``), numbers swapped for extreme ones, lines cut short.

Lines run in batches on a small scene through :meth:`Session.execute`. For each line it records
an exception other than ``StwError`` (an escape), an ``StwError`` that is only the catch-all's
"internal error", a failed line that changed the scene, lines slower than 2 s (``iterate``
apart: it reports progress and can be stopped) and lines that used over 500 MB of their own: the
peak resident memory during the line (the kernel's high-water mark, reset before each line through
``/proc/self/clear_refs``) less the resident memory at its start.

    python tests/fuzz.py --lines 100000 [--seed 1] [--show 10] [--progress 1000]

prints those counts, the slowest and the largest lines and the peak memory, with a progress line (counts so far,
time left) on stderr every 1000 lines. ``tests/test_fuzz.py`` runs a few
thousand lines of it in CI.
"""

from __future__ import annotations

import argparse
import heapq
import os
import random
import re
import resource
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
os.environ.setdefault("STW_CACHE_DIR", "off")   # a fuzz run must not fill the user's cache

import numpy as np  # noqa: E402

from stw_tui.session.session import Session  # noqa: E402
from stw_tui.sym.errors import StwError  # noqa: E402

SLOW = 2.0   # seconds: no line but `iterate` may take longer before its first result
MEMORY_MB = 500.0   # no line may use more memory of its own

PRELUDE = """time 0 1 knots=8
const m = 1, g = 9.81, T = 0.5
dof x, y = t
let f = m*x'' + m*g
constraint start: x = 0, x' = 0 @ 0
constraint floor: y >= 0 on [0, 1]
objective fuel: f
window w1 dofs=x [0.2, 0.8]
use all
set adaptive off"""

NAMES = ["x", "y", "m", "g", "T", "f", "start", "floor", "fuel", "w1", "all", "z", "q", "new",
         "arm", "arm.tip.x", "x.bounds", "sin", "t", "pi", "__import__", "a__b", "dofs", "on"]
FUNCTIONS = ["sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "exp",
             "log", "sqrt", "abs", "sign", "min", "max", "nosuch"]
NUMBERS = ["0", "1", "2", "0.5", "-1", "3.25", "1e-3", "1e308", "1e-400", "1e999", "9.81",
           "2147483648", "4294967296", "99999999999999999999", "0.0", "1000000", "1e15", "T", "pi"]
COMMANDS = ["time", "const", "dof", "let", "constraint", "objective", "key", "window", "use", "weight",
            "damp", "filter", "shake", "refine", "backend", "set", "iterate", "delete", "print", "help",
            "instances", "linkage"]
SETTINGS = ["samples", "adaptive", "adaptive_rounds", "tol_violation", "tol_kkt", "quadrature",
            "merit", "frame", "dense_tol", "limit", "nosuch"]
INSERTS = ["\x00", "\x1b[2J", "\t", "\r", "\x7f", "\udcff", "\u00e9", "\u0663", "__", "#", "'", "''",
           "(", ")", "[", "]", ",", "=", "@", "^", "**", "/", "-", " ", ";", "\"", "\\", "$", "\n"]


def _number(rng: random.Random) -> str:
    pick = rng.random()
    if pick < 0.6:
        return rng.choice(NUMBERS[:7] + ["T", "pi", "0.25", "0.75"])
    if pick < 0.9:
        return rng.choice(NUMBERS)
    return rng.choice(["9" * rng.randint(20, 5000), "1" + "0" * rng.randint(300, 400),
                       f"{rng.random():.3g}e{rng.randint(-400, 400)}"])


def expression(rng: random.Random, depth: int = 0, *, numeric: bool = False) -> str:
    """A random expression (only numbers and constants when ``numeric``)."""
    leaf = depth > 3 or rng.random() < 0.35
    if leaf:
        if numeric or rng.random() < 0.4:
            return _number(rng)
        return rng.choice(["x", "y", "x'", "y''", "f", "t", "m", "g", "x'''", "f'", "arm.tip.x", "z"])
    kind = rng.random()
    sub = lambda: expression(rng, depth + 1, numeric=numeric)  # noqa: E731
    if kind < 0.45:
        return f"{sub()} {rng.choice(['+', '-', '*', '/', '^', '**'])} {sub()}"
    if kind < 0.7:
        fn = rng.choice(FUNCTIONS)
        args = [sub() for _ in range(2 if fn in ("atan2", "min", "max") else 1)]
        return f"{fn}({', '.join(args)})"
    if kind < 0.85:
        return f"({sub()})"
    if kind < 0.93:
        return f"-{sub()}"
    return rng.choice(["(" * 70 + "x" + ")" * 70, "-" * 80 + "x", "9^9^9^9.81", "x^2147483648",
                       "(-8)^(1/3)", "sqrt(-1)", "log(0)", "1/0", "cos(1.5^2147483648)", "acos(2)",
                       "exp(exp(exp(100)))", "1/exp(exp(exp(100)))", "sinh(1e5)", "x^(1/3)",
                       "10**10**10^9.81", "atan2(0, 0)", "tan(pi/2)", "sign(x)*abs(x)^0.5"])


def _interval(rng: random.Random) -> str:
    return f"[{expression(rng, 2, numeric=True)}, {expression(rng, 2, numeric=True)}]"


def grammar_line(rng: random.Random) -> list[str]:
    """One command from the grammar (a linkage block comes as several lines)."""
    word = rng.choice(COMMANDS)
    e = lambda: expression(rng)  # noqa: E731
    n = lambda: expression(rng, 2, numeric=True)  # noqa: E731
    name = rng.choice(NAMES)
    count = lambda: rng.choice(["1", "2", "3", "8", "0", "5000", "1000000", "99999999999"])  # noqa: E731
    if word == "time":
        return [f"time {n()} {n()}" + rng.choice(["", f" knots={count()}", f" samples={count()}"])]
    if word == "const":
        return ["const " + ", ".join(f"{rng.choice(NAMES)} = {n()}" for _ in range(rng.randint(1, 3)))]
    if word == "dof":
        return [f"dof {name}" + rng.choice(["", f" = {expression(rng, 1)}", f" knots={count()}",
                                              f" lo={n()}", f" hi={n()}"])]
    if word == "let":
        return [f"let {name} = {e()}"]
    if word == "constraint":
        rel = f"{e()} {rng.choice(['=', '>=', '<='])} {e()}"
        scope = rng.choice([f"@ {n()}", f"on {_interval(rng)}", ""])
        extra = rng.choice(["", f" when {e()} > {e()}", f" weight={n()}", f" samples={count()}"])
        return [f"constraint {name}: {rel} {scope}{extra}"]
    if word == "objective":
        return [f"objective {name}: {e()}" + rng.choice(["", f" on {_interval(rng)}", f" weight={n()}"])]
    if word == "key":
        return [f"key {n()} {rng.choice(['x', 'y', 'm'])}={n()}"]
    if word == "window":
        return [f"window {name} dofs={rng.choice(['x', 'y', 'x,y', 'all', 'm'])} {_interval(rng)}"]
    if word in ("use", "delete"):
        return [f"{word} {name}"]
    if word == "weight":
        return [f"weight {name} {n()}"]
    if word == "damp":
        return [f"damp {rng.choice(['x', 'y', 'm'])} {n()}"]
    if word == "filter":
        return [f"filter {rng.choice(['x', 'y'])} {count()}"]
    if word == "shake":
        return [f"shake {rng.choice(['x', 'y', ''])} amplitude={n()}" + rng.choice(["", f" seed={count()}"])]
    if word == "refine":
        return [f"refine {rng.choice(['x', 'y'])}" + rng.choice(["", f" {_interval(rng)}",
                                                              f" @ {n()} multiplicity={count()}"])]
    if word == "backend":
        return [f"backend {rng.choice(['scipy', 'nosuch', 'torch'])}"
                + rng.choice(["", " solver=minres", " tol=0", " nosuch=1"])]
    if word == "set":
        setting = rng.choice(SETTINGS)
        if setting == "limit":
            return [f"set limit {rng.choice(['knots', 'samples', 'exponent', 'nosuch', 'nesting'])} {count()}"]
        return [f"set {setting} {rng.choice([count(), 'on', 'off', '-1', '1e-7', 'nan', 'inf'])}"]
    if word == "iterate":
        return [f"iterate {rng.choice(['1', '2', '3'])}" + rng.choice(["", " adapt=1", " adapt=0"])]
    if word == "print":
        return [f"print {e()}" + rng.choice(["", f" @ {n()}", f" on {_interval(rng)}"])]
    if word == "help":
        return [f"help {rng.choice(['', 'limits', 'print', 'nosuch', 'set'])}"]
    if word == "instances":
        return [f"instances {rng.choice(['floor', 'start', 'x.bounds'])} "
                + rng.choice([f"add {n()}", "clear", "add"])]
    rows = [f"  {rng.choice(['J1', 'sin', 'x', 'J__2', 'J3'])} {rng.choice(['revolute', 'prismatic', 'hinge'])}"
            f" a={n()} mass={n()}" for _ in range(rng.randint(1, 3))]
    return [f"linkage {rng.choice(['arm', '__import__', 'x', 'leg'])} base=fixed", *rows, "end"]


def session_units() -> list[list[str]]:
    """The lines of the bundled sessions (the test catalogue's, less its HEAVY ones), a `linkage` block
    kept as one unit."""
    import catalogue
    from stw_tui.sym.language import classify_line

    units: list[list[str]] = []
    for problem in catalogue.problems():
        if problem.path is None:
            continue
        block: list[str] | None = None
        for line in problem.text.splitlines():
            kind = classify_line(line)
            if block is not None:
                block.append(line)
                if kind.words == ("end",):
                    units.append(block)
                    block = None
            elif kind.verb == "linkage":
                block = [line]
            elif not kind.is_blank:
                units.append([line.replace("iterate 150", "iterate 2").replace("iterate 10", "iterate 2")])
    return units


def mutate(rng: random.Random, line: str) -> str:
    """The line with one to three random edits."""
    for _ in range(rng.randint(1, 3)):
        i = rng.randint(0, len(line))
        j = min(len(line), i + rng.randint(1, 8))
        op = rng.random()
        if op < 0.25:
            line = line[:i] + line[j:]
        elif op < 0.55:
            line = line[:i] + rng.choice(INSERTS) + line[i:]
        elif op < 0.7:
            line = line[:i] + line[i:j] * rng.randint(2, 4) + line[j:]
        elif op < 0.85:
            words = line.split(" ")
            k = rng.randrange(len(words))
            words[k] = _number(rng) if rng.random() < 0.5 else rng.choice(NAMES)
            line = " ".join(words)
        else:
            line = line[:i]
    return line


def generate(rng: random.Random, units: list[list[str]]) -> list[str]:
    """One fuzz unit: usually one line, a linkage block several."""
    pick = rng.random()
    if pick < 0.35:
        lines = grammar_line(rng)
    elif pick < 0.55:
        lines = list(rng.choice(units))
    elif pick < 0.8:
        lines = [mutate(rng, line) for line in grammar_line(rng)]
    else:
        lines = [mutate(rng, line) for line in rng.choice(units)]
    return [line for part in lines for line in part.split("\n")]


def fingerprint(session: Session) -> tuple:
    """What a failed line must leave exactly as it was."""
    s = session.scene
    return (s.t0, s.t1, s.knots, s.samples, tuple(s.constants.items()), tuple(s.lets.items()),
            tuple(s.constraints), tuple(s.objectives), tuple(s.windows), s.active_window, s.backend,
            tuple(s.backend_options.items()), tuple(s.settings.items()), tuple(s.limits.items()),
            tuple((n, d.lo, d.hi, d.damp, tuple(d.keys), d.curve.coef.tobytes(), d.curve.knots.tobytes())
                  for n, d in s.dofs.items()), tuple(s.extra_instances.items()), s.shake_count)


@dataclass
class Findings:
    lines: int = 0
    failed: int = 0
    escaped: Counter = field(default_factory=Counter)
    internal: Counter = field(default_factory=Counter)
    changed_on_failure: int = 0
    slow: list[tuple[float, str]] = field(default_factory=list)
    heavy: list[tuple[float, str]] = field(default_factory=list)     # (MB, line) over MEMORY_MB
    largest: list[tuple[float, str]] = field(default_factory=list)   # a heap of the largest lines
    slowest: tuple[float, str] = (0.0, "")     # the slowest line of all, iterate included
    memory_exact: bool = True      # per-line peaks from the kernel (False: process-peak growth only)
    examples: dict[str, str] = field(default_factory=dict)
    traces: dict[str, str] = field(default_factory=dict)   # kind -> the scene's lines, the line, the traceback

    @property
    def clean(self) -> bool:
        return not (self.escaped or self.internal or self.changed_on_failure or self.slow or self.heavy)

    def measured(self, megabytes: float, line: str, keep: int = 10) -> None:
        """Record a line's own memory: counted when over the limit, kept among the largest."""
        if megabytes > MEMORY_MB:
            self.heavy.append((megabytes, line))
        entry = (megabytes, line)
        if len(self.largest) < keep:
            heapq.heappush(self.largest, entry)
        elif entry > self.largest[0]:
            heapq.heapreplace(self.largest, entry)

    def report(self, show: int = 5) -> str:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        out = [f"lines: {self.lines}, failed as StwError: {self.failed}",
               f"escaped exceptions: {sum(self.escaped.values())} {dict(self.escaped)}",
               f"internal errors: {sum(self.internal.values())} {dict(self.internal)}",
               f"failed lines that changed the scene: {self.changed_on_failure}",
               f"lines over {SLOW:g} s (iterate apart): {len(self.slow)}",
               f"lines over {MEMORY_MB:g} MB of their own: {len(self.heavy)}"
               + ("" if self.memory_exact else " (measured as growth of the process peak only)"),
               f"peak memory: {peak:.0f} MB",
               f"slowest line: {self.slowest[0]:.2f} s: {self.slowest[1][:120]!r}"]
        for kind, line in list(self.examples.items())[:show]:
            out.append(f"  {kind}: {line[:120]!r}")
        for seconds, line in sorted(self.slow, reverse=True)[:show]:
            out.append(f"  {seconds:.1f} s: {line[:120]!r}")
        out.append("largest lines (their own peak memory):")
        for megabytes, line in sorted(self.largest, reverse=True)[:show]:
            out.append(f"  {megabytes:.0f} MB: {line[:120]!r}")
        return "\n".join(out)


class LineMemory:
    """A line's own memory: the peak resident size while it ran, less the resident size at its
    start. Linux keeps the peak (VmHWM) and resets it on request (``5`` to clear_refs), so a short
    spike inside C code that no sampling thread would see is counted too. Elsewhere the growth of
    the process's peak (``ru_maxrss``) stands in, which misses lines below an earlier peak."""

    STATUS = "/proc/self/status"
    RESET = "/proc/self/clear_refs"

    def __init__(self):
        self.exact = self._reset()

    def _reset(self) -> bool:
        try:
            with open(self.RESET, "w") as out:
                out.write("5")
            return True
        except OSError:
            return False

    def _status(self) -> dict[str, float]:
        with open(self.STATUS) as status:
            found = re.findall(r"^(VmHWM|VmRSS):\s+(\d+) kB", status.read(), re.M)
        return {key: int(kb) / 1024 for key, kb in found}

    def start(self) -> float:
        """Mark a line's start; returns the baseline for :meth:`used`."""
        if self.exact:
            self._reset()
            return self._status()["VmRSS"]
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    def used(self, baseline: float) -> float:
        """MB the line used beyond its start."""
        if self.exact:
            return max(0.0, self._status()["VmHWM"] - baseline)
        return max(0.0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - baseline)


def run(n_lines: int, seed: int = 1, batch: int = 40, progress=None, every: int = 1000) -> Findings:
    """Fuzz ``n_lines`` lines, ``batch`` lines to a fresh prelude scene, and return the findings;
    ``progress(found)`` is called every ``every`` lines (a long campaign shows where it is)."""
    rng = random.Random(seed)
    units = session_units()
    found = Findings()
    memory = LineMemory()
    found.memory_exact = memory.exact
    session = None
    while found.lines < n_lines:
        if session is None or found.lines % batch == 0 or rng.random() < 0.01:
            session = Session()
            session.run_text(PRELUDE)
        for line in generate(rng, units):
            _one(session, line, found, memory)
            if progress is not None and found.lines % every == 0:
                progress(found)
            if found.lines >= n_lines:
                break
    return found


def _one(session: Session, line: str, found: Findings, memory: LineMemory | None = None) -> None:
    found.lines += 1
    before_scene, before = session.scene, fingerprint(session)
    baseline = memory.start() if memory is not None else 0.0
    start = time.perf_counter()
    np.seterr(all="ignore")
    try:
        session.execute(line)
        ok = True
    except StwError as exc:
        ok = False
        found.failed += 1
        if "internal error" in str(exc):
            cause = type(exc.__cause__).__name__ if exc.__cause__ else "?"
            found.internal[cause] += 1
            found.examples.setdefault(f"internal {cause}", line)
            _trace(found, f"internal {cause}", session, line, exc.__cause__)
    except KeyboardInterrupt:
        raise   # the person running the fuzzer
    except BaseException as exc:  # noqa: BLE001 - counting every escape is the point
        ok = False
        found.escaped[type(exc).__name__] += 1
        found.examples.setdefault(f"escaped {type(exc).__name__}", line)
        _trace(found, f"escaped {type(exc).__name__}", session, line, exc)
        session.cancel_block()
    seconds = time.perf_counter() - start
    found.slowest = max(found.slowest, (seconds, line))
    if memory is not None:
        found.measured(memory.used(baseline), line)
    if not ok and (session.scene is not before_scene or fingerprint(session) != before):
        found.changed_on_failure += 1
        found.examples.setdefault("changed on failure", line)
    if seconds > SLOW and not line.lstrip().startswith("iterate") and not session.in_block:
        found.slow.append((seconds, line))


def _trace(found: Findings, kind: str, session: Session, line: str, exc: BaseException | None) -> None:
    if kind not in found.traces:
        import traceback

        scene = "\n".join(session.journal.replayable())
        text = "".join(traceback.format_exception(exc)) if exc is not None else ""
        found.traces[kind] = f"--- scene:\n{scene}\n--- line: {line!r}\n{text}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--show", type=int, default=10, help="examples and slow lines to show")
    parser.add_argument("--trace", action="store_true", help="print how to reproduce each finding")
    parser.add_argument("--batch", type=int, default=40, help="lines run on one scene before a fresh one")
    parser.add_argument("--progress", type=int, default=1000, metavar="N",
                        help="a progress line on stderr every N lines (0: none)")
    args = parser.parse_args(argv)
    start = time.perf_counter()

    def progress(found: Findings) -> None:
        seconds = time.perf_counter() - start
        left = (args.lines - found.lines) * seconds / found.lines
        print(f"{found.lines}/{args.lines} lines, {seconds:.0f} s (about {left:.0f} s left): "
              f"{sum(found.escaped.values())} escaped, {sum(found.internal.values())} internal, "
              f"{found.changed_on_failure} changed on failure, {len(found.slow)} slow, "
              f"{len(found.heavy)} over {MEMORY_MB:g} MB",
              file=sys.stderr, flush=True)

    found = run(args.lines, args.seed, args.batch, progress=progress if args.progress else None,
                every=args.progress or 1000)
    print(found.report(args.show))
    if args.trace:
        for trace in found.traces.values():
            print(trace)
    print(f"{time.perf_counter() - start:.1f} s")
    return 0 if found.clean else 1


if __name__ == "__main__":
    sys.exit(main())
