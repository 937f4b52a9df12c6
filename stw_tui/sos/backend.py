"""The solver backend plugin interface, discovery, and the one driver loop every backend runs under.

A backend is a class registered under the entry-point group ``stw_tui.backends``. It never loops
by itself: the driver (:func:`run_iterations`) calls ``init`` once and ``step`` once per
iteration, checks for non-finite results, asks the caller's callback whether to go on, and stops
on convergence — so pause, single-step and cancel work the same for every backend (the shape of
optimistix's init/step/terminate). Everything crossing the interface is plain data: the
:class:`~stw_tui.sos.window.WindowProblem` (numpy arrays, scipy sparse matrices, compiled terms with
their sympy expressions) and :class:`SolverState` / :class:`StepReport`.
"""

from __future__ import annotations

import enum
import math
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from importlib import metadata
from typing import Any, Callable, ClassVar

import numpy as np

from stw_tui.sos.stopping import StepStopped
from stw_tui.sym.errors import SolveError, StwError
from stw_tui.sym.kinds import Capability, TermKind

INTERFACE_VERSION = 1
ENTRY_POINT_GROUP = "stw_tui.backends"


@dataclass(frozen=True)
class BackendOption:
    """One option a backend accepts, declared as data (CLI flags, `backend NAME k=v`, TUI panel)."""

    name: str
    type: type
    default: Any
    help: str
    choices: tuple | None = None
    minimum: float | None = None    # the smallest value allowed (numbers only)
    exclusive: bool = False         # the minimum itself is not allowed (a tolerance of 0)

    def parse(self, raw: str | Any) -> Any:
        """Convert a raw string to the option's type, with a clear error."""
        try:
            if self.type is bool and isinstance(raw, str):
                if raw.lower() not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                    raise ValueError(raw)
                value = raw.lower() in ("1", "true", "yes", "on")
            else:
                value = self.type(raw)
        except (TypeError, ValueError):
            raise StwError(f"option {self.name}: '{raw}' is not a valid {self.type.__name__}") from None
        if self.type in (int, float) and not math.isfinite(value):
            raise StwError(f"option {self.name}: '{raw}' is not a finite number")
        if self.minimum is not None and (value < self.minimum or (self.exclusive and value == self.minimum)):
            least = f"above {self.minimum:g}" if self.exclusive else f"at least {self.minimum:g}"
            raise StwError(f"option {self.name}: '{raw}' must be {least}")
        if self.choices is not None and value not in self.choices:
            raise StwError(f"option {self.name}: '{raw}' is not one of {', '.join(map(str, self.choices))}")
        return value


class Status(enum.Enum):
    """Why a run of iterations ended; the value is the message shown to the user."""

    RUNNING = "running"
    CONVERGED = "converged"
    MAX_ITERATIONS = "iteration limit reached"
    STOPPED = "stopped by the user"
    STALLED = "no further progress (line search failed)"
    INFEASIBLE = "the constraints cannot be met (no step lowers their violation)"
    FAILED = "failed"


@dataclass(frozen=True)
class SolverState:
    """Backend-neutral state carried between iterations and across `iterate` commands."""

    s: np.ndarray                    # free control point values
    lam_eq: np.ndarray               # multipliers of equality rows
    lam_ge: np.ndarray               # multipliers of inequality rows (<= 0 when active)
    working_set: np.ndarray          # bool, inequality rows treated as active
    merit_weight: float = 1.0
    regularization: float = 0.0      # proximal (Levenberg-Marquardt) weight; 0: the backend's default
    trust_radius: float = 0.0        # step limit; 0: the backend's initial one
    elastic_weight: float = 0.0      # cost of an elastic slack once elastic mode was needed; 0: not yet
    newton_refusals: int = 0         # exact-Hessian steps refused in a row (SQP, hessian=auto) ...
    newton_wait: int = 0             # ... and the iterations left before the next is tried

    @classmethod
    def start(cls, problem) -> "SolverState":
        """The state a first solve of ``problem`` starts from: its control points, zero multipliers."""
        return cls(s=problem.initial(), lam_eq=np.zeros(problem.row_counts[TermKind.EQ]),
                   lam_ge=np.zeros(problem.row_counts[TermKind.GE]),
                   working_set=np.zeros(problem.row_counts[TermKind.GE], bool))



@dataclass
class WarmStart:
    """Multipliers and working set of the last solve, reused when the next problem has the same rows."""

    signature: tuple
    state: SolverState

