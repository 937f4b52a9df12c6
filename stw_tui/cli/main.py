"""The `stw` command: the TUI by default, plus headless `run`, `bench`, `compare`, `export`,
`survey` and `backends`."""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from stw_tui.sym.errors import SourceError, StwError, printable

if TYPE_CHECKING:   # numpy and the solver stack load only for the commands that solve
    from stw_tui.sos.backend import StepReport

SUBCOMMANDS = ("run", "bench", "backends", "compare", "export", "survey")

# The TUI comes first: it is what `stw` with no command opens.
USAGE = """
  stw [SESSION.stw] [--step] [--journal FILE]  open the TUI (and replay SESSION)
  stw --resume [JOURNAL] [--resolve]           reopen an autosaved session
  stw COMMAND ...                              headless (the commands below)"""


def _say(text: object, err: bool = False) -> None:
    """Print ``text`` terminal-safe (:func:`~stw_tui.sym.errors.printable`, line breaks kept): paths,
    messages and a plugin's text may hold escape sequences, C1 controls or bidi overrides."""
    print(printable(str(text), newlines=True), file=sys.stderr if err else sys.stdout)


def _table_header() -> str:
    return f"{'iter':>5} {'objective':>14} {'max viol':>10} {'KKT':>10} {'step':>8} {'lin it':>6} {'active':>6} {'ms':>8}"


def format_report(r: StepReport) -> str:
    """One row of the iteration table."""
    return (f"{r.iteration:>5} {r.objective:>14.8g} {r.max_violation:>10.2e} {r.kkt_residual:>10.2e} "
            f"{r.step_length:>8.3g} {r.linear_iterations:>6} {r.active:>6} {r.total_ms:>8.2f}")


def _journal_is_the_session(journal: Path | None, session: Path | None) -> bool:
    """`--journal` naming the session being replayed would append the replay to itself (and the
    next replay would run everything twice)."""
    if journal is None or session is None or not journal.exists() or not session.exists():
        return False
    return os.path.samefile(journal, session)


def _journal_refused(journal: Path | None, overwrite: bool) -> str | None:
    """Why `--journal FILE` may not be used (None: it may): a journal is appended to, so an existing
    file would be clobbered (a stranger's) or mixed with another session (a journal); with
    ``overwrite`` an existing journal is removed here, its checkpoints with it."""
    if journal is None or not os.path.lexists(journal):
        return None
    if journal.is_symlink() or not journal.is_file():
        return f"stw: --journal {journal} is not a regular file (a link, a folder or a device); journal to a new file"
    if not overwrite:
        return (f"stw: --journal {journal} exists; journal to a new file, add --overwrite to replace it, "
                f"or `stw --resume {journal}` to go on with it")
    from stw_tui.session.autosave import checkpoint_path
    from stw_tui.session.midsolve import midsolve_path

    for stale in (journal, checkpoint_path(journal), midsolve_path(journal)):
        stale.unlink(missing_ok=True)
    return None


JOURNAL_ON_ITSELF = ("stw: --journal {0} is the session being replayed: the replay would append itself "
                     "to it; journal to another file")


_OWN_PROCESS = False   # main() runs in a process of its own (console()), not inside a caller's


@contextlib.contextmanager
def _long_lived_imports():
    """In a process of its own, import with the cyclic collector paused, then freeze what was
    imported out of its sight: numpy, scipy.sparse and sympy make ~10^5 objects that live until
    the process ends, and walking them cost 0.1-0.2 s of collections during the import."""
    if not _OWN_PROCESS:
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.enable()


def _run(args: argparse.Namespace) -> int:
    with _long_lived_imports():
        from stw_tui.session.session import Session

    if _journal_is_the_session(args.journal, args.session):
        _say(JOURNAL_ON_ITSELF.format(args.journal), err=True)
        return 2
    refused = _journal_refused(args.journal, args.overwrite)
    if refused:
        _say(refused, err=True)
        return 2
    session = Session(journal_path=args.journal)
    if args.journal is not None:   # as the TUI's: `stw --resume JOURNAL` then restores, not re-solves
        from stw_tui.session.autosave import Checkpoints

        session.checkpoints = Checkpoints(args.journal)
    started = time.perf_counter()

    def on_line(number, line, outcome):
        if args.json or not outcome.message:
            return
        if outcome.run is not None:
            print(_table_header())
            for report in outcome.run.reports:
                print(format_report(report))
        _say(f"[{number}] {outcome.message}")

    if args.backend:
        try:
            session.execute(f"backend {args.backend}")
        except StwError as exc:   # e.g. a backend that is not installed: say so, run nothing
            _say(f"stw run: --backend {args.backend}: {exc}", err=True)
            return 2
    # A plugin backend solves in a process of its own, so Ctrl+C ends it even while it holds the
    # interpreter lock in C (stw_tui/session/child_process.py); the built-in SQP solves here.
    from stw_tui.session.child_process import SolverProcess

    session.solver_process = SolverProcess(quiet=False)
    try:
        session.run_file(args.session, on_line=on_line)
    except SourceError as exc:
        _say(exc.report(str(args.session)), err=True)
        return 2
    except StwError as exc:
        _say(f"{args.session}: {exc}", err=True)
        return 1
    finally:
        session.solver_process.close()
    seconds = time.perf_counter() - started
    if args.json:
        print(json.dumps(summary(session, args.samples, seconds)))
    code, why = run_verdict(session)
    if code:
        _say(f"stw run: {args.session}: {why}", err=True)
    return code


