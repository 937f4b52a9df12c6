"""Key latency of the real TUI in tmux at 80x24 while a session solves, the time F4 takes to end
a solve, and that solve's time in the TUI against the same solve headless (issues 12 and 52).

    python tests/tmux_latency.py [SESSION] [--rounds N] [--stops N] [--endless] [--quick]

SESSION defaults to sessions/basketball.stw (it must contain an `iterate` line). The TUI runs
with this interpreter (`python -m stw_tui.cli.main`, started in a temporary folder), so
PYTHONPATH picks the tree measured. `--endless` replaces the session's solve by one that never
converges (its lines up to the first `iterate`, then tests/conftest.py's ENDLESS settings), so a
solve runs through every round of keys however fast the real one is (basketball's now takes
under 2 s); F4 ends it after the rounds. `--quick` leaves out the headless solves (1 and 4).

What is measured, in order:

1. the headless solve: the session's lines up to its first `iterate` run in a fresh process,
   then that `iterate` is timed;
2. the TUI solve, untouched: the time the status line says `solving` (polled every 0.1 s);
3. the TUI solve again, while keys are pressed: console echo (a typed character appears at the
   prompt), F2 and F3 (the panels' or plots' side of the screen changes), `]` on the Curves plot
   (the next DOF's title, computed off the UI thread) and → on the Figure plot (the frame time in
   its title). Each key has two figures: *first*, the time from sending it until tmux receives
   the output that first changed its area of the screen (through a control-mode client, see
   :class:`Tui`), and *settled*, until the last output that changed the area before it stayed
   unchanged for SETTLE_QUIET (a panel drawn empty, then filled, then refitted settles late;
   on the plots' side a live redraw of the running solve within that time counts too). Only
   keys whose first change came while the solve was still running count; before each key the
   area must have been still for a moment; then rounds of the same keys once the solve has
   ended (the idle columns: what the solve adds is the difference);
4. F4: `--stops` times `undo`, the session's solve again, 0.5 to 2 s of it, F4, and the time
   until the status line no longer says solving/stopping/running;
5. the headless solve once more (so a warm cache favours neither side).

The load average (1, 5, 15 min) is printed at the start, after the keys and at the end: these
2-core machines are shared, and figures mean little without it. Nothing here asserts: it prints
the figures next to the targets (issue 52: while a solve runs, F2/F3 first change p95 <= 50 ms
and settled <= 100 ms, console echo p95 <= 20 ms; F4 <= 300 ms; TUI solve <= 1.2 x headless).
Needs tmux.
"""

from __future__ import annotations

import argparse
import os
import queue
import shlex
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SIZE = (80, 24)
TARGETS = {"keys": 0.050, "echo": 0.020, "ratio": 1.2}

HEADLESS = """
import re, sys, time
from stw_tui.session.session import Session

session = Session()
for number, line in enumerate(open(sys.argv[1], encoding="utf-8").read().splitlines(), start=1):
    if not line.split("#")[0].strip():
        continue
    if re.match(r"\\s*iterate\\b", line):
        start = time.perf_counter()
        outcome = session.execute(line, line=number)
        print(time.perf_counter() - start)
        print(outcome.message.splitlines()[0], file=sys.stderr)
        break
    session.execute(line, line=number)
"""


def headless_solve(session: Path, env: dict) -> float:
    """Seconds of the session's first `iterate`, headless, in a fresh process."""
    done = subprocess.run([sys.executable, "-c", HEADLESS, str(session)], capture_output=True, text=True,
                          env=env, cwd=env["XDG_STATE_HOME"], check=False)
    if done.returncode != 0:
        raise SystemExit(f"the headless solve failed:\n{done.stderr[-2000:]}")
    return float(done.stdout.split()[0])


