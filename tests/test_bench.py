"""`stw bench` prints a row per configuration with same-run ratios (no timing assertions)."""

import argparse

import pytest

from conftest import SESSIONS
from stw_tui.session import bench
from stw_tui.sos.window import WindowProblem
from stw_tui.sym.errors import StwError


def _number(text: str) -> float:
    return float(text.rstrip("*"))


def test_bench_table_has_a_row_per_configuration(capsys):
    bench.run_bench(argparse.Namespace(sessions=[SESSIONS / "particle_jet.stw"], repeat=1))
    out = capsys.readouterr().out
    assert out.startswith("stw bench — python ")
    assert "numpy " in out.splitlines()[0] and "scipy " in out.splitlines()[0]
    assert "CPUs" in out.splitlines()[0]
    header = next(line for line in out.splitlines() if line.startswith("session "))
    assert "ratio" in header and "ms/it" in header
    rows = [line for line in out.splitlines() if line.startswith("particle_jet ")]
    configs = [" ".join(c).strip() for c in bench.configurations()]
    assert len(rows) == len(configs)                   # every installed backend loads here
    parsed = [(" ".join(row.split()[1:-16]), row.split()[-16:]) for row in rows]
    assert [config for config, _ in parsed] == configs
    assert "synthetic" not in out                      # only the named sessions
    for _, fields in parsed:
        free, inst, ineq, its, lin, fb = (int(_number(f)) for f in fields[:6])
        assert (free, inst, ineq) == (15, 4, 0)        # 12 spans + 3, the four boundary rows
        assert its >= 1 and lin >= 0 and fb >= 0
        phases = [float(p) for p in fields[7:11] if p != "-"]       # '-': a phase not reported
        ms_it, ms_conv, ratio, objective, violation = map(float, fields[6:7] + fields[11:15])
        assert ms_it > 0 and all(p >= 0 for p in phases) and ms_conv > 0 and ratio > 0
        assert abs(objective - (12 + 9.81 ** 2)) < 1e-3  # the particle's optimum, 12 + g^2
        assert violation < 1e-6
        assert int(fields[15]) == 1                    # repeat=1: one timed run
    reference = dict(parsed)["scipy solver=direct"]
    assert reference[12] == "1.00"                     # the reference's own ratio


def test_synthetic_problems_have_the_papers_arm_size_and_ten_times_it():
    small = bench.prepare("s", bench.synthetic_session(*bench.SMALL))
    problem = WindowProblem(small.setup.scene)
    assert problem.n_free == 135                       # 5 DOF x 27 control points
    assert 60 <= problem.row_counts["eq"] <= 80 and problem.row_counts["ge"] == 0
    windowed = bench.prepare("w", bench.synthetic_session(*bench.LARGE, window=True))
    assert windowed.name == "w@focus" and windowed.n == 30
    assert WindowProblem(windowed.setup.scene).n_free < 200   # only the window is free
    large = bench.synthetic_session(*bench.LARGE)
    assert "knots=264" in large and large.count("iterate") == 1


def test_split_at_first_and_last_iterate():
    text = "time 0 1\ndof x\niterate 5   # first\nwindow w [0, 0.5]\n  iterate 7\nprint x"
    assert bench.split_at_first_iterate(text) == ("time 0 1\ndof x", 5)
    assert bench.split_at_last_iterate(text) == ("time 0 1\ndof x\niterate 5   # first\nwindow w [0, 0.5]", 7)
    assert bench.split_at_last_iterate("dof x\n# iterate 3") is None


# --- the issue-10 target table (bench_targets.py) -------------------------------------------------

from stw_tui.cli import bench_targets as targets
from stw_tui.cli.bench_targets import Figure


def _figures() -> list[Figure]:
    return [Figure("arm_throw first solve: ms/it", 8.7, "ms", 4.0),            # missed
            Figure("point_mass_2d: torch / scipy per it", 1.2, "x", 1.5),     # met
            Figure("a label far longer than the label column could ever hold", 0.3, "x", 0.5),
            Figure("arm_overhand: time / ipopt", 0.4, "x", 0.5, "other optimum", counted=False),
            Figure("10k points: torch cuda / scipy", None, "x", 0.1,
                   "no CUDA device, and a note longer than the verdict column"),
            Figure("cold start: stw run arm, 1 it", 123456.0, "s", 1.0)]