# `stw run`'s exit codes (README): a script can tell a motion it may use from one it may not
EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INFEASIBLE, EXIT_NOT_CONVERGED, EXIT_DENSE_FAILED = 1, 2, 3, 4, 5


def run_verdict(session) -> tuple[int, str]:
    """(exit code, why) of a replayed session: 0 only when every solve converged and the motion
    holds its constraints between the samples (the continuous-time check)."""
    from stw_tui.sos.backend import Status
    from stw_tui.sos.continuous import check_scene

    runs = session.runs
    for code, bad in ((EXIT_INFEASIBLE, [r for r in runs if r.status is Status.INFEASIBLE]),
                      (EXIT_NOT_CONVERGED, [r for r in runs if not r.converged])):
        if bad:
            return code, f"{len(bad)} of {len(runs)} solve(s) ended: {bad[0].status.value}"
    tol = session.scene.settings["dense_tol"]
    check = check_scene(session.scene)
    if check.failing(tol):
        return EXIT_DENSE_FAILED, f"the motion fails between the samples: {check.describe_failures(tol)}"
    return 0, ""


def summary(session, samples: int, seconds: float) -> dict:
    """The JSON result of `stw run --json`: the last solve, and the continuous-time check of
    every constraint over the whole animation (instances, dense, worst_t)."""
    from stw_tui.sos.continuous import check_scene

    runs = session.runs
    reports = [r for run in runs for r in run.reports]
    last = reports[-1] if reports else None
    check = check_scene(session.scene)
    tol = session.scene.settings["dense_tol"]
    return {
        "backend": session.scene.backend,
        "iterations": len(reports),
        "converged": bool(runs and runs[-1].converged),
        "objective": last.objective if last else None,
        "max_violation": last.max_violation if last else None,
        "dense_violation": check.dense_violation,
        "dense_ok": not check.failing(tol),
        "constraints": {name: c.as_dict() for name, c in check.checks.items()},
        "seconds": seconds,
        "dofs": session.sample(samples),
        "prints": [{"expr": p.expr, "t": p.t, "value": p.value} for p in session.prints],
    }


def _backends(args: argparse.Namespace) -> int:
    from stw_tui.sos.backend import available_backends, load_backend

    for name, ep in sorted(available_backends().items()):
        try:
            cls = load_backend(name)
        except StwError as exc:
            _say(f"{name:<10} unavailable: {exc}")
            continue
        dist = ep.dist.version if ep.dist is not None else "?"
        _say(f"{name:<10} {dist:<8} {cls.__doc__.strip().splitlines()[0] if cls.__doc__ else ''}")
        for opt in cls.options:
            choices = f" ({'|'.join(map(str, opt.choices))})" if opt.choices else ""
            _say(f"    {opt.name}={opt.default}{choices}  {opt.help}")
    return 0


def _compare(args: argparse.Namespace) -> int:
    from stw_tui.session.compare import run_compare

    try:
        return run_compare(args)
    except StwError as exc:
        _say(f"stw compare: {exc}", err=True)
        return 1


def _bench(args: argparse.Namespace) -> int:
    from stw_tui.cli.bench_targets import run_bench

    return run_bench(args)


def _export(args: argparse.Namespace) -> int:
    """Replay a session headless and write its motion (see stw_tui/session/export.py)."""
    from stw_tui.session.export import export_text, write_text
    from stw_tui.session.session import Session

    session = Session()
    try:
        session.run_file(args.session)
        what = tuple(n for n in (args.what or "").split(",") if n)
        target = write_text(args.output, export_text(session, args.format, args.fps, what), args.overwrite)
    except SourceError as exc:
        _say(exc.report(str(args.session)), err=True)
        return 2
    except StwError as exc:
        _say(f"stw export: {exc}", err=True)
        return 1
    _say(f"wrote {target}")
    return 0


