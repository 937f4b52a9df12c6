"""`stw bench` prints a row per configuration with same-run ratios (no timing assertions)."""

import argparse

from conftest import SESSIONS
from stw_tui import bench
from stw_tui.window import WindowProblem


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