def test_target_table_has_a_row_per_figure_within_80_columns():
    lines = targets.format_table(_figures())
    assert all(len(line) <= 80 for line in lines), max(lines, key=len)
    assert lines[0].split() == ["figure", "measured", "target", "verdict"]
    rows = lines[2:-1]
    assert len(rows) == len(_figures())
    assert "8.7 ms" in rows[0] and "≤ 4 ms" in rows[0]
    assert "1.20x" in rows[1] and "≤ 1.5x" in rows[1]
    assert lines[-1] == "2 of 4 judged targets met; 2 not judged"   # 8.7 ms and 123456 s miss


def test_a_missed_target_is_shown_missed_and_an_unjudged_one_says_why():
    rows = targets.format_table(_figures())[2:-1]
    verdicts = [row[targets.LABEL + targets.VALUE + targets.TARGET + 3:] for row in rows]
    assert verdicts[:4] == ["missed", "met", "met", "other optimum"]
    assert verdicts[4].startswith("no CUDA device") and verdicts[5] == "missed"
    values = [row[targets.LABEL + 1:targets.LABEL + 1 + targets.VALUE].strip() for row in rows]
    assert values[3] == "0.40x" and values[4] == "-"                # not measured: no figure
    assert Figure("x", 4.0, "ms", 4.0).verdict() == "met"            # the limit itself is met
    assert Figure("x", 4.0 + 1e-9, "ms", 4.0).verdict() == "missed"


def test_quick_mode_measures_the_quick_sessions_and_fits_80_columns(monkeypatch, capsys):
    seen = {}

    def fake_sessions(sources, repeat, out):
        seen["sessions"], seen["repeat"] = [name for name, _ in sources], repeat
        return [Figure("ball", 30.0, "ms", 20.0), Figure("acrobat: time / ipopt", 0.9, "x", 0.5)]

    monkeypatch.setattr(targets, "session_figures", fake_sessions)
    monkeypatch.setattr(targets, "arm_first_solve_figure", lambda text, repeat: Figure("arm", 3.0, "ms", 4.0))
    monkeypatch.setattr(targets, "pendulum_figures", lambda repeat, anchors: [])
    monkeypatch.setattr(targets, "large_figure", lambda repeat: Figure("5k", 0.05, "x", 0.5))
    monkeypatch.setattr(targets, "window_figure", lambda repeat: Figure("window", 1.0, "x", 1.1))
    monkeypatch.setattr(targets, "waypoint_figure", lambda: Figure("waypoints", 2.0, "", 2.0))
    monkeypatch.setattr(targets, "cold_start_figures", lambda text, repeat: [])
    monkeypatch.setattr(targets, "gpu_figure", lambda: Figure("gpu", None, "x", 0.1, "no CUDA device"))
    figures = targets.run_targets(quick=True, anchors=False, repeat=5)
    out = capsys.readouterr().out
    assert seen == {"sessions": list(targets.QUICK_SESSIONS), "repeat": targets.QUICK_REPEAT}
    assert targets._budget == targets.QUICK_BUDGET   # a few-ms solve is timed several times
    assert {p.stem for p in bench.bundled_sessions()} >= set(targets.QUICK_SESSIONS)
    assert "basketball" in targets.QUICK_SESSIONS                      # its whole solve, as in full
    assert [f.label for f in figures] == ["arm", "ball", "acrobat: time / ipopt", "5k", "window", "waypoints", "gpu"]
    assert all(len(line) <= 80 for line in out.splitlines())
    table = out[out.index("figure "):].splitlines()
    assert next(r for r in table if r.startswith("acrobat")).endswith("missed")
    assert next(r for r in table if r.startswith("ball")).endswith("missed")
    assert next(r for r in table if r.startswith("arm ")).endswith("met")
    assert "4 of 6 judged targets met; 1 not judged" in out


