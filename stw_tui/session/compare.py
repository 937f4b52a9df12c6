"""`stw compare`: several backends on the same window problem from the same starting state."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from stw_tui.session.bench import measure, split_at_first_iterate
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError, printable


SAME_MOTION = 1e-5   # largest DOF difference for two converged motions to be the same optimum


def compare(path: Path, backends: list[str], repeat: int = 1, on_row=None) -> list[dict]:
    """Replay ``path`` up to its first `iterate`, then solve that scene with each backend.

    Each entry of ``backends`` is ``NAME`` or ``NAME:opt=value:opt=value``.
    Returns one row per backend; ``max_motion_difference`` is the largest difference of any DOF
    value (201 samples over the span) from the first backend's motion, and ``verdict`` says
    whether it reached the first backend's optimum ("same optimum", "different local optimum",
    "not converged"). ``on_row(row)`` is called as each backend finishes.
    Raises:
        StwError: unreadable session, no `iterate` in it, or an unknown backend.
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise StwError(f"cannot read session {path}: {exc}") from exc
    split = split_at_first_iterate(text)
    if split is None:
        raise StwError(f"{path} has no `iterate` line: nothing to compare")
    prefix, n = split
    setup = Session()
    setup.run_text(prefix)
    return compare_scene(setup.scene, n, backends, repeat, Path(path).stem, on_row)


def compare_scene(scene, n: int, backends: list[str], repeat: int = 1, label: str = "scene",
                  on_row=None) -> list[dict]:
    """Solve copies of ``scene`` with each backend (up to ``n`` iterations); rows as :func:`compare`."""
    setup = Session()
    setup.scene = scene.copy()
    rows, first = [], None
    for spec in backends:
        name, *opts = spec.split(":")
        m = measure(label, setup, n, name, " ".join(opts), repeat)
        first = m.motion if first is None else first
        difference = float(np.abs(m.motion - first).max())
        both_converged = m.converged and (rows[0]["converged"] if rows else True)
        verdict = ("not converged" if not both_converged
                   else "same optimum" if difference <= SAME_MOTION else "different local optimum")
        rows.append({"backend": m.config, "iterations": m.iterations, "converged": m.converged,
                     "median_ms_per_iteration": m.ms_per_iteration, "seconds_to_converge": m.seconds,
                     "objective": m.objective, "max_violation": m.violation,
                     "max_motion_difference": difference, "verdict": verdict})
        if on_row is not None:
            on_row(rows[-1])
    return rows


def run_compare(args) -> int:
    """`stw compare`: print each backend's row as it finishes, or all rows as JSON."""
    backends = [b for b in args.backends.split(",") if b]
    if args.json:
        rows = compare(args.session, backends, args.repeat)
        print(json.dumps({"session": str(args.session), "backends": rows}))
        return 0
    width = max([22, *map(len, backends)])   # a backend's label is its spec, ':' read as ' '
    print(f"{'backend':<{width}} {'its':>4} {'conv':>5} {'ms/it':>8} {'s total':>8} {'objective':>13} "
          f"{'max viol':>9} {'Δ motion':>9}", flush=True)

    shown = []

    def row(r):   # each backend's row as soon as it has finished: long solves show progress
        note = "" if not shown and r["verdict"] == "same optimum" else f"  {r['verdict']}"
        shown.append(r)
        print(f"{printable(str(r['backend'])):<{width}} {r['iterations']:>4} {str(r['converged']):>5} "
              f"{r['median_ms_per_iteration']:>8.2f} {r['seconds_to_converge']:>8.3f} {r['objective']:>13.8g} "
              f"{r['max_violation']:>9.1e} {r['max_motion_difference']:>9.1e}"
              + note, flush=True)

    compare(args.session, backends, args.repeat, on_row=row)
    return 0