def _survey(args: argparse.Namespace) -> int:
    """Replay a session headless, survey its scene's local optima (stw_tui/session/survey.py) with a
    progress line on stderr, and print the table (or its JSON)."""
    from stw_tui.cli.survey import run_survey_command

    return run_survey_command(args)


def build_parser() -> argparse.ArgumentParser:
    """The parser of the headless commands (`stw run`, `bench`, `compare`, `export`, ...)."""
    parser = argparse.ArgumentParser(
        prog="stw", usage=USAGE, description="Spacetime Windows for the terminal.",
        epilog="In the TUI: F1 help, F5 iterate, F4 stop, Ctrl+P palette, Ctrl+Q quit.")
    sub = parser.add_subparsers(dest="command", title="headless commands", metavar="COMMAND", prog="stw")
    run = sub.add_parser("run", help="replay a session headless and print the iterations")
    run.add_argument("session", type=Path)
    run.add_argument("--backend", help="backend to use (overridden by `backend` lines in the session)")
    run.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    run.add_argument("--samples", type=int, default=21, help="DOF samples in the JSON output")
    run.add_argument("--journal", type=Path, help="write the journal of this run to a new file "
                     "(solves checkpointed beside it, for `stw --resume`)")
    run.add_argument("--overwrite", action="store_true", help="replace an existing --journal file")
    run.set_defaults(func=_run)
    bench = sub.add_parser("bench", help="time the solvers against their speed targets (--detail: per solver)")
    bench.add_argument("--sessions", nargs="*", type=Path, help="session files (default: sessions/*.stw)")
    bench.add_argument("--repeat", type=int, default=3, help="repetitions per measurement")
    bench.add_argument("--quick", action="store_true", help="fewer sessions, one run each (< 2 min)")
    bench.add_argument("--anchors", action="store_true", help="also time crocoddyl, when installed")
    bench.add_argument("--detail", "--wide", dest="detail", action="store_true",
                       help="the per-backend, per-solver table (wider than 80 columns) instead of the targets")
    bench.set_defaults(func=_bench)
    comp = sub.add_parser("compare", help="solve a session's first problem with several backends")
    comp.add_argument("session", type=Path)
    comp.add_argument("--backends", default="scipy,torch",
                      help="comma list of NAME or NAME:opt=value:… (default scipy,torch)")
    comp.add_argument("--repeat", type=int, default=1, help="timed repetitions per backend")
    comp.add_argument("--json", action="store_true", help="print one JSON object")
    comp.set_defaults(func=_compare)
    export = sub.add_parser("export", help="replay a session headless and export its motion")
    export.add_argument("session", type=Path)
    export.add_argument("--format", choices=("csv", "json", "bvh"), default="csv",
                        help="file format (default csv)")
    export.add_argument("-o", "--output", type=Path, required=True, help="the file to write (a new one)")
    export.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    export.add_argument("--fps", type=int, default=30, help="frames per second (default 30)")
    export.add_argument("--what", help="subexpressions to add as columns, e.g. tau_ELBOW,arm.tip.x' "
                        "(bvh: the linkage to export)")
    export.set_defaults(func=_export)
    survey = sub.add_parser("survey", help="replay a session, then survey the local optima of its scene",
                            description="Options after N are those of the console's `survey` (help survey).")
    survey.add_argument("session", type=Path)
    survey.add_argument("n", metavar="N", help="the number of starts")
    survey.add_argument("options", nargs="*", metavar="OPTION=VALUE",
                        help="seed=S from=shake|sketch|random amplitude=A window=W workers=K iterate=M")
    survey.add_argument("--scheduler", metavar="ADDR", help="an existing Dask cluster, tcp://HOST:PORT (or pool, serial, or batch: "
                        "the starts as one batch on the torch backend, on a GPU when there is one)")
    survey.add_argument("--json", action="store_true", help="print the table as one JSON object")
    survey.set_defaults(func=_survey)
    backends = sub.add_parser("backends", help="list installed solver backends and their options")
    backends.set_defaults(func=_backends)
    return parser


def console() -> None:
    """The `stw` command and ``python -m stw_tui.cli(.main)``: :func:`main` in a process of its
    own, which exits when it returns. Its last act is to freeze every object out of the cyclic
    collector's sight, so the exit does not walk them all once more (0.4 s of a 2.5 s `stw run`
    on the arm). main() called inside another program (tests) leaves the collector alone."""
    global _OWN_PROCESS
    _OWN_PROCESS = True
    try:
        code = main()
    except BrokenPipeError:   # `stw backends | head`: the reader left; end quietly, as cat does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # no error at exit's flush
        code = 141   # 128 + SIGPIPE, what a shell reports for a command killed by it
    gc.freeze()
    sys.exit(code)