def test_slsqp_in_numpy_reaches_stws_pendulum_optimum():
    # two independent derivations of the same problem: stw's compiled terms and SQP, and the
    # objective and gradient written by hand in numpy (SLSQP); the optimum must agree
    case = bench.prepare("pendulum", targets.PENDULUM)
    _, objective = targets.slsqp_solve(case.setup.scene.copy())
    case.setup.execute("iterate 50")
    assert case.setup.runs[-1].converged
    stw = case.setup.runs[-1].reports[-1].objective
    assert abs(objective - stw) <= 1e-6 * stw


@pytest.mark.parametrize("spans", [20, 80])
def test_casadi_ipopt_written_apart_reaches_stws_pendulum_optimum(spans):
    """The bench's native IPOPT anchor states the swing-up in CasADi from scipy's B-spline, nothing
    of stw's: the optimum must be stw's on the same mesh (both solved to their tolerances)."""
    pytest.importorskip("casadi")
    case = bench.prepare("pendulum", targets.PENDULUM.replace("knots=20", f"knots={spans}"))
    scene = case.setup.scene
    _, objective = targets.native_ipopt_pendulum(spans, int(scene.settings["quadrature"]),
                                                 float(scene.constants["g"]))()
    case.setup.execute("iterate 50")
    assert case.setup.runs[-1].converged
    assert objective == pytest.approx(case.setup.runs[-1].reports[-1].objective, rel=1e-7)


def test_pendulum_references_each_alternate_with_stws_runs_of_their_own(monkeypatch):
    # A solve is slowed down by the one before it (SLSQP by 1.9x right after FDDP's): the SLSQP
    # figure's runs, and the stw runs set against them, must never follow an FDDP solve.
    import sys
    import types

    monkeypatch.setitem(sys.modules, "crocoddyl", types.ModuleType("crocoddyl"))
    order = []
    case = bench.prepare("pendulum", targets.PENDULUM)
    monkeypatch.setattr(targets, "prepare", lambda name, text: case)
    monkeypatch.setattr(targets, "slsqp_solve", lambda scene: order.append("SLSQP") or (0.004, 65.48090953))
    monkeypatch.setattr(targets, "fddp_solve", lambda g: order.append("FDDP") or (0.05, 65.4809))
    monkeypatch.setattr(targets, "native_ipopt_pendulum",
                        lambda spans, quadrature, g: lambda: order.append(f"IPOPT{spans}") or (0.003, 65.48090953))
    calls = []

    def fake_measure(case, configs, repeat, between=None, setups=None):
        calls.append(len(order))
        for _ in range(repeat):
            order.append(f"stw{len(calls)}")
            between()
        return [bench.Measurement(session="pendulum", config="scipy", free=23, instances=4, iterations=8,
                                  converged=True, ms_per_iteration=0.5, phases={}, seconds=0.006,
                                  objective=65.48090953, violation=0.0)]
    monkeypatch.setattr(targets, "_measure_together", fake_measure)

    figures = targets.pendulum_figures(3, anchors=True)
    assert [f.label for f in figures] == ["pendulum: time / SLSQP", "pendulum: time / FDDP",
                                          "pendulum 20: time / IPOPT", "pendulum 80: time / IPOPT"]
    assert figures[0].value == pytest.approx(0.006 / 0.004) and figures[0].counted
    assert figures[2].value == pytest.approx(0.006 / 0.003) and figures[2].counted
    pairs = list(zip(order, order[1:]))
    assert ("FDDP", "SLSQP") not in pairs and ("FDDP", "stw1") not in pairs
    assert order.count("stw1") == order.count("stw2") == order.count("stw3") == 3
    last_slsqp_side = max(i for i, what in enumerate(order) if what in ("SLSQP", "stw1"))
    assert last_slsqp_side < order.index("FDDP")          # no FDDP solve among SLSQP's rounds


def test_without_crocoddyl_the_fddp_figure_says_so(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "crocoddyl", None)    # an import of it fails
    def no_ipopt(name):   # as when the ipopt extra (casadi) is not installed
        raise StwError(f"backend '{name}' failed to load: ModuleNotFoundError: No module named 'casadi'")
    monkeypatch.setattr(targets, "load_backend", no_ipopt)
    case = bench.prepare("pendulum", targets.PENDULUM)
    monkeypatch.setattr(targets, "prepare", lambda name, text: case)
    figures = targets.pendulum_figures(3, anchors=True)
    assert [f.label for f in figures] == ["pendulum: time / SLSQP", "pendulum: time / FDDP",
                                          "pendulum 20: time / IPOPT", "pendulum 80: time / IPOPT"]
    assert figures[0].value is not None and figures[0].counted
    assert figures[1].value is None and figures[1].verdict() == "crocoddyl missing"
    assert all(f.value is None and f.verdict() == "casadi missing" for f in figures[2:])