@dataclass(frozen=True)
class StepReport:
    """What one iteration did (one row of the iteration table)."""

    iteration: int
    objective: float
    max_violation: float
    kkt_residual: float
    step_length: float
    linear_iterations: int
    active: int
    ms: dict[str, float] = field(default_factory=dict)
    converged: bool = False
    stalled: bool = False
    message: str = ""                # a sentence for the user (e.g. which constraints conflict)
    fallbacks: int = 0               # iterative KKT solves replaced by a factorization
    qp_capped: int = 0               # QP solves that stopped at their iteration limit unconverged
    elastic: bool = False            # the step came from the elastic QP (linearization inconsistent)
    infeasible: bool = False         # the constraints were found in conflict (status INFEASIBLE)
    conflicts: tuple[str, ...] = ()  # names of the constraints in conflict, when infeasible
    coefficients: np.ndarray | None = field(default=None, repr=False)  # all DOF control points after
    # this iteration, so front ends can redraw curves while a solve runs (the driver sets them
    # from the state when the backend did not: problem.scatter(state.s))

    @property
    def total_ms(self) -> float:
        """The iteration's time over all its phases, in ms."""
        return sum(self.ms.values())


class Backend(ABC):
    """Base class of solver backends.

    Subclasses set ``name``, optionally ``options`` and ``capabilities``, and implement
    :meth:`init` and :meth:`step`. They need know nothing of the UI.
    """

    name: ClassVar[str]
    interface_version: ClassVar[int] = INTERFACE_VERSION
    options: ClassVar[tuple[BackendOption, ...]] = ()
    capabilities: ClassVar[frozenset[Capability]] = frozenset()
    # True: each call returns after a bounded amount of work (one iteration), so a stop is
    # honoured at the next iteration boundary and there is nothing to abandon: run_iterations
    # runs the loop on the caller's thread (the shared SQP). False: on a thread of its own.
    bounded_calls: ClassVar[bool] = False

    def __init__(self, **options: Any):
        known = {o.name: o for o in self.options}
        unknown = sorted(set(options) - set(known))
        if unknown:
            names = ", ".join(known) or "none"
            raise StwError(f"backend {self.name} has no option {', '.join(unknown)} (options: {names})")
        self.config = {name: opt.default for name, opt in known.items()}
        self.config.update({k: known[k].parse(v) for k, v in options.items()})

    @abstractmethod
    def init(self, problem, state: SolverState, settings: dict[str, float]) -> Any:
        """Prepare to iterate on ``problem`` from ``state``; returns the backend's own state."""

    @abstractmethod
    def step(self, problem, inner: Any, iteration: int) -> tuple[Any, StepReport]:
        """Run one iteration; returns the new inner state and its report."""

    @abstractmethod
    def state(self, inner: Any) -> SolverState:
        """The backend-neutral state of ``inner`` (control points and multipliers)."""

    @classmethod
    def batch_solver(cls, size: int, options: dict[str, Any] | None = None):
        """A :class:`~stw_tui.sos.batch.BatchSolver` that solves up to ``size`` jobs at once,
        for a backend with :attr:`Capability.BATCH`; None (the default) for one without.

        Raises:
            StwError: bad ``options``, or the batch cannot run here (no device).
        """
        return None


# What a plugin may raise that must stop at the boundary: any error, and also SystemExit and
# KeyboardInterrupt raised by the plugin's own code (a stray sys.exit() must not end stw).
PLUGIN_FAULTS = (Exception, SystemExit, KeyboardInterrupt)


# --- discovery -------------------------------------------------------------------------------
_INSTALLED: dict[str, metadata.EntryPoint] | None = None   # the last scan of the entry points


def available_backends() -> dict[str, metadata.EntryPoint]:
    """Installed backends by name, without importing any of them.

    The scan reads every installed distribution's metadata (about 9 ms here, paid twice by each
    `iterate` before it was kept), so it is kept until :func:`forget_installed`, which
    :func:`load_backend` calls for a name it does not know (a plugin installed meanwhile).
    """
    global _INSTALLED
    if _INSTALLED is None:
        _INSTALLED = {ep.name: ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}
    return dict(_INSTALLED)


def forget_installed() -> None:
    """Make the next :func:`available_backends` scan the installed distributions again."""
    global _INSTALLED
    _INSTALLED = None


def load_backend(name: str) -> type[Backend]:
    """Import the backend called ``name``.

    Raises:
        StwError: unknown name (listing the installed ones), import failure, or an interface
            version this stw does not speak.
    """
    found = available_backends()
    if name not in found:
        forget_installed()
        found = available_backends()
    if name not in found:
        raise StwError(f"no backend named '{name}' (installed: {', '.join(sorted(found)) or 'none'})")
    try:
        cls = found[name].load()
    except PLUGIN_FAULTS as exc:  # a plugin's import error (even a sys.exit) must not take stw down
        raise StwError(f"backend '{name}' failed to load: {type(exc).__name__}: {exc}") from exc
    if not (isinstance(cls, type) and issubclass(cls, Backend)):
        raise StwError(f"backend '{name}' is not a stw_tui.sos.backend.Backend subclass")
    if cls.interface_version != INTERFACE_VERSION:
        raise StwError(f"backend '{name}' speaks interface {cls.interface_version}, stw speaks "
                       f"{INTERFACE_VERSION}")
    return cls


