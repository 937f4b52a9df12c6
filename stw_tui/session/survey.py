"""A survey of local optima: many starts from the current scene, each solved to convergence, and the
converged motions grouped into distinct local optima ranked by objective.

A start is plain session text. Its task carries the session's replayable text (the journal lines
that built the scene) and the start's own lines — `shake … seed=S`, jittered `key` lines or a
random `dof X = …` curve, then `iterate N` — never a pickled scene. A worker rebuilds the scene by
replaying the text (once per process: :func:`_base`), so a worker anywhere needs only the package,
and `adopt K` makes optimum K the scene by applying the same lines, which the journal keeps.

Two converged motions are the same optimum when their objectives agree to ``OBJECTIVE_RTOL`` and
every DOF value agrees within ``MOTION_TOL`` at ``SAMPLES`` times (the measure of `stw compare`,
with a tolerance loose enough for solves that stop at the KKT tolerance; see ``MOTION_TOL``). Starts that fail, stop
short or break a constraint between the samples are counted, never mixed into the optima.
The engines that run the tasks are in :mod:`.survey_engines`.
"""

from __future__ import annotations

import copy
import hashlib
import os
import socket
import time
from dataclasses import dataclass, field

import numpy as np

from stw_tui.sym.language import QUERIES, WRITERS
from stw_tui.sym.errors import StwError

SOURCES = ("shake", "sketch", "random")
OBJECTIVE_RTOL = 1e-4   # objectives of one optimum agree to this relative tolerance ...
# ... and its DOF values to this, times max(1, |value|), at every sample. The SQP stops at a KKT
# tolerance, and a DOF the objective hardly depends on wanders: on the arm throw, starts whose
# objectives agree to 1e-7 had wrists up to 9e-3 rad apart, while its distinct optima differ by
# 0.7 or more; the count of optima there is the same for any tolerance from 1e-2 to 1e-1.
MOTION_TOL = 1e-2
SAMPLES = 201           # times over the span at which motions are compared (as `stw compare`)
FRAMES = 4              # stick figures per optimum for the gallery's thumbnails, evenly over the span
DEFAULT_ITERATIONS = 100
# First words of journal lines a worker must not replay: they read the scene (or write files).
READ_ONLY = QUERIES | WRITERS
RANDOM_MODES = 3        # sine modes of a `from=random` curve


@dataclass(frozen=True)
class SurveyPlan:
    """What `survey N …` asks for."""

    n: int
    seed: int = 0
    source: str = "shake"
    amplitude: float = 0.5
    window: str | None = None      # None: the scene's active window
    iterations: int = DEFAULT_ITERATIONS
    workers: int | None = None     # None: one per core

    def describe(self) -> str:
        """The plan's options as the table's summary shows them."""
        where = f", window {self.window}" if self.window else ""
        return f"from={self.source} amplitude={self.amplitude:g} seed={self.seed}{where}"


@dataclass(frozen=True)
class StartTask:
    """One start: the base session text, the start's own lines, and a checksum of the base scene
    (so a worker whose replay differs says so instead of solving another problem). The session
    class that replays it travels by name (pickled by reference), never as a pickled scene."""

    base_text: str
    lines: tuple[str, ...]
    index: int
    seed: int
    checksum: float
    session_class: type


@dataclass
class StartResult:
    """What became of one start (plain data: it crosses process and machine boundaries)."""

    index: int
    seed: int
    lines: tuple[str, ...]
    status: str                    # a Status value, "failed" or "lost"
    converged: bool = False        # converged AND every constraint holds between the samples
    objective: float = float("nan")
    max_violation: float = float("nan")
    dense_violation: float = float("nan")
    iterations: int = 0
    seconds: float = 0.0
    dofs: tuple[str, ...] = ()
    motion: np.ndarray | None = None   # (len(dofs), SAMPLES) DOF values
    curves: dict = field(default_factory=dict)   # DOF -> (knots, control points), to show or play it
    descriptors: dict = field(default_factory=dict)
    frames: list = field(default_factory=list)   # figure.Figure at FRAMES times: the gallery's thumbnails
    error: str = ""
    worker: str = ""


# --- building the starts ---------------------------------------------------------------------
def base_text(session) -> str:
    """The session's replayable text without the lines that only read the scene."""
    kept = []
    for text in session.journal.replayable():
        words = text.split("#", 1)[0].split()
        if not words or words[0] in READ_ONLY:   # comments too (a survey is journalled as one)
            continue
        if words[:2] == ["set", "scheduler"]:
            # where starts run is no part of what they solve, and a replayed cluster address is
            # refused; still a step, so the journal's `undo`s take back the same steps
            text = "set scheduler local"
        kept.append(text)
    return "\n".join(kept)