def test_crocoddyls_fddp_reaches_the_pendulums_optimum_within_the_anchor_accuracy():
    # a third derivation (pinocchio's dynamics, RK4 steps, FDDP): only with the anchors extra
    pytest.importorskip("crocoddyl")
    case = bench.prepare("pendulum", targets.PENDULUM)
    _, fddp = targets.fddp_solve(float(case.setup.scene.constants["g"]))
    case.setup.execute("iterate 50")
    stw = case.setup.runs[-1].reports[-1].objective
    assert abs(fddp - stw) <= targets.ANCHOR_ACCURACY * stw


def test_the_window_is_the_same_in_the_10_and_100_second_animations():
    sizes = []
    for span in (10, 100):
        case = bench.prepare(f"w{span}", targets.window_session(span))
        assert case.name == f"w{span}@focus"
        problem = WindowProblem(case.setup.scene)
        sizes.append((problem.n_free, problem.row_counts["eq"]))
    assert sizes[0] == sizes[1] and sizes[0][0] > 0


def test_stw_bench_prints_the_targets_unless_sessions_or_detail_are_asked(monkeypatch):
    calls = []
    monkeypatch.setattr(targets, "run_targets", lambda quick, anchors, repeat: calls.append(
        ("targets", quick, anchors, repeat)))
    monkeypatch.setattr(bench, "run_bench", lambda args: calls.append(("detail",)) or 0)
    from stw_tui.cli.main import build_parser

    for argv in (["bench", "--quick"], ["bench", "--anchors", "--repeat", "2"], ["bench", "--detail"],
                 ["bench", "--wide"], ["bench", "--sessions", "x.stw"]):
        args = build_parser().parse_args(argv)
        assert args.func(args) == 0
    assert calls == [("targets", True, False, 3), ("targets", False, True, 2), ("detail",), ("detail",), ("detail",)]


def test_waypoints_that_differ_only_in_their_number_compile_one_term_between_them():
    # The figure counts real compiles (caches off): the 200 waypoint constraints share one
    # skeleton, and the objective is the other. Made to compile each on its own, they count ~200.
    figure = targets.waypoint_figure()
    assert figure.value == 2.0 and figure.verdict() == "met"
    assert targets.format_figure(figure).split()[-4:] == ["2", "≤", "2", "met"]


def test_configurations_measured_together_may_each_solve_their_own_scene():
    small = bench.prepare("s", bench.synthetic_session(1, 4))
    larger = bench.prepare("l", bench.synthetic_session(2, 8))
    got = bench.measure_together("both", small.setup, [("scipy", "solver=direct", 2)] * 2, 1,
                                 setups=[small.setup, larger.setup])
    want = [WindowProblem(c.setup.scene).n_free for c in (small, larger)]
    assert [m.free for m in got] == want and want[0] < want[1]


def test_the_large_figures_problem_converges_to_one_optimum_with_scipy_and_ipopt():
    # What makes "5k points: time/ipopt" count: both solvers converge, to the same objective.
    # (At the session start scipy stopped at its iteration limit here: the KKT regularization.)
    pytest.importorskip("casadi")
    text = bench.synthetic_session(5, targets.LARGE_KNOTS).replace("iterate", "set adaptive off\niterate")
    case = bench.prepare("synthetic-5k", text)
    found = {}
    for config, n in (("scipy solver=direct", case.n), ("ipopt", targets.IPOPT_ITERATIONS)):
        session = bench._fresh(case.setup, config)
        session.execute(f"iterate {n}")
        run = session.runs[-1]
        assert run.converged, config
        found[config] = run.reports[-1].objective
    scipy, ipopt = found.values()
    assert abs(scipy - ipopt) <= targets.SAME_OPTIMUM * abs(ipopt)