def create_backend(cls: type[Backend], options: dict[str, Any]) -> Backend:
    """An instance of backend ``cls`` with ``options`` (validated by the backend).

    Raises:
        StwError: bad options, or the plugin's constructor raised (SystemExit included).
    """
    try:
        return cls(**options)
    except StwError:
        raise
    except PLUGIN_FAULTS as exc:
        raise StwError(f"backend {getattr(cls, 'name', cls.__name__)} could not start: "
                       f"{type(exc).__name__}: {exc}") from exc


# --- the driver ------------------------------------------------------------------------------
@dataclass
class RunResult:
    """What a run of iterations ended with: its status, last state, one report per iteration."""
    status: Status
    state: SolverState
    reports: list[StepReport]
    seconds: float

    @property
    def converged(self) -> bool:
        """Whether the run ended converged."""
        return self.status is Status.CONVERGED


ITERATION_BUDGET = "iterations"   # the settings key run_iterations adds: how many iterations it may run
CANCELLED = "cancelled"           # ... and this one: a callable, True once the user asked to stop


def run_iterations(backend: Backend, problem, start: SolverState, n: int, settings: dict[str, float],
                   on_report: Callable[[StepReport], bool | None] | None = None,
                   on_state: Callable[[int, SolverState], None] | None = None) -> RunResult:
    """Run up to ``n`` iterations of ``backend`` on ``problem``.

    ``on_report`` is called after every iteration; returning False stops at that boundary. It may
    carry ``on_report.cancelled()`` (the TUI's stop flag): a backend that iterates inside one call
    (IPOPT) polls it between its own iterations, through ``settings[CANCELLED]``. A backend that
    ignores a stop for ``backend_calls.STOP_GRACE`` seconds is abandoned (stw_tui/sos/backend_calls.py).
    ``on_state(k, state)`` is called with each finite iterate, before ``on_report`` (the periodic
    checkpoint of a running solve, stw_tui/session/midsolve.py).

    The whole loop (init, the steps, the checks and both callbacks) is one call on the backend's
    thread (:class:`_Loop`): a call per iteration cost two thread hand-offs, 0.1-0.2 ms each, a
    sixth of a small solve (cat_mouse, the pendulum). The caller's thread waits meanwhile, so the
    callbacks never run beside it; once it has given up on the loop (a hung backend, Ctrl+C) the
    loop calls neither again. A backend with ``bounded_calls`` (the shared SQP) runs its loop on
    the caller's thread instead: even the one hand-off there and back cost 0.13 ms of the
    pendulum's 3.6 ms `iterate`, and its calls cannot hang.
    Raises:
        SolveError: the backend raised, produced non-finite values or hung after a stop (a
            ``HungBackend``); nothing is returned, so the caller's scene is untouched.
    """
    from stw_tui.sos.backend_calls import BackendThread, Inline

    t0 = time.perf_counter()
    cancelled = getattr(on_report, "cancelled", None) or (lambda: False)
    calls = Inline(backend.name) if backend.bounded_calls else BackendThread(backend.name, cancelled)
    loop = _Loop(backend, problem, n, on_report, on_state)
    try:
        # The budget travels with the settings: a backend that solves in one call (IPOPT) stops there.
        status, state, reports = calls.call(lambda: loop.where, loop.run, start,
                                            {**settings, ITERATION_BUDGET: n, CANCELLED: cancelled})
    except _CallbackFault as fault:   # the caller's own callback: its error, as if raised here
        raise fault.error from None
    except SolveError:
        raise
    except StwError as exc:
        raise SolveError(f"backend {backend.name}: {exc}") from exc
    except PLUGIN_FAULTS as exc:  # any bug or numerical failure inside a plugin, or its sys.exit()
        raise SolveError(f"backend {backend.name} raised {type(exc).__name__}: {exc}; "
                         "the scene is unchanged") from exc
    finally:
        loop.give_up()
        calls.close()
    return RunResult(status, replace(state), reports, time.perf_counter() - t0)


class _CallbackFault(Exception):
    """An exception raised by the caller's ``on_report`` or ``on_state`` inside the loop (not the
    backend's fault: run_iterations raises ``error`` itself)."""

    def __init__(self, error: BaseException):
        super().__init__(str(error))
        self.error = error


