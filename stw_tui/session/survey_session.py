"""Handlers of `survey`, `adopt` and `set scheduler` (session, scene copy, command) -> Outcome.

`survey` leaves the scene as it was: the table is kept on the session for `adopt`, and the
journal keeps the line as a comment (replaying a journal never re-runs a survey). `adopt K`
applies optimum K's start lines — the same text a worker solved — to the scene; the journal
keeps those lines, so a replay reaches the same motion without the survey, and `undo` takes it
back like any solve.
"""

from __future__ import annotations

import os

import numpy as np

from stw_tui.session.outcome import Outcome
from stw_tui.session.protocol import SessionLike
from stw_tui.session.survey import MOTION_TOL, SurveyPlan, motion_of, plan_tasks
from stw_tui.session.survey_engines import run_survey
from stw_tui.sym.errors import StwError


DEFAULT_AMPLITUDE = 0.5


def fingerprint(scene) -> tuple:
    """What must be unchanged for a survey's start lines to mean the same on the scene."""
    return (float(np.abs(scene.coefficient_vector()).sum()), scene.active_window, scene.backend,
            tuple(sorted(scene.backend_options.items())), tuple(scene.dofs), tuple(scene.constraints),
            tuple(scene.objectives), tuple(sorted(scene.settings.items())))


def plan_of(scene, cmd) -> SurveyPlan:
    """The :class:`SurveyPlan` of a `survey` command, its amplitude evaluated on the scene."""
    from stw_tui.session.survey import DEFAULT_ITERATIONS

    amplitude = scene.numeric(cmd.amplitude, "amplitude") if cmd.amplitude is not None else DEFAULT_AMPLITUDE
    return SurveyPlan(cmd.n, cmd.seed, cmd.source, amplitude, cmd.window,
                      cmd.iterations or DEFAULT_ITERATIONS, cmd.workers)


def survey(session: SessionLike, scene, cmd, on_report=None) -> Outcome:
    """Run the survey; ``on_report`` gets the table after each start (False cancels)."""

    plan = plan_of(scene, cmd)
    plan_tasks(session, plan)     # a bad plan fails here, before a cluster starts
    stop = {"asked": False}

    def progress(table, result):
        if on_report is not None and on_report(table) is False:
            stop["asked"] = True

    # F4 is also polled between results (the TUI's callback carries its stop flag), so a stop
    # does not wait for the next start to finish
    polled = getattr(on_report, "cancelled", None) or (lambda: False)
    table = run_survey(session, plan, scheduler=scene.scheduler or None, on_progress=progress,
                       cancelled=lambda: stop["asked"] or polled())
    table.fingerprint = fingerprint(session.scene)
    session.survey = table
    return Outcome(message=table.describe(),
                   journal_text=f"# {cmd.text}   (a survey: it leaves the scene as it was, and is not replayed)")


survey.reports_progress = True   # interpreter.apply_line passes it the progress callback


def adopt(session: SessionLike, scene, cmd, on_report=None) -> Outcome:
    """Make optimum ``cmd.rank`` of the last survey the scene, by applying its start's lines."""
    from stw_tui.session.interpreter import apply_line

    table = getattr(session, "survey", None)
    if table is None:
        raise StwError("no survey to adopt from: run `survey N` first")
    optima = table.optima
    if not optima:
        raise StwError("the last survey found no converged optimum to adopt")
    if cmd.rank > len(optima):
        raise StwError(f"no optimum {cmd.rank}: the last survey found {len(optima)} (adopt 1 to {len(optima)})")
    if table.fingerprint != fingerprint(scene):
        raise StwError("the scene has changed since the survey, so its starts would solve another problem; "
                       "`undo` back to it, or survey again")
    best = optima[cmd.rank - 1].best
    outcome = None
    for line in best.lines:
        outcome = apply_line(session, scene, line, None, on_report)
    last = outcome.run.reports[-1] if outcome.run is not None and outcome.run.reports else None
    text = (f"adopted optimum {cmd.rank} (start {best.index}, objective {best.objective:.7g}): "
            + "; ".join(best.lines))
    if last is not None:
        text += f"\nobjective {last.objective:.7g} here, {outcome.run.status.value}"
    apart = float(np.max(np.abs(motion_of(scene) - best.motion))) if best.motion.shape == \
        (len(scene.dofs), best.motion.shape[1]) else float("inf")
    if not apart <= MOTION_TOL * max(1.0, float(np.abs(best.motion).max())):
        text += (f"\nthe motion differs from the surveyed one by up to {apart:.2g} (the worker ran "
                 "another version of stw or of its backend?)")
    return Outcome(message=text, run=outcome.run, journal_text="\n".join(best.lines))


adopt.reports_progress = True


def _batch_note(backend: str) -> str:
    """Where `set scheduler batch` will solve (the setting stands even where no backend can)."""
    from stw_tui.sos.batch import batch_backend
    from stw_tui.sym.kinds import Capability

    try:
        cls = batch_backend(backend)
    except StwError as exc:
        return f"surveys will fail until a backend that solves batches is installed: {exc}"
    where = " (on a GPU when it sees one, else on the CPU)" if Capability.GPU in cls.capabilities else ""
    return f"surveys solve their starts as one batch on the {cls.name} backend{where}, in this process"


def trusted_schedulers(session: SessionLike) -> set[str]:
    """The cluster addresses the user named outside any session file: `stw survey --scheduler`
    (the session's ``trusted_schedulers``) and the environment's STW_SCHEDULER (comma-separated)."""
    named = os.environ.get("STW_SCHEDULER", "").replace(",", " ").split()
    return set(named) | set(getattr(session, "trusted_schedulers", ()))


def set_scheduler(session: SessionLike, scene, cmd) -> Outcome:
    """`set scheduler ADDRESS`: where later surveys send their starts.

    Raises:
        StwError: a cluster's address read from a session file or a journal (``cmd.line`` set)
            that the user has not named: whatever runs that cluster runs code in this process
            (results come back pickled), so only the user may choose it.
    """
    from stw_tui.session.survey_engines import dask_available

    if cmd.remote and cmd.line is not None and cmd.address not in trusted_schedulers(session):
        raise StwError(f"a session file may not send surveys to the cluster at {cmd.address}: a cluster "
                       "runs code in stw, so it is used only when you name it; type the line at the "
                       f"console, or name it with `stw survey --scheduler {cmd.address}` or "
                       f"STW_SCHEDULER={cmd.address}")
    scene.scheduler = cmd.address
    if cmd.address == "batch":
        return Outcome(message=_batch_note(scene.backend))
    if cmd.address in ("serial", "pool"):
        return Outcome(message="surveys run " + ("one start after another in this process" if cmd.address == "serial"
                                                 else "on a local process pool"))
    if not cmd.address:
        return Outcome(message="surveys run on an embedded Dask cluster" if dask_available()
                       else "surveys run on a local process pool (Dask is not installed)")
    note = "" if dask_available() else "; Dask is not installed here: pip install 'stw-tui[survey]'"
    return Outcome(message=f"surveys go to the Dask scheduler at {cmd.address}{note}")