class Tui:
    """`stw SESSION` in a detached tmux session on a private tmux server, driven through one tmux
    control-mode client: keys and captures are commands on that connection, and the pane's
    output is announced as it is written (``%output``). So a change is looked for only when the
    app has written something, and no tmux process is started per capture: polling with
    `tmux capture-pane` every few ms took most of a core and slowed the measured TUI 3x."""

    def __init__(self, session: Path, env: dict):
        self.name = f"stw-latency-{uuid.uuid4().hex[:8]}"
        self.base = ["tmux", "-L", self.name]
        exports = " ".join(f"{key}={env[key]}" for key in ("PYTHONPATH", "XDG_STATE_HOME") if env.get(key))
        # COLUMNS/LINES set by a caller would override the pane's size.
        command = f"env -u COLUMNS -u LINES {exports} {sys.executable} -m stw_tui.cli.main {session}"
        subprocess.run([*self.base, "new-session", "-d", "-s", self.name, "-x", str(SIZE[0]), "-y", str(SIZE[1]),
                        command], cwd=env["XDG_STATE_HOME"], check=True, env=env)
        self.control = subprocess.Popen([*self.base, "-C", "attach", "-t", self.name], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True, bufsize=1, errors="replace")
        self.replies: queue.Queue[list[str]] = queue.Queue()
        self.output = threading.Condition()
        self.outputs = 0            # %output notifications so far
        self.last_output = 0.0      # monotonic time of the latest
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        block: list[str] | None = None
        mine = False
        for line in self.control.stdout:
            line = line.rstrip("\n")
            if block is not None:
                if line.startswith(("%end ", "%error ")):
                    if mine:     # flags 1: the reply to one of our commands (0: the attach itself)
                        self.replies.put(block)
                    block = None
                else:
                    block.append(line)
            elif line.startswith("%begin "):
                block, mine = [], line.split()[-1] == "1"
            elif line.startswith("%output "):
                with self.output:
                    self.outputs += 1
                    self.last_output = time.monotonic()
                    self.output.notify_all()

    def command(self, line: str) -> list[str]:
        self.control.stdin.write(line + "\n")
        self.control.stdin.flush()
        return self.replies.get(timeout=10)

    def __enter__(self) -> "Tui":
        return self

    def __exit__(self, *exc) -> None:
        subprocess.run([*self.base, "kill-server"], capture_output=True)
        self.control.wait(5)

    def screen(self) -> list[str]:
        return self.command("capture-pane -p")

    def send(self, *keys: str, literal: bool = False) -> None:
        quoted = " ".join(shlex.quote(key) for key in keys)
        self.command(f"send-keys {'-l ' if literal else ''}{quoted}")

    def wait_output(self, seen: int, timeout: float) -> tuple[int, float]:
        """Wait for output after the ``seen``-th; returns the count and the latest one's time."""
        with self.output:
            self.output.wait_for(lambda: self.outputs > seen, timeout)
            return self.outputs, self.last_output

    def solving(self, screen: list[str] | None = None) -> bool:
        status = (screen or self.screen())[-2:]
        return any(line.lstrip().startswith("solving") for line in status)

    def wait(self, condition, timeout: float = 120, interval: float = 0.1) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition(self.screen()):
                return True
            time.sleep(interval)
        return False


def solve_time(tui: Tui, interval: float = 0.1) -> float:
    """Seconds the status line says `solving` (from the first capture that shows it to the first
    that does not)."""
    if not tui.wait(tui.solving, interval=0.02):
        raise SystemExit("the TUI never started solving")
    start = time.monotonic()
    tui.wait(lambda screen: not tui.solving(screen), timeout=600, interval=interval)
    return time.monotonic() - start


def split_column(screen: list[str]) -> int:
    """Where the plots' tab group starts (the panels' group is left of it)."""
    return max(0, screen[0].find("Curves") - 2)


def region(screen: list[str], row: int, side: str) -> str:
    if len(screen) <= row:
        return ""
    split = split_column(screen)
    return screen[row][split:] if side == "plots" else screen[row][:split]


def side(screen: list[str], name: str) -> str:
    """The whole panels' (or plots') side above the console: what a switch redraws."""
    rows = next((i for i, line in enumerate(screen) if "─" * 10 in line), len(screen) - 3)
    return "\n".join(region(screen, row, name) for row in range(1, rows))


def prompt(screen: list[str]) -> str:
    return next((line for line in screen if line.startswith(("stw>", "...>"))), "")