class _Loop:
    """run_iterations' loop, run on the backend's thread. ``where`` names what it is doing, for
    the messages of a hung or interrupted solve; after :meth:`give_up` (the caller stopped
    waiting) it calls no callback and takes no further step."""

    def __init__(self, backend: Backend, problem, n: int, on_report, on_state):
        self.backend, self.problem, self.n = backend, problem, n
        self.on_report, self.on_state = on_report, on_state
        self.where = "init"
        self._given_up = False
        self._gate = threading.Lock()   # a callback runs whole, or not once the caller gave up

    def give_up(self) -> None:
        with self._gate:
            self._given_up = True

    def _callback(self, fn, *args):
        """``fn(*args)``; _GIVEN_UP, without calling it, once the caller gave up."""
        with self._gate:
            if self._given_up:
                return _GIVEN_UP
            try:
                return fn(*args)
            except BaseException as exc:  # noqa: BLE001 - re-raised by the caller as it was
                raise _CallbackFault(exc) from exc

    def run(self, start: SolverState, settings: dict) -> tuple[Status, SolverState, list[StepReport]]:
        backend, problem = self.backend, self.problem
        inner = backend.init(problem, start, settings)
        reports: list[StepReport] = []
        status, state = Status.MAX_ITERATIONS, start
        for k in range(1, self.n + 1):
            if self._given_up:
                break
            self.where = f"iteration {k}"
            try:
                inner, report = backend.step(problem, inner, k)
            except StepStopped:   # a stop asked for during the step (the shared SQP's, stopping.py)
                status = Status.STOPPED
                break
            state = backend.state(inner)
            _check_shapes(backend.name, problem, state, k)
            if not (np.isfinite(state.s).all() and np.isfinite(report.objective)
                    and np.isfinite(report.max_violation)):
                raise SolveError(f"iteration {k} produced non-finite values (diverged); "
                                 "the scene is unchanged — try damping, a smaller window or `shake`")
            _check_kept(backend.name, state, report, k)
            if self.on_state is not None and self._callback(self.on_state, k, state) is _GIVEN_UP:
                break
            if report.coefficients is None:   # the shared SQP's steps carry them already
                report = replace(report, coefficients=problem.scatter(state.s))
            reports.append(report)
            if report.converged:
                status = Status.CONVERGED
                break
            if report.infeasible:
                status = Status.INFEASIBLE
                break
            if report.stalled:
                status = Status.STALLED
                break
            if self.on_report is not None and self._callback(self.on_report, report) is False:
                status = Status.STOPPED
                break
        if reports and status in (Status.CONVERGED, Status.STALLED, Status.INFEASIBLE) \
                and self.on_report is not None:
            self._callback(self.on_report, reports[-1])
        return status, state, reports


_GIVEN_UP = object()   # what _Loop._callback answers once the caller stopped waiting


def _refused(name: str, k: int, what: str) -> SolveError:
    return SolveError(f"iteration {k}: backend {name!r} returned {what}; the scene is unchanged")


def _check_shapes(name: str, problem, state: SolverState, k: int) -> None:
    """Raise unless ``state`` has ``problem``'s sizes: a control point or multiplier per variable
    and row (a plugin's wrong sizes failed later, far from it, as broadcasting errors)."""
    rows = getattr(problem, "row_counts", None)
    if rows is None:   # not a window problem (a test's stand-in): nothing to compare with
        return
    eq, ge = rows[TermKind.EQ], rows[TermKind.GE]
    for what, values, expected in (("control points", state.s, problem.n_free),
                                   ("equality multipliers", state.lam_eq, eq),
                                   ("inequality multipliers", state.lam_ge, ge),
                                   ("working-set flags", state.working_set, ge)):
        shape = np.shape(values)
        if shape != (expected,):
            raise _refused(name, k, f"{what} of shape {shape} where the window has {expected}")


def _check_kept(name: str, state: SolverState, report: StepReport, k: int) -> None:
    """Raise unless every number of ``state`` and ``report`` that stw keeps is finite: the
    multipliers and the rest of the state are the next solve's warm start (NaN multipliers with
    finite control points and converged=True poisoned it: 'KKT system stayed singular'), and a
    report's control points are drawn and checkpointed. (Both checks: 7 µs an iteration here.)"""
    if not (np.isfinite(state.lam_eq).all() and np.isfinite(state.lam_ge).all()):
        raise _refused(name, k, "non-finite multipliers")
    if report.coefficients is not None and not np.isfinite(report.coefficients).all():
        raise _refused(name, k, "non-finite control points in its report")
    for field_name in ("merit_weight", "regularization", "trust_radius", "elastic_weight"):
        value = getattr(state, field_name)
        if not math.isfinite(value):
            raise _refused(name, k, f"a non-finite {field_name} ({value!r}) in its state")
    kind = np.asarray(state.working_set).dtype
    if kind != bool:
        raise _refused(name, k, f"a working set of {kind}, not of booleans")
