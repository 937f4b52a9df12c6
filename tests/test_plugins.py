"""Third-party backends: discovered through entry points without touching stw."""

import os
import subprocess
import sys
import textwrap

import pytest

PLUGIN = textwrap.dedent('''
    """A tiny out-of-tree backend: steepest descent on the objective, no constraints."""
    import numpy as np
    from stw_tui.sos.backend import Backend, BackendOption, SolverState, StepReport

    class Descent(Backend):
        """Gradient descent (a third party's toy)."""
        name = "descent"
        options = (BackendOption("rate", float, 0.1, "step size"),)

        def init(self, problem, state, settings):
            return state

        def step(self, problem, state, iteration):
            ev = problem.evaluate(state.s)
            s = state.s - self.config["rate"] * ev.gradient
            new = SolverState(s, state.lam_eq, state.lam_ge, state.working_set)
            return new, StepReport(iteration, ev.objective, ev.max_violation(), 0.0, 1.0, 0, 0)

        def state(self, inner):
            return inner
''')

BATCHING = textwrap.dedent('''
    """A third party's backend that solves batches: scipy's SQP, a batch being its jobs in turn."""
    from stw_scipy.sqp import ScipyBackend
    from stw_tui.sos.backend import Capability
    from stw_tui.sos.batch import BatchSolver

    class InTurn(BatchSolver):
        def __init__(self, size):
            self.size = size

        def describe(self):
            return f"herd batch of up to {self.size}"

        def run(self, jobs, on_done, cancelled):
            for index, job in enumerate(jobs):
                if cancelled():
                    return
                on_done(index, job())

    class Herd(ScipyBackend):
        name = "herd"
        capabilities = ScipyBackend.capabilities | {Capability.BATCH}

        @classmethod
        def batch_solver(cls, size, options=None):
            cls(**(options or {}))
            return InTurn(size)
''')

BROKEN = "raise ImportError('this plugin needs a library that is not installed')\n"