def title(screen: list[str]) -> str:
    """The plot's title (centred: it moves when a redraw changes the axis labels' width)."""
    return region(screen, 2, "plots").strip()


def show_plot(tui: Tui, marker: str) -> bool:
    """Press F3 (the plots have the focus) until the plot whose title holds ``marker`` shows."""
    for _ in range(5):
        if marker in title(tui.screen()):
            return True
        tui.send("F3")
        time.sleep(0.5)
    return marker in title(tui.screen())


def timed_key(tui: Tui, keys: list[str], area, literal: bool = False) -> tuple[float, float, bool]:
    """Seconds from sending ``keys`` until the output that first changed ``area(screen)`` (once
    the area has been still for 0.1 s: a tab's underline slides) and until the last output that
    changed it before it stayed still for SETTLE_QUIET s (a panel drawn in several steps, an
    empty header then its rows, settles late); and whether the solve was still running then."""
    last = area(tui.screen())
    for _ in range(30):
        time.sleep(0.1)
        now = area(tui.screen())
        if now == last:
            break
        last = now
    seen = tui.wait_output(0, 0)[0]
    sent = time.monotonic()
    tui.send(*keys, literal=literal)
    first = settled = None
    while time.monotonic() - sent < 5:
        if first is None:
            seen, written = tui.wait_output(seen, 5 - (time.monotonic() - sent))
        else:
            quiet = SETTLE_QUIET - (time.monotonic() - settled_at)
            if quiet <= 0:
                break
            count, written = tui.wait_output(seen, quiet)
            if count == seen:
                continue
            seen = count
        screen = tui.screen()
        now = area(screen)
        if now != last:
            last, settled, settled_at = now, max(0.0, written - sent), time.monotonic()
            if first is None:
                first, solving = settled, tui.solving(screen)
    if first is None:
        return float("inf"), float("inf"), tui.solving()
    return first, settled, solving


SETTLE_QUIET = 0.3   # seconds an area must stay unchanged to count as settled


PLOT_TABS = ("Curves", "Expr", "Figure", "Conv")   # the plots' order (app.PLOTS)
KINDS = ("console echo", "F2 panel switch", "F3 plot switch", *(f"  F3 onto {tab}" for tab in PLOT_TABS),
         "] next DOF (Curves)", "→ scrub (Figure)")


def key_round(tui: Tui, record) -> None:
    """One round of every kind of key, each result passed to ``record(kind, (first, settled, solving))``."""
    for _ in range(5):
        record("console echo", timed_key(tui, ["x"], lambda s: prompt(s).count("x"), literal=True))
    tui.send("C-u")
    tui.send("F2")                                   # focuses the panels (no visible switch)
    for _ in range(2):
        record("F2 panel switch", timed_key(tui, ["F2"], lambda s: side(s, "panels")))
    tui.send("F3")                                   # focuses the plots
    # From Curves (where every round but perhaps the first starts) each switch is also recorded
    # under the tab it shows: a tail that only one tab has is then seen as such.
    onto = PLOT_TABS[1:] + PLOT_TABS[:1] if "value" in title(tui.screen()) else (None,) * 4
    for tab in onto:                                 # back to the tab it started on
        result = timed_key(tui, ["F3"], lambda s: side(s, "plots"))
        record("F3 plot switch", result)
        if tab is not None:
            record(f"  F3 onto {tab}", result)
    if show_plot(tui, "value"):                      # the Curves plot's title
        for _ in range(2):
            record("] next DOF (Curves)", timed_key(tui, ["]"], title, literal=True))
    if show_plot(tui, "t = "):                       # the Figure plot's
        for _ in range(2):
            record("→ scrub (Figure)", timed_key(tui, ["Right"], title))
    show_plot(tui, "value")
    tui.send("Escape")                               # back to the console
    time.sleep(0.2)


