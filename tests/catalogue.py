"""The test catalogue: problems (every bundled session, plus small ones with known answers) and
the installed backends, for any test to parametrize over (the shape of optimistix's
tests/helpers.py). Fixtures over it live in conftest.py: ``any_problem``, ``any_backend`` and
``registered``.

A problem is session text. ``setup()`` runs it up to its first `iterate` (the starting scene a
solver sees), ``run()`` runs all of it.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SESSIONS = ROOT / "sessions"


@dataclass(frozen=True)
class Problem:
    """One scene to solve, as session text, and what is known about its answer."""

    name: str
    text: str
    path: Path | None = None   # the session file of a bundled problem
    known: str = ""            # the analytic answer, or what the session is for

    def __str__(self) -> str:   # the test id
        return self.name

    def before_first_iterate(self) -> str:
        """The lines before the first `iterate` (all of them when there is none)."""
        from stw_tui.sym.language import classify_line

        lines = self.text.splitlines()
        cut = next((i for i, line in enumerate(lines) if classify_line(line).verb == "iterate"), len(lines))
        return "\n".join(lines[:cut]) + "\n"

    def setup(self, prefix: str = ""):
        """A session that ran ``prefix`` and then the problem up to its first `iterate`."""
        from stw_tui.session.session import Session

        session = Session()
        session.run_text(prefix + self.before_first_iterate())
        return session

    def run(self, prefix: str = "", then: str = ""):
        """A session that ran ``prefix``, the whole problem, and ``then``."""
        from stw_tui.session.session import Session

        session = Session()
        session.run_text(prefix + self.text + then)
        return session


BUNDLED = {path.stem: Problem(path.stem, path.read_text(encoding="utf-8"), path, "a bundled session")
           for path in sorted(SESSIONS.glob("*.stw"))}
# Bundled sessions that solve in a few seconds: the default for tests that run whole sessions.
QUICK = ("particle_jet", "point_mass_2d", "cat_mouse")

# Small problems with known answers. They hold no `iterate`: tests add the solve they need.
ANALYTIC = {p.name: p for p in (
    Problem("analytic_particle", """time 0 1 knots=12
const m = 1, g = 9.81
dof x
let f = m*x'' + m*g
constraint start: x = 0, x' = 0 @ 0
constraint end:   x = 1, x' = 0 @ 1
objective fuel: f
""", known="Euler-Lagrange of ∫(m x'' + m g)² gives x'''' = 0: x = 3t² - 2t³, in the spline space"),
    Problem("analytic_point_mass", """time 0 2 knots=16 samples=32
const m = 1, g = 9.81
dof x, y = 0.5
let fy = m*y'' + m*g
constraint start: x = 0, y = 0.5, x' = 1, y' = -3 @ 0
constraint goal:  x = 2, y = 0.5, x' = 0, y' = 0 @ 2
objective thrust: x'', fy
""", known="x'''' = 0 and y'''' = 0: a cubic per axis through the boundary conditions"),
    Problem("analytic_arm2", """time 0 1 knots=8
const g = 9.81
linkage arm base=fixed
  SHOULDER revolute a=0.35 mass=2.0
  ELBOW    revolute a=0.30 mass=1.5
end
""", known="all angles 0: the tip at x = 0.65, shoulder torque g (2·0.175 + 1.5·0.5)"),
    Problem("analytic_double_integrator", """time 0 1 knots=10 samples=240
dof x
constraint start: x = 0, x' = 1 @ 0
constraint end:   x = 0, x' = -1 @ 1
constraint bound: x <= 1/9 on [0, 1]
objective effort: x'' weight=0.5
""", known="Bryson & Ho's state-constrained double integrator: with l = 1/9 the optimal ∫½u² is "
           "4/(9l) = 4, the bound active on [3l, 1 - 3l] = [1/3, 2/3]"),
    Problem("analytic_pendulum_swing_up", """time 0 2.5 knots=10
const g = 9.81
dof th
let u = th'' + g*sin(th)
constraint start: th = 0, th' = 0 @ 0
constraint top: th = pi, th' = 0 @ 2.5
objective effort: u
""", known="a torque-limited swing-up has more than one local optimum: straight up, or pumping back first"),
    Problem("analytic_landing", """time 0 1 knots=8
const g = 9.81
dof x, y
constraint start: x = 0, y = 0, x' = 1, y' = 3 @ 0
constraint land: x^2 + y^2 = 1 @ 1
objective fuel: y'' + g, x''
""", known="a thrown point mass that lands on the unit circle at t = 1 with least thrust"),
    Problem("analytic_arm3", """time 0 1.5 knots=24 samples=24
const g = 9.81
linkage arm base=fixed
  SHOULDER revolute a=0.35 mass=2.0
  ELBOW    revolute a=0.30 mass=1.5
  WRIST    revolute a=0.15 mass=0.5
end
""", known="all angles 0: the tip at x = 0.8"),
)}

PROBLEMS = {**BUNDLED, **ANALYTIC}
# Bundled sessions whose first run compiles for minutes (the jumper's tree of seven links: about
# two): the tests that take every problem on every backend leave them out, and each has a test
# of its own (test_jumper.py).
HEAVY = ("jumper",)


def problem(name: str) -> Problem:
    """The problem called ``name`` (a bundled session's stem, or ``analytic_…``)."""
    return PROBLEMS[name]


def problems(*names: str) -> list[Problem]:
    """The named problems, in order; every problem but the HEAVY ones when none is named."""
    return [PROBLEMS[n] for n in names] if names else [p for n, p in PROBLEMS.items() if n not in HEAVY]


# In-tree backends, by name: the entry point and the library they need. Tests register them
# (the ``registered`` fixture) so they run whether or not the distribution's entry points are
# installed yet; a backend whose library is missing is not offered.
IN_TREE = {"scipy": ("stw_scipy:ScipyBackend", "scipy"),
           "torch": ("stw_torch:TorchBackend", "torch"),
           "ipopt": ("stw_ipopt:IpoptBackend", "casadi")}
# The `backend` line a test uses for each (torch on the CPU: the same numbers on every machine).
BACKEND_LINES = {"scipy": "backend scipy", "torch": "backend torch device=cpu", "ipopt": "backend ipopt"}


def installed_backends() -> list[str]:
    """The in-tree backends whose library is installed, scipy first."""
    return [name for name, (_, library) in IN_TREE.items() if importlib.util.find_spec(library) is not None]


def backend_package(module: str):
    """Import an in-tree backend package (``stw_torch`` …), from the checkout when the
    distribution installed on this machine predates it."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError:
        sys.path.insert(0, str(ROOT / "backends"))
        return importlib.import_module(module)


def linear_algebras() -> list:
    """The SQP's linear algebras, to run the shared QP on each: SciPy's sparse one, its dense
    numpy one (small windows), and torch's dense one where torch is installed."""
    from stw_scipy.dense import NumpyDenseAlgebra
    from stw_scipy.linear import SparseAlgebra

    found = [SparseAlgebra(), NumpyDenseAlgebra()]
    try:
        import torch
        from stw_torch.linalg import DenseAlgebra
    except ModuleNotFoundError:
        return found
    return found + [DenseAlgebra(torch.device("cpu"))]
