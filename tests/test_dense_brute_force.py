"""The continuous-time check against brute force: random constraints with weights, `when`
masks, scopes and their own tolerances on random curves, each constraint's dense violation
compared with the largest violation on a grid of 200,001 times, evaluated here with numpy from
the curves' own values (scipy's BSpline), not through stw's compiler."""

import numpy as np
import pytest
from scipy.interpolate import BSpline

from conftest import run_lines
from stw_tui.session.session import Session
from stw_tui.sos.continuous import check_scene

GRID = np.linspace(0.0, 2.0, 200_001)


def curves(scene):
    return {n: BSpline(d.curve.knots, d.curve.coef, 3) for n, d in scene.dofs.items()}


@pytest.mark.parametrize("seed", range(6))
def test_the_dense_check_finds_the_worst_violation_a_fine_grid_finds(seed):
    rng = np.random.default_rng(seed)
    a, b = (float(v) for v in np.sort(rng.uniform(0, 2, 2)).round(3))
    w, c, d, lvl = (float(v) for v in (rng.uniform(0.5, 5), rng.uniform(-1, 1), rng.uniform(-0.5, 0.5),
                                         rng.uniform(-0.3, 0.3)))
    s = run_lines(Session(), f"""time 0 2 knots=7
dof x, y
constraint eq: x - {c!r}*y = 0 on [{a!r}, {b!r}] weight={w!r}
constraint ge: y*y - {d!r} >= 0 on [0, 2] when x > {lvl!r} weight=2.5
constraint tol: x + y = 0 on [{a!r}, {b!r}] dense_tol=0.5
constraint now: x - y'' = 0 @ {b!r} weight=3
""")
    for name in ("x", "y"):
        s.scene.dofs[name].curve = s.scene.dofs[name].curve.with_coef(rng.normal(size=10))
    f = curves(s.scene)
    grid = np.union1d(GRID, [a, b])                  # the scope's ends exactly
    x, y = f["x"](grid), f["y"](grid)
    inside = (grid >= a) & (grid <= b)
    brute = {
        "eq": w * np.abs(x - c * y)[inside].max(),
        "ge": 2.5 * np.where(x > lvl, np.maximum(0, d - y * y), 0).max(),   # only where x > lvl
        "tol": np.abs(x + y)[inside].max(),
        "now": 3 * abs(f["x"](b) - f["y"].derivative(2)(b)),
    }
    report = check_scene(s.scene).checks
    for name, expected in brute.items():
        found = report[name].dense
        # within what the two grids resolve (the check zooms in on each peak; measured: 5e-9
        # relative at worst over these seeds)
        assert found == pytest.approx(expected, rel=1e-6, abs=1e-9), (name, found, expected)
    assert report["tol"].tol == 0.5 and report["eq"].tol is None
    # where the condition is off, the inequality counts nothing: a level above every x
    s.execute(f"constraint ge: y*y - {d!r} >= 0 on [0, 2] when x > {float(x.max()) + 1!r} weight=2.5")
    assert check_scene(s.scene).checks["ge"].dense == 0