def measure_keys(tui: Tui, rounds: int, idle_rounds: int = 2, stop: bool = False) -> tuple[dict, dict, float]:
    """Latencies (first change, settled) per kind of key while the solve runs (only those that
    changed the screen during it), the same keys once it has ended (what a solve adds is the
    difference), and the solve's time."""
    if not tui.wait(tui.solving, interval=0.02):
        raise SystemExit("the TUI never started solving")
    start = time.monotonic()
    samples: dict[str, list[tuple[float, float]]] = {kind: [] for kind in KINDS}
    idle: dict[str, list[tuple[float, float]]] = {kind: [] for kind in KINDS}

    def record(kind: str, result: tuple[float, float, bool]) -> None:
        first, settled, during = result
        if during:
            samples[kind].append((first, settled))

    for _ in range(rounds):
        if not tui.solving():
            break
        key_round(tui, record)
    if stop:            # an endless solve: F4 ends it after the rounds
        tui.send("F4")
    tui.wait(lambda screen: not tui.solving(screen), timeout=600, interval=0.1)
    solved = time.monotonic() - start
    for _ in range(idle_rounds):
        key_round(tui, lambda kind, result: idle[kind].append(result[:2]))
    return samples, idle, solved


def busy(screen: list[str]) -> bool:
    """Whether the status line says a command runs (solving, stopping, running)."""
    return any(line.lstrip().startswith(("solving", "stopping", "running")) for line in screen[-2:])


def measure_stops(tui: Tui, stops: int, line: str, seed: int = 1) -> list[float]:
    """Seconds from F4 until the status line says the solve has ended, ``stops`` times: each time
    `undo` (the last solve, stopped or not), ``line`` (the solve again, from the same scene), a
    pause of 0.5 to 2 s into it, F4."""
    import random

    pick = random.Random(seed)
    latencies = []
    for _ in range(stops):
        tui.wait(lambda screen: not busy(screen), timeout=600, interval=0.05)
        tui.send("undo", "Enter")
        time.sleep(0.3)
        tui.wait(lambda screen: not busy(screen), timeout=60, interval=0.05)
        tui.send(line, "Enter")
        if not tui.wait(tui.solving, timeout=60, interval=0.02):
            continue
        time.sleep(pick.uniform(0.5, 2.0))
        if not tui.solving():
            continue
        seen = tui.wait_output(0, 0)[0]
        sent = time.monotonic()
        tui.send("F4")
        ended = None
        while time.monotonic() - sent < 30:
            seen, written = tui.wait_output(seen, 1.0)
            if not busy(tui.screen()):
                ended = written - sent
                break
        latencies.append(ended if ended is not None else float("inf"))
    return latencies


# tests/conftest.py's ENDLESS: no tolerance is ever met, and steps are too short to stall
ENDLESS = "set tol_violation 0\nset tol_kkt 0\nset tol_step 0\nbackend scipy max_step=1e-6\n"
ENDLESS_ITERATIONS = 3000


def endless(session: Path, folder: Path) -> Path:
    """A copy of ``session`` (in ``folder``) whose lines up to its first `iterate` build the
    scene, then a solve that never converges: every iteration starts from the sketch, as the
    first ones of a real solve do (basketball: ~0.15 s each on these machines)."""
    lines = session.read_text(encoding="utf-8").splitlines()
    first = next(i for i, line in enumerate(lines) if line.split("#")[0].strip().startswith("iterate"))
    copy = folder / f"endless_{session.name}"
    copy.write_text("\n".join(lines[:first]) + "\n" + ENDLESS + f"iterate {ENDLESS_ITERATIONS}\n", encoding="utf-8")
    return copy


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def ms(value: float) -> str:
    return f"{value * 1000:6.0f}" if value != float("inf") else "  lost"


def figures(values: list[float]) -> str:
    """median, p95 and max in ms (dashes without samples)."""
    if not values:
        return f"{'-':>6} {'-':>6} {'-':>6}"
    return f"{ms(percentile(values, 0.5))} {ms(percentile(values, 0.95))} {ms(max(values))}"


def row(label: str, values: list[tuple[float, float]], idle: list[tuple[float, float]]) -> list[str]:
    """Two lines (first change, settled) of a kind of key: solving n, median, p95, max, then idle."""
    lines = []
    for which, name in ((0, "first"), (1, "settled")):
        solving = [v[which] for v in values]
        rest = [v[which] for v in idle]
        lines.append(f"  {label + ' ' + name:<30} {len(solving):3d} {figures(solving)}   {len(rest):3d} {figures(rest)}")
    return lines


