"""Key latency of the real TUI in tmux at 80x24 while a session solves, and that solve's time in
the TUI against the same solve headless: the figures and targets of issue 12.

    python tests/tmux_latency.py [SESSION] [--rounds N]

SESSION defaults to sessions/basketball.stw (it must contain an `iterate` line). The TUI runs
with this interpreter (`python -m stw_tui.cli.main`, started in a temporary folder), so
PYTHONPATH picks the tree measured.

What is measured, in order:

1. the headless solve: the session's lines up to its first `iterate` run in a fresh process,
   then that `iterate` is timed;
2. the TUI solve, untouched: the time the status line says `solving` (polled every 0.1 s);
3. the TUI solve again, while keys are pressed: console echo (a typed character appears at the
   prompt), F2 and F3 (the active panel and plot tab's underline moves), `]` on the Curves plot
   (the next DOF's title, computed off the UI thread) and → on the Figure plot (the frame time in
   its title). A latency is the time from sending the keys until tmux receives the output that
   changed the screen (through a control-mode client, see :class:`Tui`). Only keys whose
   change came while the solve was still running count; before each key the area it changes must
   have been still for a moment (the tab underline slides); then two rounds of the same keys
   once the solve has ended (the idle columns: what the solve adds is the difference);
4. the headless solve once more (so a warm cache favours neither side).

Nothing here asserts: it prints the figures next to the targets (p95 key to screen <= 50 ms,
console echo p95 <= 20 ms, TUI solve <= 1.2 x headless). Needs tmux.
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


def timed_key(tui: Tui, keys: list[str], area, literal: bool = False) -> tuple[float, bool]:
    """Seconds from sending ``keys`` until the output that changed ``area(screen)`` (once the
    area has been still for 0.1 s: a tab's underline slides); and whether the solve was still
    running then."""
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
    while time.monotonic() - sent < 5:
        seen, written = tui.wait_output(seen, 5 - (time.monotonic() - sent))
        screen = tui.screen()
        if area(screen) != last:
            return max(0.0, written - sent), tui.solving(screen)
    return float("inf"), tui.solving()


KINDS = ("console echo", "F2 panel switch", "F3 plot switch", "] next DOF (Curves)", "→ scrub (Figure)")


def key_round(tui: Tui, record) -> None:
    """One round of every kind of key, each result passed to ``record(kind, (latency, solving))``."""
    for _ in range(5):
        record("console echo", timed_key(tui, ["x"], lambda s: prompt(s).count("x"), literal=True))
    tui.send("C-u")
    tui.send("F2")                                   # focuses the panels (no visible switch)
    for _ in range(2):
        record("F2 panel switch", timed_key(tui, ["F2"], lambda s: region(s, 1, "panels")))
    tui.send("F3")                                   # focuses the plots
    for _ in range(4):                               # back to the tab it started on
        record("F3 plot switch", timed_key(tui, ["F3"], lambda s: region(s, 1, "plots")))
    if show_plot(tui, "value"):                      # the Curves plot's title
        for _ in range(2):
            record("] next DOF (Curves)", timed_key(tui, ["]"], title, literal=True))
    if show_plot(tui, "t = "):                       # the Figure plot's
        for _ in range(2):
            record("→ scrub (Figure)", timed_key(tui, ["Right"], title))
    show_plot(tui, "value")
    tui.send("Escape")                               # back to the console
    time.sleep(0.2)


def measure_keys(tui: Tui, rounds: int, idle_rounds: int = 2) -> tuple[dict, dict, float]:
    """Latencies per kind of key while the solve runs (only those that finished during it), the
    same keys once it has ended (what a solve adds is the difference), and the solve's time."""
    if not tui.wait(tui.solving, interval=0.02):
        raise SystemExit("the TUI never started solving")
    start = time.monotonic()
    samples: dict[str, list[float]] = {kind: [] for kind in KINDS}
    idle: dict[str, list[float]] = {kind: [] for kind in KINDS}

    def record(kind: str, result: tuple[float, bool]) -> None:
        latency, during = result
        if during:
            samples[kind].append(latency)

    for _ in range(rounds):
        if not tui.solving():
            break
        key_round(tui, record)
    tui.wait(lambda screen: not tui.solving(screen), timeout=600, interval=0.1)
    solved = time.monotonic() - start
    for _ in range(idle_rounds):
        key_round(tui, lambda kind, result: idle[kind].append(result[0]))
    return samples, idle, solved


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def row(label: str, values: list[float], idle: list[float], target: str = "", ok: bool | None = None) -> str:
    if not values:
        return f"  {label:<22} no sample during the solve"
    ms = lambda v: f"{v * 1000:7.0f}" if v != float("inf") else "   lost"
    verdict = "" if ok is None else ("  ok" if ok else "  MISSED")
    rest = f"{ms(percentile(idle, 0.5))} {ms(percentile(idle, 0.95))}" if idle else f"{'-':>7} {'-':>7}"
    return (f"  {label:<22} {len(values):4d} {ms(percentile(values, 0.5))} {ms(percentile(values, 0.95))} "
            f"{ms(max(values))} {rest}   {target}{verdict}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("session", nargs="?", type=Path, default=ROOT / "sessions" / "basketball.stw")
    parser.add_argument("--rounds", type=int, default=20, help="rounds of keys at most (each ~4 s)")
    args = parser.parse_args(argv)
    if shutil.which("tmux") is None:
        print("needs tmux", file=sys.stderr)
        return 2
    session = args.session.resolve()
    with tempfile.TemporaryDirectory() as state:
        # The TUI's autosaved journals go to the state folder, and every process starts in it:
        # `python -m`/`-c` put the working directory first on sys.path, so a checkout there would
        # win over PYTHONPATH.
        env = dict(os.environ, XDG_STATE_HOME=state)
        print(f"{session.name}: headless solve…", flush=True)
        headless = [headless_solve(session, env)]
        print(f"  {headless[0]:.1f} s; the TUI solving untouched…", flush=True)
        with Tui(session, env) as tui:
            quiet = solve_time(tui)
        print(f"  {quiet:.1f} s; the TUI solving while keys are pressed…", flush=True)
        with Tui(session, env) as tui:
            samples, idle, keyed = measure_keys(tui, args.rounds)
        print("  headless again…", flush=True)
        headless.append(headless_solve(session, env))

    every = [v for values in samples.values() for v in values]
    every_idle = [v for values in idle.values() for v in values]
    print(f"\nstw TUI at {SIZE[0]}x{SIZE[1]} in tmux while {session.name} solves "
          f"(ms from send-keys to the output that shows it; idle: the same keys after the solve)")
    print(f"  {'':<22} {'n':>4} {'median':>7} {'p95':>7} {'max':>7} {'idle50':>7} {'idle95':>7}   target")
    if every:
        print(row("any key", every, every_idle, f"p95 <= {TARGETS['keys'] * 1000:.0f} ms",
                  percentile(every, 0.95) <= TARGETS["keys"]))
    for kind, values in samples.items():
        if kind == "console echo":
            print(row(kind, values, idle[kind], f"p95 <= {TARGETS['echo'] * 1000:.0f} ms",
                      bool(values) and percentile(values, 0.95) <= TARGETS["echo"]))
        else:
            print(row(kind, values, idle[kind]))
    base = min(headless)
    ratio = quiet / base
    print(f"\nsolve: headless {' and '.join(f'{h:.1f}' for h in headless)} s; in the TUI {quiet:.1f} s untouched "
          f"= {ratio:.2f}x the faster headless   target <= {TARGETS['ratio']}x"
          f"{'  ok' if ratio <= TARGETS['ratio'] else '  MISSED'}")
    print(f"       in the TUI while keys were pressed: {keyed:.1f} s "
          f"= {keyed / base:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