def main(argv: list[str] | None = None) -> int:
    """Entry point of `stw`: a headless command if one is named, else the TUI."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or (argv[0] not in SUBCOMMANDS and argv[0] not in ("-h", "--help")):
        return _launch_tui(argv)
    args = build_parser().parse_args(argv)
    _defer_unused_numpy()   # every command loads numpy and scipy.sparse (`stw backends`: its plugins)
    return args.func(args)


def _defer_unused_numpy() -> None:
    """In a process of its own, numpy's subpackages that scipy's import lists but stw never reads
    are deferred (cli/lazy_numpy.py); `stw --help` does not get here, so it imports no numpy."""
    if _OWN_PROCESS:
        from stw_tui.cli.lazy_numpy import defer_unused_numpy_subpackages

        defer_unused_numpy_subpackages()


# Frames a second Textual may draw (its default is 60). A key's echo waits for the screen's next
# frame, and while a solve runs the status line keeps the frame timer going, so at 60 a typed
# character appeared up to 17 ms late, more with the machine's own delays: console echo p95 36-51 ms
# against 9-20 at 120 and 11 at 240 (tests/tmux_latency.py, endless basketball at 80x24, load
# 0.8-1.2, one to three runs each). The screen is drawn only when something changed, so the rate
# is a ceiling, not a cost.
TUI_FPS = 120


def _tui_environment() -> None:
    """Settings Textual reads when it is imported, unless the user has set them (TEXTUAL_FPS)."""
    os.environ.setdefault("TEXTUAL_FPS", str(TUI_FPS))


def _launch_tui(argv: list[str]) -> int:
    _tui_environment()   # before Textual's first import
    parser = argparse.ArgumentParser(prog="stw", description="Open the Spacetime Windows TUI.")
    parser.add_argument("session", nargs="?", type=Path, help="a .stw session to open and replay")
    parser.add_argument("--step", action="store_true", help="step through the session line by line")
    parser.add_argument("--journal", type=Path, help="write the journal of this session to a new file "
                        "(default: a new one in the state directory, see `journal` in the console)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --journal file")
    parser.add_argument("--resume", nargs="?", const="", metavar="JOURNAL",
                        help="reopen the last autosaved journal (or JOURNAL) and restore its checkpointed state")
    parser.add_argument("--resolve", action="store_true", help="with --resume: solve everything again")
    args = parser.parse_args(argv)
    _defer_unused_numpy()
    try:
        from stw_tui.app import run_app
    except ImportError as exc:  # the TUI is optional for the headless core
        _say(f"stw: the TUI is unavailable ({exc}); use `stw run SESSION`", err=True)
        return 1
    if args.session is not None and not args.session.is_file():
        _say(f"stw: no session file {args.session}", err=True)
        return 2
    if _journal_is_the_session(args.journal, args.session):
        _say(JOURNAL_ON_ITSELF.format(args.journal), err=True)
        return 2
    if args.resume is not None:
        return _resume_tui(args, run_app)
    refused = _journal_refused(args.journal, args.overwrite)
    if refused:
        _say(refused, err=True)
        return 2
    return run_app(args.session, step=args.step, journal=args.journal or _autosave_journal(args.session))


def _autosave_journal(session: Path | None) -> Path | None:
    """A new journal in the state directory (None, with a warning, when it cannot be made)."""
    from stw_tui.session.paths import new_journal_path, state_dir

    try:
        return new_journal_path(session)
    except OSError as exc:
        _say(f"stw: not autosaving: cannot use {state_dir()} ({exc})", err=True)
        return None


def _resume_tui(args: argparse.Namespace, run_app) -> int:
    """`stw --resume [JOURNAL] [--resolve]`: replay the journal (checkpointed solves are not solved
    again), then open the TUI on it, appending to the same journal."""
    from stw_tui.session.paths import latest_journal, state_dir
    from stw_tui.session.resume import resume

    if args.session is not None or args.journal is not None:
        _say("stw: --resume reopens a journal; give no session file or --journal with it", err=True)
        return 2
    path = Path(args.resume) if args.resume else latest_journal()
    if path is None:
        _say(f"stw: no autosaved session in {state_dir()} to resume", err=True)
        return 2
    notes: list[str] = []   # shown in the TUI's console (the shell's screen is hidden while it runs)
    try:
        session, restored, solved = resume(path, resolve=args.resolve, on_note=notes.append)
    except (SourceError, StwError) as exc:
        _say(f"stw: cannot resume {path}: {exc}", err=True)
        return 1
    commands = sum(1 for entry in session.journal.entries if entry.ok)
    notes.insert(0, f"resumed {path}: {commands} command(s), {restored} solve(s) restored from checkpoints, "
                    f"{solved} solved again; Up recalls its commands")
    return run_app(None, session=session, notes=notes)


if __name__ == "__main__":
    console()