def load() -> str:
    return " ".join(f"{value:.2f}" for value in os.getloadavg())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("session", nargs="?", type=Path, default=ROOT / "sessions" / "basketball.stw")
    parser.add_argument("--rounds", type=int, default=20, help="rounds of keys at most (each ~4 s)")
    parser.add_argument("--idle-rounds", type=int, default=2, help="rounds of keys after the solve")
    parser.add_argument("--stops", type=int, default=6, help="F4 stops timed after the keys (0: none)")
    parser.add_argument("--endless", action="store_true",
                        help="solve without converging (see endless()): a solve that lasts through every round")
    parser.add_argument("--quick", action="store_true",
                        help="keys and stops only: no headless solves, no untouched TUI solve")
    args = parser.parse_args(argv)
    if shutil.which("tmux") is None:
        print("needs tmux", file=sys.stderr)
        return 2
    session = args.session.resolve()
    solve_line = next(line.split("#")[0].strip() for line in session.read_text(encoding="utf-8").splitlines()
                      if line.split("#")[0].strip().startswith("iterate"))
    loads = [load()]
    with tempfile.TemporaryDirectory() as state:
        if args.endless:
            session, solve_line = endless(session, Path(state)), f"iterate {ENDLESS_ITERATIONS}"
        # The TUI's autosaved journals go to the state folder, and every process starts in it:
        # `python -m`/`-c` put the working directory first on sys.path, so a checkout there would
        # win over PYTHONPATH.
        env = dict(os.environ, XDG_STATE_HOME=state)
        headless, quiet = [], None
        if not args.quick:
            print(f"{session.name}: headless solve…", flush=True)
            headless = [headless_solve(session, env)]
            print(f"  {headless[0]:.1f} s; the TUI solving untouched…", flush=True)
            with Tui(session, env) as tui:
                quiet = solve_time(tui)
            print(f"  {quiet:.1f} s; ", end="")
        print("the TUI solving while keys are pressed…", flush=True)
        with Tui(session, env) as tui:
            samples, idle, keyed = measure_keys(tui, args.rounds, args.idle_rounds, stop=args.endless)
            loads.append(load())
            stops = measure_stops(tui, args.stops, solve_line) if args.stops else []
        if not args.quick:
            print("  headless again…", flush=True)
            headless.append(headless_solve(session, env))
    loads.append(load())

    print(f"\nstw TUI at {SIZE[0]}x{SIZE[1]} in tmux while {session.name} solves "
          f"(ms from send-keys to the output that shows it; settled: the last change before "
          f"{SETTLE_QUIET * 1000:.0f} ms still; idle: the same keys after the solve); load {' -> '.join(loads)}")
    print(f"  {'':<30} {'n':>3} {'median':>6} {'p95':>6} {'max':>6}   {'n':>3} {'median':>6} {'p95':>6} {'max':>6}")
    print(f"  {'':<30} {'while solving':^24}   {'idle':^24}")
    for kind, values in samples.items():
        for text in row(kind, values, idle[kind]):
            print(text)
    print(f"  targets (solving, p95): echo <= {TARGETS['echo'] * 1000:.0f} ms; F2/F3 first <= 50 ms, "
          f"settled <= 100 ms")
    if stops:
        print(f"\nF4 to the status line's end of the solve ({len(stops)} stops of `{solve_line}`, 0.5-2 s in): "
              f"median {ms(percentile(stops, 0.5)).strip()} ms, p95 {ms(percentile(stops, 0.95)).strip()} ms, "
              f"max {ms(max(stops)).strip()} ms   target <= 300 ms")
    if headless and quiet is not None:
        base = min(headless)
        ratio = quiet / base
        print(f"\nsolve: headless {' and '.join(f'{h:.1f}' for h in headless)} s; in the TUI {quiet:.1f} s untouched "
              f"= {ratio:.2f}x the faster headless   target <= {TARGETS['ratio']}x"
              f"{'  ok' if ratio <= TARGETS['ratio'] else '  MISSED'}")
        print(f"       in the TUI while keys were pressed: {keyed:.1f} s = {keyed / base:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
