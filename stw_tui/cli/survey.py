"""`stw survey SESSION N [OPTION=VALUE…] [--scheduler ADDR] [--json]`: the console's `survey`, headless.

The session is replayed, then `survey N OPTIONS` runs as the console would run it (the same parser
and the same checks), with a progress line on stderr while the starts come back.
"""

from __future__ import annotations

import json
import sys

from stw_tui.sym.errors import SourceError, StwError, printable


def _progress_line(table) -> str:
    optima = len(table.optima)
    rate = len(table.results) / table.seconds if table.seconds > 0 else 0.0
    return (f"\r[{len(table.results)}/{table.plan.n}] {optima} optim{'um' if optima == 1 else 'a'}, "
            f"{len(table.unconverged)} not converged, {len(table.failed)} failed, {rate:.2g} starts/s")


def run_survey_command(args) -> int:
    """`stw survey`: replay the session, run the survey with progress on stderr, print the table."""
    from stw_tui.session.session import Session

    session = Session()
    line = " ".join(["survey", args.n, *args.options])
    if args.scheduler:
        session.trusted_schedulers.add(args.scheduler)   # the session file may name it too
    try:
        session.run_file(args.session)
        if args.scheduler:
            session.execute(f"set scheduler {args.scheduler}")
        shown = {"notes": 0}

        def on_report(table) -> None:
            for note in table.notes[shown["notes"]:]:
                print(f"\r{printable(note, newlines=True)}", file=sys.stderr)
            shown["notes"] = len(table.notes)
            print(_progress_line(table), end="", file=sys.stderr, flush=True)

        outcome = session.execute(line, on_report=on_report)
        print(file=sys.stderr)
    except SourceError as exc:
        print("\n" + printable(exc.report("stw survey"), newlines=True), file=sys.stderr)
        return 2
    except StwError as exc:
        print(f"\nstw survey: {printable(str(exc), newlines=True)}", file=sys.stderr)
        return 1
    finally:
        _close_clusters()
    if args.json:
        print(json.dumps({"session": str(args.session), **session.survey.as_dict()}))
    else:
        print(printable(outcome.message, newlines=True))
    return 0


def _close_clusters() -> None:
    """Close an embedded Dask cluster now, while the interpreter can still talk to it."""
    engines = sys.modules.get("stw_tui.session.survey_engines")
    if engines is not None:
        engines.close_local_clusters()