def checksum(scene) -> float:
    """A cheap fingerprint of a scene's curves: a worker checks its replay against it."""
    return float(np.abs(scene.coefficient_vector()).sum())


def start_seeds(seed: int, n: int) -> list[int]:
    """Seeds of the starts: the first n of a survey with more starts are the same."""
    return [int(s) for s in np.random.default_rng(seed).integers(0, 2**31 - 1, size=n)]


def plan_tasks(session, plan: SurveyPlan) -> list[StartTask]:
    """The tasks of a survey of ``session``'s scene.

    Raises:
        StwError: an unknown source or window, a bad count or amplitude, or `from=sketch` on a
            scene without keyframes.
    """
    scene = session.scene
    if plan.n < 1:
        raise StwError("a survey needs at least one start")
    if plan.source not in SOURCES:
        raise StwError(f"from={plan.source}: a start comes from {', '.join(SOURCES)}")
    if not (np.isfinite(plan.amplitude) and plan.amplitude > 0):
        raise StwError(f"amplitude must be a finite number > 0, not {plan.amplitude:g}")
    if plan.iterations < 1:
        raise StwError("a survey needs at least one iteration per start")
    if not scene.dofs:
        raise StwError("nothing to survey: the scene has no DOF")
    if not scene.objectives and not scene.constraints:
        raise StwError("nothing to survey: the scene has no objective or constraint")
    name = plan.window or scene.active_window
    if name not in scene.windows:
        raise StwError(f"no window named '{name}' (windows: {', '.join(scene.windows)})")
    window = scene.windows[name]
    if window.interval is not None and plan.source != "shake":
        # Keyframe and random starts change whole curves, and a windowed solve cannot move them
        # back outside its interval: each start would end unconverged after all its iterations
        # (measured on the arm throw: 4 of 4, 70 s each, when shake changed whole curves too).
        # A shake there moves only what the window frees.
        a, b = window.interval
        raise StwError(f"window {name} frees only [{a:g}, {b:g}], but a {plan.source} start changes whole "
                       f"curves, which a solve in it could not bring back outside it; survey from=shake, "
                       "window=all, or a window without an interval")
    dofs = list(window.dofs or scene.dofs)
    prefix = [f"use {name}"] if name != scene.active_window else []
    text, total = base_text(session), checksum(scene)
    tasks = []
    for index, seed in enumerate(start_seeds(plan.seed, plan.n)):
        lines = prefix + _start_lines(scene, plan, dofs, seed) + [f"iterate {plan.iterations}"]
        tasks.append(StartTask(text, tuple(lines), index, seed, total, type(session)))
    return tasks


def _start_lines(scene, plan: SurveyPlan, dofs: list[str], seed: int) -> list[str]:
    if plan.source == "shake":
        return [f"shake amplitude={plan.amplitude!r} seed={seed}"]
    rng = np.random.default_rng(seed)
    if plan.source == "sketch":
        return _sketch_lines(scene, plan.amplitude, dofs, rng)
    return [_random_line(scene, name, plan.amplitude, rng) for name in dofs]


def _sketch_lines(scene, amplitude: float, dofs: list[str], rng) -> list[str]:
    """Every keyframe of the window's DOF, its value jittered by ``amplitude`` × N(0, 1)."""
    by_time: dict[float, list[str]] = {}
    for name in dofs:
        for t, value in scene.dofs[name].keys:
            by_time.setdefault(t, []).append(f"{name}={value + amplitude * rng.standard_normal()!r}")
    if not by_time:
        raise StwError("from=sketch jitters keyframes, and the window's DOF have none; "
                       "sketch some with `key T DOF=VALUE`, or survey from=shake")
    return [f"key {t!r} " + ", ".join(items) for t, items in sorted(by_time.items())]


def _random_line(scene, name: str, amplitude: float, rng) -> str:
    """`dof NAME = …`: the straight line between the curve's end values plus random sine modes."""
    curve = scene.dofs[name].curve
    t0, t1 = scene.t0, scene.t1
    v0, v1 = (float(v) for v in curve.evaluate(np.array([t0, t1])))
    terms = [f"{v0!r}", _signed((v1 - v0) / (t1 - t0), f"(t - {t0!r})")]
    for k in range(1, RANDOM_MODES + 1):
        terms.append(_signed(amplitude * rng.standard_normal(), f"sin({k * np.pi / (t1 - t0)!r}*(t - {t0!r}))"))
    return f"dof {name} = " + " ".join(terms)


def _signed(c: float, factor: str) -> str:
    return f"{'-' if c < 0 else '+'} {abs(float(c))!r}*{factor}"


# --- solving one start (runs in a worker) ----------------------------------------------------
_BASES: dict[str, tuple] = {}    # this process's replayed base scenes, by text digest
_BASES_KEPT = 2


