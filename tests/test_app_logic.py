"""The TUI's plain logic, without a screen: completion, history, the session script, plot data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stw_tui.app.completion import History, candidates, complete, path_candidates
from stw_tui.app.messages import Job
from stw_tui.app.runner import Script
from stw_tui.session.queries import dof_series, equation_series, equation_violations, figure_bounds, scene_info
from stw_tui.session.session import Session

SESSIONS = Path(__file__).resolve().parent.parent / "sessions"


@pytest.fixture(scope="module")
def jet() -> Session:
    session = Session()
    session.run_file(SESSIONS / "particle_jet.stw")
    return session


def test_completion_of_commands_names_settings_and_backends(jet):
    scene = jet.scene
    assert complete("ite", scene) == ("iterate ", [])
    assert complete("print f", scene) == ("print f", ["f", "fuel"])
    assert complete("weight st", scene) == ("weight start ", [])
    assert complete("set tol_k", scene) == ("set tol_kkt ", [])
    assert complete("backend sc", scene, ["scipy", "torch"]) == ("backend scipy ", [])
    assert complete("help lin", scene) == ("help linkage ", [])
    assert complete("print x +", scene) == ("print x +", [])       # nothing to complete after +
    assert candidates("use ", scene)[1] == sorted(["all", "end", "f", "fuel", "g", "m", "pi", "start", "t", "x"])
    assert complete("d", None)[1] == ["damp", "delete", "diff", "dof"]      # before the core has loaded


def test_completion_offers_verb_groups_once():
    s = Session()
    s.run_text("time 0 1 knots=8\nconst g = 9.81\nlinkage hop base=tx:X,ty:Y\n  LEG revolute a=1 mass=1\n"
               "end\ncontact hop.LEG on ground on [0, 0.5] x=0\nflight hop on [0.5, 1]\n")
    # LEG_contact's parts have other names; hop_flight is both a group and one of its parts.
    assert candidates("delete LEG_", s.scene)[1] == ["LEG_contact", "LEG_friction", "LEG_liftoff", "LEG_pressure",
                                                     "LEG_push"]
    assert candidates("delete hop_", s.scene)[1] == ["hop_flight", "hop_spin"]


@pytest.fixture
def files(tmp_path, monkeypatch):
    """A current directory with sessions, exports, a directory, a hidden file and a name with a space."""
    for name in ("jump.stw", "jump.csv", "jumper.json", "notes.txt", ".hidden.stw", "two words.stw"):
        (tmp_path / name).write_text("")
    (tmp_path / "jumps").mkdir()
    (tmp_path / "jumps" / "high.stw").write_text("")
    (tmp_path / "jumps" / "long.stw").write_text("")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_path_candidates_list_stw_files_first_and_directories_with_a_slash(files):
    assert path_candidates("jump") == ["jump.stw", "jump.csv", "jumper.json", "jumps/"]
    assert path_candidates("jump", suffix=".csv") == ["jump.csv", "jump.stw", "jumper.json", "jumps/"]
    assert path_candidates("jumps/") == ["jumps/high.stw", "jumps/long.stw"]
    assert path_candidates("jumps/l") == ["jumps/long.stw"]
    assert path_candidates("n") == ["notes.txt"]
    assert path_candidates(".h") == [".hidden.stw"]            # hidden only when asked for
    assert ".hidden.stw" not in path_candidates("")
    assert path_candidates("t") == ['"two words.stw']           # a space: quoted
    assert path_candidates("nothing/") == [] and path_candidates("zzz") == []
    assert path_candidates("high", cwd=files / "jumps") == ["high.stw"]


def test_path_candidates_expand_the_home_directory_and_keep_the_tilde(files, monkeypatch):
    monkeypatch.setenv("HOME", str(files / "jumps"))
    assert path_candidates("~") == ["~/"]
    assert path_candidates("~/h") == ["~/high.stw"]
    assert path_candidates(str(files / "jumps") + "/lo") == [str(files / "jumps") + "/long.stw"]


def test_tab_completes_paths_after_open_save_and_export(files, jet):
    scene = jet.scene
    assert complete("open jumps/h", scene) == ("open jumps/high.stw ", [])
    assert complete("save jumps/l", scene) == ("save jumps/long.stw ", [])
    assert complete("save --journal jumps/l", scene) == ("save --journal jumps/long.stw ", [])
    assert complete("open jumps", scene) == ("open jumps/", [])       # a directory: no space, Tab again
    assert complete("open jumps/", scene) == ("open jumps/", ["high.stw", "long.stw"])
    assert complete("open ju", scene) == ("open jump", ["jump.stw", "jump.csv", "jumper.json", "jumps/"])
    assert complete("export cs", scene) == ("export csv ", [])
    assert complete("export ", scene) == ("export ", ["csv", "json", "bvh"])
    assert complete("export csv jump.", scene) == ("export csv jump.", ["jump.csv", "jump.stw"])
    assert complete("export json jumpe", scene) == ("export json jumper.json ", [])
    assert complete("open t", scene) == ('open "two words.stw" ', [])
    assert complete('open "two', scene) == ('open "two words.stw" ', [])
    assert complete("print f", scene) == ("print f", ["f", "fuel"])      # not a path: names as before
    assert complete("export csv out.csv fps", scene) == ("export csv out.csv fps", [])


def test_history_browses_back_and_keeps_the_draft():
    history = History()
    for line in ("dof x", "dof x", "iterate 5"):
        history.add(line)
    assert history.lines == ["dof x", "iterate 5"]
    assert history.previous("typing") == "iterate 5"
    assert history.previous("iterate 5") == "dof x"
    assert history.previous("dof x") == "dof x"          # stays at the oldest
    assert history.next() == "iterate 5"
    assert history.next() == "typing"                      # back to the draft


def test_script_skips_comments_and_numbers_lines():
    script = Script(Path("s.stw"), "# a comment\n\ndof x   # inline\n  # more\niterate 2\n", stepping=True)
    assert not script.running and script.upcoming() == (3, "dof x   # inline")
    comments, job = script.advance()
    assert comments == ["# a comment"] and job == Job("dof x   # inline", number=3, origin="file")
    comments, job = script.advance()
    assert comments == ["  # more"] and job.number == 5 and job.is_solve
    assert script.advance() == ([], None) and script.done


def test_plot_data_and_scene_info(jet):
    scene = jet.scene
    series = dof_series(scene, "x", 2, n=5)
    assert series.label == "x''" and len(series.values) == 5
    curves, scope = equation_series(scene, "end")
    assert scope == (1.0, 1.0) and [c.label for c in curves] == ["end[1] = 0", "end[2] = 0"]
    assert abs(curves[0].values[-1]) < 1e-6                     # x = 1 at t = 1
    force, _ = equation_series(scene, "f", n=3)
    assert force[0].values == pytest.approx([6 + 9.81, 9.81, -6 + 9.81], abs=1e-5)
    assert set(equation_violations(scene)) == {"start", "end"}
    assert figure_bounds(Session().scene) is not None          # empty scene: a default box
    info = scene_info(scene)
    assert "solver" in [o.name for o in info.backend_options] and not info.backend_error


def test_importing_the_app_loads_neither_the_solver_stack_nor_torch():
    """The screen paints before sympy/scipy load (the worker loads them); torch is never needed."""
    import subprocess
    import sys

    code = ("import sys, stw_tui.app\n"
            "print(','.join(m for m in ('torch', 'sympy', 'scipy', 'stw_tui.session.session') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_the_stw_command_starts_without_the_numeric_stack():
    """`stw --help` answers at once: the command's module loads no numpy, sympy or solver; the
    subcommands that solve import them when they run."""
    import subprocess
    import sys

    code = ("import sys, stw_tui.cli.main\n"
            "print(','.join(m for m in ('numpy', 'sympy', 'scipy', 'textual', 'stw_tui.sos.backend') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
    usage = subprocess.run([sys.executable, "-m", "stw_tui.cli", "--help"], capture_output=True, text=True)
    assert usage.returncode == 0 and "stw" in usage.stdout


def test_equation_violations_cover_every_constraint_densely_whatever_the_window():
    s = Session()
    s.run_text("time 0 1 knots=20\ndof x = 0.3 + 0.1*sin(40*t)\nconstraint pin: x = 0.3 @ 0.02\n"
               "constraint low: x <= 0.35 on [0, 1] samples=5\nwindow mid [0.8, 0.9]\n")
    shown = equation_violations(s.scene)
    assert set(shown) == {"pin", "low"}                  # pin lies far outside the window
    x = s.scene.dofs["x"].curve
    assert shown["pin"] == pytest.approx(abs(x.evaluate([0.02])[0] - 0.3), rel=1e-9)
    # Between its 6 instances `low` is broken where the wave's crests pass 0.35 (brute force).
    crest = x.evaluate(np.linspace(0, 1, 200_001)).max() - 0.35
    assert crest > 0.02 and shown["low"] == pytest.approx(crest, rel=1e-6)


def test_the_panels_take_an_iterate_s_dense_check_and_a_proposal_s_is_not_the_scene_s(monkeypatch):
    from stw_tui.sos import continuous

    s = Session()
    s.run_text("time 0 1 knots=20\ndof x = 0.3 + 0.1*sin(40*t)\nconstraint pin: x = 0.3 @ 0.02\n"
               "constraint low: x <= 0.35 on [0, 1] samples=5\nobjective smooth: x''\n")
    outcome = s.execute("iterate 3 adapt=0")
    assert outcome.dense is not None
    fresh = equation_violations(s.scene)               # checked anew: the same numbers
    assert {name: c.dense for name, c in outcome.dense.checks.items()} == fresh
    monkeypatch.setattr(continuous, "check_scene", lambda scene: pytest.fail("checked again"))
    assert scene_info(s.scene, dense=outcome.dense).violations == fresh
    monkeypatch.undo()
    s.execute("set preview on")
    proposed = s.execute("iterate 3 adapt=0")
    assert proposed.run is not None and proposed.dense is None   # of the proposal, not the scene
    assert scene_info(s.scene, dense=proposed.dense).violations == fresh


def test_axes_have_round_ticks_and_a_constant_gets_a_sensible_range():
    from stw_tui.app.axes import fit_title, nice_ticks, title_room, value_limits

    assert nice_ticks(-0.11, 1.19, 4) == ([0.0, 0.5, 1.0], ["0.0", "0.5", "1.0"])
    assert nice_ticks(0, 1, 5)[1] == ["0.00", "0.25", "0.50", "0.75", "1.00"]
    assert nice_ticks(1, 2, 5, integer=True) == ([1.0, 2.0], ["1", "2"])
    assert nice_ticks(0, 2.5e-7, 4)[1] == ["0", "1e-07", "2e-07"]
    assert nice_ticks(1, 1) == ([], [])
    # A constant DOF (dof x = -pi/2) differs from itself only by rounding: not zoomed into.
    noise = [-np.pi / 2 + k * 1e-16 for k in range(5)]
    lo, hi = value_limits(noise)
    assert lo < -np.pi / 2 < hi and hi - lo > 1
    assert all(len(label) <= 4 for label in nice_ticks(lo, hi, 5)[1])
    assert value_limits([0.0, 0.0]) == (-0.5, 0.5)
    assert value_limits([float("nan")]) == (-1.0, 1.0)
    # Titles: the most detailed that fits, else the shortest cut with an ellipsis.
    room = title_room(40, 4)
    assert 30 <= room < 40
    assert fit_title(["t = 1.000 of [0, 2] · space plays · ← → and more", "t = 1.000"], room) == "t = 1.000"
    assert fit_title(["a_very_long_dof_name_indeed value"], 10) == "a_very_lo…"


def test_stw_help_starts_with_how_to_open_the_tui(capsys):
    from stw_tui.cli.main import main

    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    first = [line.strip() for line in out.splitlines() if line.strip()][:2]
    assert first[0] == "usage:" and first[1].startswith("stw [SESSION.stw]") and "TUI" in first[1]
    assert all(len(line) <= 80 for line in out.splitlines())
    assert "Ctrl+Q" in out and "run" in out and "compare" in out
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert capsys.readouterr().out.startswith("usage: stw run ")


def test_latest_only_runs_one_computation_at_a_time_and_keeps_only_the_newest_request():
    import threading
    import time

    from stw_tui.app.background import LatestOnly

    delivered, done = [], threading.Event()
    started, release = threading.Event(), threading.Event()

    def deliver(sequence, result, error):
        delivered.append((sequence, result, None if error is None else str(error)))
        if result == "last":
            done.set()

    computer = LatestOnly(deliver)

    def blocked():
        started.set()
        release.wait(5)
        return "first"

    first = computer.submit(blocked)
    assert started.wait(5)                             # running: what comes next has to wait
    replaced = computer.submit(lambda: "replaced")     # waits behind `blocked`...
    last = computer.submit(lambda: "last")             # ...and is replaced by this one
    release.set()
    assert done.wait(5)
    assert first < replaced < last
    assert delivered == [(first, "first", None), (last, "last", None)]

    def broken():
        raise ValueError("no such DOF")

    done.clear()
    failed = computer.submit(broken)
    for _ in range(500):                                     # the thread is idle: it takes it at once
        if len(delivered) == 3:
            break
        time.sleep(0.01)
    computer.submit(lambda: "last")
    assert done.wait(5)
    assert delivered[2:] == [(failed, None, "no such DOF"), (failed + 1, "last", None)]   # and goes on


def test_latest_only_accepts_only_the_newest_result_and_drop_discards_every_request_so_far():
    import threading

    from stw_tui.app.background import LatestOnly

    delivered, started, release, done = [], threading.Event(), threading.Event(), threading.Event()

    def deliver(sequence, result, error):
        delivered.append(sequence)
        if result == "last":
            done.set()
    computer = LatestOnly(deliver)
    assert not computer.pending

    def blocked():
        started.set()
        release.wait(5)
    running = computer.submit(blocked)
    assert started.wait(5)
    waiting = computer.submit(lambda: delivered.append("ran"))
    assert computer.pending
    assert computer.accept(running) and computer.pending    # an older result: shown, still pending
    assert computer.accept(waiting) and not computer.pending
    assert not computer.accept(running) and not computer.accept(waiting)   # already superseded

    third = computer.submit(lambda: delivered.append("dropped"))
    computer.drop()                       # while `blocked` still runs and `third` waits
    assert not computer.pending and not computer.accept(third)
    release.set()
    last = computer.submit(lambda: "last")
    assert done.wait(5)
    assert "dropped" not in delivered      # the dropped computation never ran
    assert not computer.accept(running)    # and a result from before the drop is not shown
    assert computer.pending and computer.accept(last) and not computer.pending


def test_plot_data_is_computed_from_a_scene_with_a_solves_coefficients(jet):
    from stw_tui.app.plot_data import dof_plot_data, expression_plot_data, figure_data, live_scene

    scene = jet.scene
    coefficients = scene.coefficient_vector() + 1.0          # the curve shifted up by one
    live = live_scene(scene, coefficients)
    assert live is not scene
    assert np.array_equal(scene.dofs["x"].curve.coef + 1.0, live.dofs["x"].curve.coef)
    assert live_scene(scene, None) is scene and live_scene(scene, coefficients[:-1]) is scene
    data = dof_plot_data(live, "x", 0)
    base = dof_plot_data(scene, "x", 0)
    # B-splines are a partition of unity: every value moves by exactly one.
    assert np.allclose(np.subtract(data.series.values, base.series.values), 1.0, atol=1e-12)
    assert data.inside and data.span == (0.0, 1.0) and data.window == "all"
    end = expression_plot_data(live, "end")
    assert end.scope == (1.0, 1.0) and abs(abs(end.series[0].values[-1]) - 1.0) < 1e-6   # x = 1 is off by one
    dot = figure_data(scene, 2.0)                            # clamped to the span; a lone DOF is a dot
    assert dot.t == 1.0 and dot.points[0][0] == "x" and abs(dot.points[0][1][1] - 1.0) < 1e-6
    lo, hi = dot.bounds[2], dot.bounds[3]
    assert lo < min(base.series.values) and hi > max(base.series.values)
    # During a solve the dot's range follows the live curve: the worker's figure_bounds (measured
    # on the scene after the last command) would lose the dot shifted up by one.
    assert figure_data(live, 1.0).bounds[3] > max(data.series.values) > figure_bounds(scene)[3]


def test_only_subexpressions_that_are_positions_are_drawn_as_points():
    """point_mass_2d's thrust (fx, fy use x'' and y'') is a force, not a point: drawn, it put a dot
    near height 9.81 and squashed the motion (y in [0, 0.5]) to the plot's bottom. cat_mouse's
    mouse (mx = 1 + t, my = 1) is a position and is drawn where it runs."""
    from stw_tui.session.figure import player_figure, point_pairs

    thrown = Session()
    thrown.run_file(SESSIONS / "point_mass_2d.stw")
    scene = thrown.scene
    assert point_pairs(scene) == [("•", "x", "y")]
    (label, (x, y)), = player_figure(scene, 1.0).points
    assert (x, y) == pytest.approx((scene.dofs["x"].curve.evaluate([1.0])[0],
                                    scene.dofs["y"].curve.evaluate([1.0])[0]), abs=1e-12)
    y_values = dof_series(scene, "y", 0).values
    x0, x1, y0, y1 = figure_bounds(scene)
    assert y1 < max(y_values) + 0.1 and y0 > min(y_values) - 0.1     # the motion fills the plot

    chase = Session()
    chase.run_file(SESSIONS / "cat_mouse.stw")
    assert point_pairs(chase.scene) == [("c", "cx", "cy"), ("m", "mx", "my")]
    points = dict(player_figure(chase.scene, 1.5).points)
    assert points["m"] == pytest.approx((2.5, 1.0), abs=1e-12)       # the mouse at 1 + t, 1

    # Through other subexpressions: a position built on a position is one; anything built on a
    # velocity (a DOF's, or a subexpression's derivative) is not.
    s = Session()
    s.run_text("dof x, y\nconst k = 2\nlet ox = k*t\nlet oy = sin(x)\nlet px = x + ox\nlet py = y\n"
               "let vx = px'\nlet vy = y\nlet wx = vx + 1\nlet wy = y\n")
    assert point_pairs(s.scene) == [("•", "x", "y"), ("o", "ox", "oy"), ("p", "px", "py")]


def test_a_proposal_is_measured_and_drawn_beside_the_scene():
    """`set preview on`: the worker's SceneInfo carries the proposal, its objective and violation
    and the scene's, and figure bounds that hold both motions; the player draws the proposal."""
    import catalogue

    s = Session()
    s.run_text(catalogue.problem("analytic_landing").text + "set preview on\n")
    outcome = s.execute("iterate 30")
    proposal, scene = s.proposal.scene, s.scene
    info = scene_info(scene, proposal)
    view = info.proposal
    assert view is not None and view.scene is proposal
    last = outcome.run.reports[-1]
    assert view.proposed.objective == pytest.approx(last.objective, rel=1e-9)
    assert view.proposed.dense < 1e-6 < 0.1 < view.current.dense       # solved vs the unsolved start
    new, now = view.captions(0.5)[0].split(" · ")[1:3]
    assert new == f"proposal obj {view.proposed.objective:.4g} viol {view.proposed.dense:.1e}"
    assert now == f"now (dim) obj {view.current.objective:.4g} viol {view.current.dense:.1e}"
    x0, x1, y0, y1 = info.figure_bounds
    for t in np.linspace(0, 1, 9):
        (label, (x, y)), = view.figure(t).points                     # the point mass x, y
        assert (x, y) == pytest.approx((proposal.dofs["x"].curve.evaluate([t])[0],
                                        proposal.dofs["y"].curve.evaluate([t])[0]), abs=1e-12)
        assert x0 < x < x1 and y0 < y < y1
    assert scene_info(scene).proposal is None
    # A lone DOF (the jet particle) is a dot at its height, as the player draws it.
    jet = Session()
    jet.run_text((SESSIONS / "particle_jet.stw").read_text().split("iterate")[0] + "set preview on\niterate 20\n")
    view = scene_info(jet.scene, jet.proposal.scene).proposal
    (label, (x, y)), = view.figure(0.5).points
    assert label == "x" and x == 0 and y == pytest.approx(jet.proposal.scene.dofs["x"].curve.evaluate([0.5])[0])
