"""Starts per second of a survey on each engine, with the ratio to serial measured in the same run.

    python -m stw_tui.cli.survey_bench SESSION N [OPTION=VALUE…] [--workers K]

The session is replayed, then the same survey (`survey N OPTIONS`, the console's parser) runs on
each engine: serial in this process, a local process pool of K workers, a Dask LocalCluster of
K workers when Dask is installed, and the starts as one batch on the torch backend (on cuda when
torch sees a GPU, else on the CPU) when it is installed. Each engine pays what a user pays for its
first survey, except the LocalCluster's own start-up (a TUI session starts it once) and the import
of torch by the batch, which are timed apart: every worker process replays the session once, the
pool's processes start with the survey, and the batch lowers the terms to torch in it. The machines
are shared and noisy, so only the ratios of one run mean much. The tables must agree (the same
optima from the same starts); the last column says whether they do.
"""

from __future__ import annotations

import argparse
import time

from stw_tui.session.session import Session
from stw_tui.session.survey_engines import (BatchEngine, DaskEngine, PoolEngine, SerialEngine, dask_available,
                                            run_survey)
from stw_tui.sos.batch import batch_backend
from stw_tui.session.survey_session import plan_of
from stw_tui.sym.errors import StwError, printable


def _rows(table) -> list:
    # members in index order: starts whose objectives agree to 1e-12 may rank either way
    return [(round(o.best.objective, 6), tuple(sorted(m.index for m in o.members))) for o in table.optima]


def _batch_installed() -> bool:
    """Whether an installed backend solves batches (the torch backend does)."""
    try:
        batch_backend()
    except StwError:
        return False
    return True


def main(argv: list[str] | None = None) -> int:
    """Run the same survey on each engine and print starts per second and the ratio to serial."""
    parser = argparse.ArgumentParser(prog="python -m stw_tui.cli.survey_bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("session")
    parser.add_argument("n", metavar="N")
    parser.add_argument("options", nargs="*", metavar="OPTION=VALUE")
    parser.add_argument("--workers", type=int, default=None, help="pool and cluster size (default: cores)")
    parser.add_argument("--engines", default="serial,pool,dask,batch",
                        help="which engines to run, of serial,pool,dask,batch (serial always runs: the reference)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="surveys per engine: the first pays what a user's first survey pays, later ones "
                             "find caches warm (ratios are to serial's run of the same number)")
    args = parser.parse_args(argv)
    from stw_tui.session.interpreter import SceneScope
    from stw_tui.sym.language import parse_command

    session = Session()
    try:
        session.run_file(args.session)
        command = parse_command(" ".join(["survey", args.n, *args.options]), SceneScope(session.scene))
    except StwError as exc:
        print(printable(f"survey_bench: {exc}", newlines=True))
        return 1
    plan = plan_of(session.scene, command)
    wanted = set(args.engines.split(","))
    engines = [SerialEngine()] + ([PoolEngine(args.workers)] if "pool" in wanted else [])
    if dask_available() and "dask" in wanted:
        engines.append(DaskEngine(args.workers))
    if "batch" in wanted and _batch_installed():
        engines.append(BatchEngine())
    print(printable(f"{args.session}: survey {args.n} {' '.join(args.options)}"))
    print(f"{'engine':<62} {'run':>3} {'s':>7} {'starts/s':>9} {'ratio':>6} {'optima':>6}  same table as serial")
    serial, first = {}, None
    for engine in engines:
        note = ""
        if isinstance(engine, DaskEngine):
            started = time.perf_counter()
            engine.client()
            note = f"  (cluster start-up {time.perf_counter() - started:.1f} s, not counted)"
        if isinstance(engine, BatchEngine):
            started = time.perf_counter()
            engine.solver()
            note = f"  (importing torch {time.perf_counter() - started:.1f} s, not counted)"
        for run in range(1, max(1, args.repeat) + 1):
            table = run_survey(session, plan, engine)
            rate = len(table.results) / table.seconds
            serial.setdefault(run, (rate, _rows(table)))
            first = first or table
            same = "yes" if _rows(table) == serial[1][1] else "NO"
            print(f"{engine.describe():<62} {run:>3} {table.seconds:>7.1f} {rate:>9.3f} {rate / serial[run][0]:>6.2f} "
                  f"{len(table.optima):>6}  {same}{note if run == 1 else ''}", flush=True)
    print()
    print(first.describe(limit=40))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