def _base(text: str, session_class: type):
    """The scene and warm start the base text replays to, replayed once per process."""
    key = hashlib.sha256(text.encode("utf-8")).hexdigest()
    if key not in _BASES:
        session = session_class()
        session.run_text(text)
        while len(_BASES) >= _BASES_KEPT:
            _BASES.pop(next(iter(_BASES)))
        _BASES[key] = (session.scene, copy.deepcopy(session.warm))
    return _BASES[key]


def replay_base(task: StartTask) -> None:
    """Replay ``task``'s base text into this process's cache now (before starts run on threads)."""
    _base(task.base_text, task.session_class)


def solve_start(task: StartTask) -> StartResult:
    """Replay the base text, apply the start's lines and report what the solve reached.
    Never raises for a bad start: the error is in the result."""
    result = StartResult(task.index, task.seed, task.lines, "failed",
                         worker=f"{socket.gethostname()}:{os.getpid()}")
    started = time.perf_counter()
    try:
        scene, warm = _base(task.base_text, task.session_class)
        if not np.isclose(checksum(scene), task.checksum, rtol=1e-9, atol=1e-12):
            raise StwError("replaying the session here gives another scene than the survey's "
                           "(a different version of stw or of a backend?)")
        session = task.session_class()
        session.scene, session.warm = scene.copy(), copy.deepcopy(warm)
        for line in task.lines:
            session.execute(line)
        _measure(session, result)
    except StwError as exc:
        result.error = str(exc)
    except Exception as exc:  # a bug in one start must not end the survey: report it
        result.error = f"internal error ({type(exc).__name__}: {exc})"
    result.seconds = time.perf_counter() - started
    return result


def _measure(session, result: StartResult) -> None:
    from stw_tui.session.figure import scene_figure
    from stw_tui.session.survey_descriptors import describe
    from stw_tui.sos.continuous import check_scene

    scene, run = session.scene, session.runs[-1]
    last = run.reports[-1] if run.reports else None
    report = check_scene(scene)
    result.status = run.status.value
    result.converged = run.converged and not report.failing(scene.settings["dense_tol"])
    if run.converged and not result.converged:
        result.status = "fails between the samples: " + report.describe_failures(scene.settings["dense_tol"])
    result.objective = last.objective if last else float("nan")
    result.max_violation = last.max_violation if last else float("nan")
    result.dense_violation = report.dense_violation
    result.iterations = len(run.reports)
    result.dofs = tuple(scene.dofs)
    result.motion = motion_of(scene)
    result.curves = {name: (np.asarray(d.curve.knots), np.asarray(d.curve.coef)) for name, d in scene.dofs.items()}
    result.descriptors = describe(scene)
    result.frames = [scene_figure(scene, float(t)) for t in np.linspace(scene.t0, scene.t1, FRAMES)]


def motion_of(scene) -> np.ndarray:
    """Every DOF's values at ``SAMPLES`` times over the span, to tell optima apart."""
    times = np.linspace(scene.t0, scene.t1, SAMPLES)
    return np.array([scene.dof_values(name, times) for name in scene.dofs])


def preview_scene(scene, result: StartResult):
    """A copy of ``scene`` with the curves a start reached (to draw or play, not to solve)."""
    from stw_tui.sos.spline import DofCurve

    preview = scene.copy()
    for name, (knots, coef) in result.curves.items():
        if name in preview.dofs:
            preview.dofs[name].curve = DofCurve(np.array(knots), np.array(coef))
    return preview


# --- grouping into optima --------------------------------------------------------------------
@dataclass
class Optimum:
    """Starts that reached the same local optimum; the first member has the least objective."""

    members: list[StartResult]

    @property
    def best(self) -> StartResult:
        """The member with the least objective."""
        return self.members[0]

    @property
    def count(self) -> int:
        """How many starts reached this optimum."""
        return len(self.members)


def same_optimum(a: StartResult, b: StartResult, objective_rtol: float = OBJECTIVE_RTOL,
                 motion_tol: float = MOTION_TOL) -> bool:
    """Objectives within a relative tolerance AND every DOF value within ``motion_tol``."""
    scale = max(abs(a.objective), abs(b.objective), 1e-12)
    if abs(a.objective - b.objective) > objective_rtol * scale:
        return False
    if a.dofs != b.dofs or a.motion.shape != b.motion.shape:
        return False
    return bool(np.all(np.abs(a.motion - b.motion) <= motion_tol * np.maximum(1.0, np.abs(a.motion))))


def group(results: list[StartResult], objective_rtol: float = OBJECTIVE_RTOL,
          motion_tol: float = MOTION_TOL) -> list[Optimum]:
    """Converged results grouped into optima, ranked by objective. The order the results arrived
    in does not matter: they are taken by (objective, start index)."""
    optima: list[Optimum] = []
    for r in sorted((r for r in results if r.converged), key=lambda r: (r.objective, r.index)):
        for optimum in optima:
            if same_optimum(optimum.best, r, objective_rtol, motion_tol):
                optimum.members.append(r)
                break
        else:
            optima.append(Optimum([r]))
    return optima