def _install(tmp_path):
    """A real distribution on the path: a module plus its .dist-info with entry points."""
    (tmp_path / "stw_descent.py").write_text(PLUGIN)
    (tmp_path / "stw_broken.py").write_text(BROKEN)
    (tmp_path / "stw_herd.py").write_text(BATCHING)
    info = tmp_path / "stw_descent-0.3.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: stw-descent\nVersion: 0.3\n")
    (info / "entry_points.txt").write_text(
        "[stw_tui.backends]\ndescent = stw_descent:Descent\nbroken = stw_broken:Nothing\nherd = stw_herd:Herd\n")
    env = dict(os.environ, PYTHONPATH=str(tmp_path) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return env


def test_an_installed_third_party_backend_is_listed_and_used(tmp_path):
    env = _install(tmp_path)
    listing = subprocess.run([sys.executable, "-m", "stw_tui.cli.main", "backends"], env=env,
                             capture_output=True, text=True, check=True).stdout
    assert "descent" in listing and "0.3" in listing and "rate=0.1" in listing
    assert "broken" in listing and "unavailable" in listing and "not installed" in listing  # reported, skipped
    code = ("from stw_tui.session.session import Session\n"
            "s = Session()\n"
            "s.run_text('dof x\\nobjective o: x - 1\\nbackend descent rate=4\\niterate 200')\n"
            "print(s.scene.dofs['x'].curve.evaluate([0.5])[0])\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert abs(float(out.stdout) - 1.0) < 1e-3     # descent on ∫(x-1)² approaches x = 1 (from 0)


def test_a_batch_runs_on_a_backend_found_by_its_capability_not_its_name(tmp_path):
    """`set scheduler batch` on a scipy scene: the first installed backend that declares batches
    (herd sorts before torch; broken fails to load and is passed over) solves the survey."""
    env = _install(tmp_path)
    code = ("from stw_tui.session.session import Session\n"
            "s = Session()\n"
            "s.run_text('time 0 1 knots=6\\ndof x\\nconstraint c: x = 1 @ 1\\nobjective o: x\\'\\'')\n"
            "print(s.execute('set scheduler batch').message)\n"
            "s.execute('survey 3 seed=1')\n"
            "print(s.survey.engine, len(s.survey.results))\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    lines = out.stdout.splitlines()
    assert lines[0] == "surveys solve their starts as one batch on the herd backend, in this process"
    assert lines[1] == "herd batch of up to 64 3"


def test_listing_backends_imports_none_of_them(tmp_path):
    env = _install(tmp_path)
    code = ("import sys\nfrom stw_tui.sos.backend import available_backends\n"
            "names = sorted(available_backends())\n"
            "print(names, [m for m in ('stw_descent', 'stw_broken', 'stw_torch', 'torch') if m in sys.modules])\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert "'descent'" in out.stdout and out.stdout.strip().endswith("[]")


def test_installed_backends_declare_capabilities_as_the_enum():
    """Capabilities are Capability members, not bare strings (the interpreter reads them)."""
    from stw_tui.sos.backend import Capability, available_backends, load_backend

    for name in available_backends():
        declared = load_backend(name).capabilities
        assert declared and all(isinstance(c, Capability) for c in declared), name


@pytest.mark.parametrize("line, message", [
    ("backend ipopt tol=0", "option tol: '0' must be above 0"),
    ("backend ipopt tol=-1e-8", "must be above 0"),
    ("backend ipopt max_iter=0", "option max_iter: '0' must be at least 1"),
    ("backend scipy lin_tol=nan", "is not a finite number"),
    ("backend scipy trust=-0.5", "option trust: '-0.5' must be at least 0"),
    ("backend scipy trust=inf", "is not a finite number"),
])
def test_backend_options_out_of_range_are_refused_and_change_nothing(line, message):
    pytest.importorskip("casadi")
    from stw_tui.session.session import Session
    from stw_tui.sym.errors import StwError

    s = Session()
    s.run_text("time 0 1 knots=8\ndof x\nbackend scipy lin_tol=1e-10\n")
    with pytest.raises(StwError, match=message):
        s.execute(line)
    assert (s.scene.backend, s.scene.backend_options) == ("scipy", {"lin_tol": "1e-10"})


def test_a_batch_solver_that_fails_to_start_is_a_message_not_a_crash():
    from stw_tui.sos.backend import Backend
    from stw_tui.sos.batch import create_batch_solver
    from stw_tui.sym.errors import StwError

    class Faulty(Backend):
        name = "faulty"

        @classmethod
        def batch_solver(cls, size, options=None):
            raise SystemExit("a plugin's stray exit")

    class Declines(Faulty):
        name = "declines"
        batch_solver = Backend.batch_solver      # the default: None, no batches

    with pytest.raises(StwError, match="backend faulty could not start a batch: SystemExit: a plugin's stray exit"):
        create_batch_solver(Faulty, 4, {})
    with pytest.raises(StwError, match="backend declines cannot solve a batch"):
        create_batch_solver(Declines, 4, {})


def test_a_backend_that_hands_back_nan_multipliers_is_refused_and_the_start_is_kept():
    """Finite control points and converged=True, but NaN multipliers: they would be the next
    solve's warm start (issue 54: it poisoned it, 'KKT system stayed singular')."""
    import catalogue
    import numpy as np
    from stw_tui.sos.backend import Backend, SolverState, StepReport, run_iterations
    from stw_tui.sos.window import WindowProblem
    from stw_tui.sym.errors import SolveError

    class Poisoned(Backend):
        name = "poisoned"

        def init(self, problem, state, settings):
            return state

        def step(self, problem, state, iteration):
            ev = problem.evaluate(state.s)
            new = SolverState(state.s, np.full_like(state.lam_eq, np.nan), state.lam_ge, state.working_set)
            return new, StepReport(iteration, ev.objective, ev.max_violation(), 0.0, 1.0, 0, 0, converged=True)

        def state(self, inner):
            return inner

    session = catalogue.problem("particle_jet").setup()
    problem = WindowProblem(session.scene)
    start = SolverState.start(problem)
    with pytest.raises(SolveError, match="returned non-finite multipliers"):
        run_iterations(Poisoned(), problem, start, 3, session.scene.settings)
    assert np.isfinite(start.lam_eq).all()


def _liar(corrupt):
    """A plugin backend that takes one gradient step, says converged=True and hands back what
    ``corrupt(state, coefficients)`` makes of its state and its report's control points."""
    import numpy as np
    from stw_tui.sos.backend import Backend, SolverState, StepReport

    class Liar(Backend):
        name = "liar"

        def init(self, problem, state, settings):
            return state

        def step(self, problem, state, iteration):
            ev = problem.evaluate(state.s)
            s = state.s - 1e-3 * ev.gradient
            new, coefficients = corrupt(SolverState(s, state.lam_eq, state.lam_ge, state.working_set),
                                        problem.scatter(s))
            return new, StepReport(iteration, ev.objective, ev.max_violation(), 0.0, 1.0, 0, 0, converged=True,
                                   coefficients=np.asarray(coefficients, float))

        def state(self, inner):
            return inner

    return Liar


def _nan(values):
    import numpy as np

    return np.full(np.shape(values), np.nan)


LIES = {   # what the plugin corrupts -> what the refusal says
    "NaN equality multipliers": (lambda st, c: (replace(st, lam_eq=_nan(st.lam_eq)), c), "non-finite multipliers"),
    "a multiplier too few": (lambda st, c: (replace(st, lam_eq=st.lam_eq[:-1]), c),
                             r"equality multipliers of shape \(\d+,\) where the window has \d+"),
    "a control point too many": (lambda st, c: (replace(st, s=list(st.s) + [0.0]), c),
                                 r"control points of shape \(\d+,\) where the window has \d+"),
    "an inequality multiplier where there is no inequality":
        (lambda st, c: (replace(st, lam_ge=[0.0], working_set=[False]), c),
         r"inequality multipliers of shape \(1,\) where the window has 0"),
    "a NaN merit weight": (lambda st, c: (replace(st, merit_weight=float("nan")), c),
                           r"a non-finite merit_weight \(nan\) in its state"),
    "an infinite trust radius": (lambda st, c: (replace(st, trust_radius=float("inf")), c),
                                 r"a non-finite trust_radius \(inf\) in its state"),
    "a working set of numbers": (lambda st, c: (replace(st, working_set=st.working_set.astype(float)), c),
                                 "a working set of float64, not of booleans"),
    "NaN control points in its report": (lambda st, c: (st, _nan(c)), "non-finite control points in its report"),
}


def replace(state, **changes):
    import dataclasses

    return dataclasses.replace(state, **changes)


@pytest.mark.parametrize("lie", list(LIES))
def test_a_backend_handing_back_bad_numbers_is_refused_and_the_scene_kept(monkeypatch, registered, lie):
    """Issue 54 item 8: every number a backend hands back is checked before it is kept. Finite
    control points with NaN multipliers and converged=True used to be accepted, and the next
    solve (the built-in SQP, warm-started from them) failed: 'KKT system stayed singular'; the
    wrong sizes failed later as broadcasting errors. Each is refused with the backend's name,
    the scene and the warm start stay as they were, and the next solve converges."""
    import catalogue
    import numpy as np
    import stw_tui.sos.backend as backend
    from test_guards import _Entry
    from stw_tui.sym.errors import StwError

    corrupt, message = LIES[lie]
    installed = {**backend.available_backends(), "liar": _Entry(lambda: _liar(corrupt))}
    monkeypatch.setattr(backend, "available_backends", lambda: installed)
    session = catalogue.problem("particle_jet").setup()
    session.execute("iterate 2")                     # a warm start to keep
    session.execute("backend liar")
    scene, coefficients, warm = session.scene, session.scene.coefficient_vector().copy(), session.warm
    assert warm is not None
    with pytest.raises(StwError, match=rf"iteration 1: backend 'liar' returned {message}; the scene is unchanged"):
        session.execute("iterate 3")
    assert session.scene is scene
    assert session.warm.signature == warm.signature
    for name in ("s", "lam_eq", "lam_ge", "working_set", "merit_weight", "trust_radius"):
        np.testing.assert_array_equal(getattr(session.warm.state, name), getattr(warm.state, name))
    np.testing.assert_array_equal(session.scene.coefficient_vector(), coefficients)
    session.execute("backend scipy")
    outcome = session.execute("iterate 30")
    assert outcome.run.converged, outcome.message