@dataclass
class SurveyTable:
    """A survey's outcome so far: the optima, and the starts that did not converge or failed."""

    plan: SurveyPlan
    base_text: str
    engine: str = ""
    results: list[StartResult] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)   # worker loss, the engine chosen
    seconds: float = 0.0
    cancelled: bool = False
    fingerprint: tuple = ()   # of the surveyed scene: `adopt` refuses a scene changed since

    @property
    def optima(self) -> list[Optimum]:
        """The converged starts grouped into distinct optima, ranked by objective."""
        return group(self.results)

    @property
    def failed(self) -> list[StartResult]:
        """Starts that gave no motion (an error, or a lost worker)."""
        return [r for r in self.results if r.motion is None]

    @property
    def unconverged(self) -> list[StartResult]:
        """Starts that gave a motion but did not converge."""
        return [r for r in self.results if r.motion is not None and not r.converged]

    def summary(self) -> str:
        """The table's first line: counts of optima and starts, the engine and the rate."""
        optima, done = self.optima, len(self.results)
        rate = f", {done / self.seconds:.2g} starts/s" if self.seconds > 0 else ""
        head = (f"survey of {done} of {self.plan.n} start(s) ({self.plan.describe()}"
                f"{', cancelled' if self.cancelled else ''}): {len(optima)} distinct optim"
                f"{'um' if len(optima) == 1 else 'a'} from {done - len(self.failed) - len(self.unconverged)} "
                f"converged, {len(self.unconverged)} not converged, {len(self.failed)} failed; "
                f"{self.engine}, {self.seconds:.1f} s{rate}")
        return head

    def describe(self, limit: int = 20) -> str:
        """The table as text: a summary, one row per optimum, then what failed and the notes."""
        lines = [self.summary()]
        optima = self.optima
        if optima:
            lines.append(f"{'rank':>4} {'objective':>13} {'dense viol':>10} {'count':>5}  descriptors")
            for rank, o in enumerate(optima[:limit], start=1):
                lines.append(f"{rank:>4} {o.best.objective:>13.7g} {o.best.dense_violation:>10.1e} "
                             f"{o.count:>5}  {describe_text(o.best.descriptors)}")
            if len(optima) > limit:
                lines.append(f"  … and {len(optima) - limit} more")
        for r in (self.unconverged + self.failed)[:3]:
            lines.append(f"start {r.index} (seed {r.seed}): {r.status}" + (f": {r.error}" if r.error else ""))
        lines += self.notes
        if optima:
            lines.append("`adopt K` makes optimum K the scene")
        return "\n".join(lines)

    def as_dict(self) -> dict:
        """The table for `stw survey --json`."""
        def row(rank: int, o: Optimum) -> dict:
            b = o.best
            return {"rank": rank, "objective": b.objective, "max_violation": b.max_violation,
                    "dense_violation": b.dense_violation, "count": o.count,
                    "starts": [m.index for m in o.members], "lines": list(b.lines),
                    "descriptors": b.descriptors}

        def other(r: StartResult) -> dict:
            return {"start": r.index, "seed": r.seed, "status": r.status, "error": r.error}

        return {"plan": {"n": self.plan.n, "seed": self.plan.seed, "from": self.plan.source,
                         "amplitude": self.plan.amplitude, "window": self.plan.window,
                         "iterations": self.plan.iterations},
                "engine": self.engine, "seconds": self.seconds, "done": len(self.results),
                "cancelled": self.cancelled,
                "optima": [row(k, o) for k, o in enumerate(self.optima, start=1)],
                "unconverged": [other(r) for r in self.unconverged],
                "failed": [other(r) for r in self.failed], "notes": list(self.notes)}


def describe_text(descriptors: dict) -> str:
    """'SHOULDER -2.1..0.4, ELBOW 0..2.5; multi-turn WRIST; first moves SHOULDER- ELBOW+; release overhand'."""
    parts = [", ".join(f"{n} {lo:.3g}..{hi:.3g}" for n, (lo, hi) in descriptors.get("ranges", {}).items())]
    if descriptors.get("multi_turn"):
        parts.append("multi-turn " + ",".join(descriptors["multi_turn"]))
    first = [f"{n}{'+' if sign > 0 else '-'}" for n, sign in descriptors.get("first_move", {}).items() if sign]
    if first:
        parts.append("first moves " + " ".join(first))
    if descriptors.get("release"):
        parts.append("release " + descriptors["release"])
    return "; ".join(p for p in parts if p)
