"""Surveys of local optima (stw_tui/session/survey.py, survey_engines.py, survey_session.py).

The problem is a pendulum swing-up: θ'' = u − g sin θ from hanging at rest (θ = 0) to upright at
rest (θ = π) in 2.5 s, minimizing ∫u². Two local optima are known from the physics: swing straight
up (θ first moves positive), or pump back first (θ first moves negative) and use gravity. They
are told apart here from the motion itself (the sign of θ's first excursion), not from the
survey's own descriptors.
"""

import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import catalogue
from conftest import ROOT, popen_foreground

from stw_tui.session.session import Session
from stw_tui.session.survey import SurveyPlan, plan_tasks
from stw_tui.session.survey_engines import PoolEngine, SerialEngine, run_survey
from stw_tui.sym.errors import SourceError, StwError

PENDULUM = catalogue.problem("analytic_pendulum_swing_up").text
PLAN = SurveyPlan(12, seed=1, amplitude=3.0, iterations=100)


@pytest.fixture(scope="module")
def pendulum() -> Session:
    session = Session()
    session.run_text(PENDULUM)
    return session


@pytest.fixture(scope="module")
def serial_table(pendulum):
    return run_survey(pendulum, PLAN, SerialEngine())


def first_excursion(theta: np.ndarray, threshold: float = 0.05) -> int:
    """The sign of θ's first move away from where it starts."""
    away = theta - theta[0]
    return int(np.sign(away[np.flatnonzero(np.abs(away) > threshold)[0]]))


def table_rows(table) -> list[tuple]:
    """What two surveys must agree on: per optimum its objective, its starts and their lines."""
    return [(round(o.best.objective, 6), tuple(m.index for m in o.members), o.best.lines)
            for o in table.optima] + [("unconverged", tuple(r.index for r in table.unconverged)),
                                      ("failed", tuple(r.index for r in table.failed))]


def test_pendulum_survey_finds_a_straight_and_a_pumping_swing_up(serial_table):
    optima = serial_table.optima
    assert len(optima) > 1
    assert sum(o.count for o in optima) + len(serial_table.unconverged) + len(serial_table.failed) == PLAN.n
    signs = {first_excursion(o.best.motion[0]) for o in optima}
    assert signs == {1, -1}
    for o in optima:   # each is a true swing-up: hanging at rest to upright at rest
        theta = o.best.motion[0]
        assert theta[0] == pytest.approx(0, abs=1e-6) and theta[-1] == pytest.approx(np.pi, abs=1e-6)
        assert o.best.dense_violation < 1e-6
    objectives = [o.best.objective for o in optima]
    assert objectives == sorted(objectives)
    # distinct optima really differ, in the objective and in the motion
    assert abs(objectives[1] - objectives[0]) > 1e-3 * objectives[0]
    assert np.abs(optima[0].best.motion - optima[1].best.motion).max() > 0.1
    # pumping first uses gravity and costs less than swinging straight up
    pump = next(o for o in optima if first_excursion(o.best.motion[0]) < 0)
    straight = next(o for o in optima if first_excursion(o.best.motion[0]) > 0)
    assert pump.best.objective < straight.best.objective
    assert pump.best.descriptors["first_move"]["th"] == -1


def test_same_seed_same_survey_and_another_seed_other_starts(pendulum, serial_table):
    again = run_survey(pendulum, PLAN, SerialEngine())
    assert table_rows(again) == table_rows(serial_table)
    for a, b in zip(again.results, serial_table.results):
        np.testing.assert_array_equal(a.motion, b.motion)
    other = plan_tasks(pendulum, SurveyPlan(12, seed=2, amplitude=3.0))
    assert [t.lines for t in other] != [r.lines for r in serial_table.results]
    # the first starts of a longer survey are those of a shorter one
    longer = plan_tasks(pendulum, SurveyPlan(20, seed=1, amplitude=3.0, iterations=100))
    assert [t.lines for t in longer[:12]] == [r.lines for r in serial_table.results]


def test_a_task_is_session_text_not_a_scene(tmp_path):
    session = Session()
    session.run_text(PENDULUM + "print th @ 1\n")
    session.execute(f"export csv {tmp_path / 'x.csv'}")   # typed: a replayed line writes only in its folder
    task = plan_tasks(session, SurveyPlan(1, seed=3))[0]
    assert isinstance(task.base_text, str) and "print" not in task.base_text and "export" not in task.base_text
    assert task.lines[0].startswith("shake amplitude=0.5 seed=") and task.lines[-1] == "iterate 100"


def test_starts_that_do_not_converge_are_counted_apart(pendulum):
    table = run_survey(pendulum, SurveyPlan(3, seed=1, amplitude=3.0, iterations=2), SerialEngine())
    assert not table.optima and len(table.unconverged) == 3
    assert all(r.status == "iteration limit reached" for r in table.unconverged)
    assert "3 not converged" in table.summary()


def test_console_survey_adopt_undo_and_replay():
    session = Session()
    session.run_text(PENDULUM + "set scheduler serial\n")
    before = session.scene.coefficient_vector().copy()
    outcome = session.execute("survey 12 seed=1 amplitude=3")
    assert "2 distinct optima" in outcome.message
    np.testing.assert_array_equal(session.scene.coefficient_vector(), before)   # a survey changes nothing
    second = session.survey.optima[1].best
    session.execute("adopt 2")
    now = session.scene.coefficient_vector().copy()
    theta = session.scene.dofs["th"].curve.evaluate(np.linspace(0, 2.5, 201))
    np.testing.assert_allclose(theta, second.motion[0], atol=1e-9)
    journal = session.journal.replayable()
    assert journal[-1] == "\n".join(second.lines) and journal[-2].startswith("# survey 12")
    replay = Session()
    replay.run_text("\n".join(journal))
    np.testing.assert_array_equal(replay.scene.coefficient_vector(), now)
    session.execute("undo")
    np.testing.assert_array_equal(session.scene.coefficient_vector(), before)
    session.execute("adopt 1")     # the scene is the surveyed one again
    session.execute("key 1 th=1")
    with pytest.raises(StwError, match="changed since the survey"):
        session.execute("adopt 2")


@pytest.mark.parametrize("line, message", [
    ("survey 0", "at least one start"),
    ("survey 3 from=nowhere", "a start comes from"),
    ("survey 3 seed=1 seed=2", "given twice"),
    ("survey 3 speed=2", "unknown survey option"),
    ("survey 3 workers=0", "at least 1"),
    ("set scheduler tcp://host", "not a scheduler address"),
    ("set scheduler tcp://host:8786 now", "unexpected 'now'"),
])
def test_bad_survey_lines_say_where(line, message):
    session = Session()
    session.run_text(PENDULUM)
    with pytest.raises(SourceError, match=message):
        session.execute(line)


def test_bad_survey_plans_leave_the_scene(pendulum):
    session = Session()
    session.run_text(PENDULUM + "window late [1, 2]\nuse all\n")
    for line, message in [("survey 2 window=nope", "no window named"), ("adopt 1", "no survey"),
                          ("survey 2 from=sketch", "keyframes"), ("survey 2 amplitude=-1", "amplitude"),
                          ("survey 2 window=late from=random", "frees only")]:
        with pytest.raises(StwError, match=message):
            session.execute(line)
    assert session.scene.scheduler == ""
    session.execute("set scheduler tcp://10.0.0.5:8786")
    assert session.scene.scheduler == "tcp://10.0.0.5:8786"


def test_shaken_starts_in_a_window_with_an_interval_keep_the_motion_outside_it():
    """A survey in a window with an interval: its shaken starts move only the control points the
    window frees (`shake` there), so each start's solve can converge, and every start's motion
    before the window is the scene's own."""
    session = Session()
    session.run_text(PENDULUM + "iterate 100\nwindow late [1.5, 2.5]\n")
    before = session.scene.dofs["th"].curve.coef.copy()
    support = session.scene.dofs["th"].curve.support()
    outside = support[:, 1] <= 1.5
    table = run_survey(session, SurveyPlan(2, seed=3, amplitude=0.2, iterations=60, window="late"), SerialEngine())
    results = [r for o in table.optima for r in o.members]
    assert len(results) == 2 and not table.failed and not table.unconverged, table.summary()
    for r in results:                     # each start replayed: shaken and solved in the window
        start = Session()
        start.run_text(PENDULUM + "iterate 100\nwindow late [1.5, 2.5]\nuse late\n" + "\n".join(r.lines))
        assert start.runs[-1].converged and abs(start.runs[-1].reports[-1].objective - r.objective) < 1e-9
        assert np.array_equal(start.scene.dofs["th"].curve.coef[outside], before[outside])
        assert not np.array_equal(start.scene.dofs["th"].curve.coef, before)


def test_sketch_and_random_starts_are_session_lines(pendulum):
    session = Session()
    session.run_text(PENDULUM + "key 1.2 th=-1\n")
    sketch = plan_tasks(session, SurveyPlan(2, seed=4, source="sketch", amplitude=0.3))
    assert all(t.lines[0].startswith("key 1.2 th=") for t in sketch)
    random = plan_tasks(session, SurveyPlan(2, seed=4, source="random"))
    assert all(t.lines[0].startswith("dof th = ") for t in random)
    table = run_survey(session, SurveyPlan(2, seed=4, source="random", amplitude=2.0), SerialEngine())
    assert len(table.results) == 2 and not table.failed


def _kill_one(pids) -> None:
    os.kill(pids[0], signal.SIGKILL)


def test_pool_gives_the_serial_table_and_survives_a_killed_worker(pendulum, serial_table):
    engine = PoolEngine(2)
    killed = []

    def on_progress(table, result):
        if result is not None and not killed and engine.processes:
            killed.append(engine.processes[0])
            _kill_one(engine.processes)

    table = run_survey(pendulum, PLAN, engine, on_progress=on_progress)
    assert killed
    assert any("worker process died" in note for note in table.notes)
    assert len(table.results) == PLAN.n
    assert table_rows(table) == table_rows(serial_table)


def test_dask_local_cluster_gives_the_pool_table(pendulum, serial_table):
    pytest.importorskip("distributed")
    from stw_tui.session.survey_engines import DaskEngine

    table = run_survey(pendulum, PLAN, DaskEngine(2))
    assert table_rows(table) == table_rows(serial_table)   # the pool gives it too (the test above)
    assert "Dask LocalCluster" in table.engine


def test_dask_survives_a_killed_worker(pendulum, serial_table):
    pytest.importorskip("distributed")
    from stw_tui.session.survey_engines import DaskEngine

    engine = DaskEngine(2)
    client = engine.client()
    killed = []

    def on_progress(table, result):
        if result is not None and not killed:
            by_pid = {pid: address for address, pid in client.run(os.getpid).items()}
            pids = sorted(by_pid)
            killed.append(pids[0])
            _kill_one(pids)
            # until the scheduler has seen it go: the engine looks for lost workers after each
            # pass over the results, and the other worker could otherwise finish the survey first
            deadline = time.monotonic() + 30
            while by_pid[pids[0]] in client.ncores() and time.monotonic() < deadline:
                time.sleep(0.05)

    table = run_survey(pendulum, PLAN, engine, on_progress=on_progress)
    assert killed
    assert any("was lost" in note for note in table.notes), table.notes
    assert len(table.results) == PLAN.n
    assert table_rows(table) == table_rows(serial_table)


STOP_WITHIN_S = 5.0   # issue 54 asks for 2 s; room here for a loaded machine (measured: 0.05-0.1 s)


def test_a_stop_ends_a_long_dask_survey_at_once(pendulum):
    # `survey 100000 iterate=1`, stopped from another thread (F4 from the UI's) once a few starts
    # are back, or after 5 s if none are: the survey returns within seconds, however many starts
    # are left. It used to submit every start at once (19 s for 100000, during which no stop was
    # looked at) and then to take each result in turn, 33 s after the stop here. A thread takes
    # the interpreter lock now and then meanwhile, as the TUI's event loop does.
    pytest.importorskip("distributed")
    from stw_tui.session.survey_engines import DaskEngine

    engine = DaskEngine(2)
    engine.client()                       # the cluster is up before the clock starts
    plan = SurveyPlan(100_000, seed=1, amplitude=3.0, iterations=1)
    few_back, stop, finished = threading.Event(), threading.Event(), threading.Event()
    asked = []

    def on_progress(table, result):
        if len(table.results) >= 3:
            few_back.set()

    def press_stop():
        few_back.wait(timeout=5.0)
        asked.append(time.monotonic())
        stop.set()

    def event_loop():
        while not finished.is_set():
            sum(range(20_000))
            time.sleep(0.001)

    threads = [threading.Thread(target=press_stop, daemon=True), threading.Thread(target=event_loop, daemon=True)]
    for thread in threads:
        thread.start()
    try:
        table = run_survey(pendulum, plan, engine, on_progress=on_progress, cancelled=stop.is_set)
        returned = time.monotonic()
    finally:
        finished.set()
    waited = returned - asked[0]
    print(f"survey returned {waited:.2f} s after the stop, with {len(table.results)} starts done")
    assert waited < STOP_WITHIN_S
    assert table.cancelled and 3 <= len(table.results) < plan.n
    # nothing of the dropped starts holds the cluster: the next survey runs at once
    again = run_survey(pendulum, SurveyPlan(4, seed=2, amplitude=3.0, iterations=1), engine)
    assert len(again.results) == 4 and not again.cancelled


def test_ctrl_c_ends_a_headless_survey_at_once(tmp_path):
    # Ctrl+C (SIGINT) during `stw run`'s `survey 100000 iterate=1`: it ends the line at once with
    # what was done, and the cluster's starts are dropped. It used to end in a KeyboardInterrupt
    # traceback 8 s later (rc -2), the cluster closing at exit with its queue full.
    pytest.importorskip("distributed")
    path = tmp_path / "pendulum.stw"
    path.write_text(PENDULUM + "survey 100000 iterate=1\n")
    lines = len(PENDULUM.splitlines())
    env = {**os.environ, "PYTHONUNBUFFERED": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "backends"), os.environ.get("PYTHONPATH", "")])}
    # SIGINT at its default in the child: under a pytest that ignores it (a background job) the
    # child ignored Ctrl+C and this test hung until its timeout.
    child = popen_foreground([sys.executable, "-m", "stw_tui.cli.main", "run", str(path)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=env)
    try:
        for line in child.stdout:              # the scene is built: the survey starts
            if line.startswith(f"[{lines}]"):
                break
        time.sleep(6.0)                        # the cluster starts, and the first starts come back
        child.send_signal(signal.SIGINT)
        asked = time.monotonic()
        _, err = child.communicate(timeout=60)
        waited = time.monotonic() - asked
    finally:
        child.kill()
    print(f"stw run exited {waited:.2f} s after SIGINT")
    assert child.returncode == 1, err
    assert "survey interrupted (Ctrl+C) after" in err and "the scene is unchanged" in err
    assert "Traceback" not in err
    assert waited < STOP_WITHIN_S


def test_cli_survey_json(tmp_path):
    path = tmp_path / "pendulum.stw"
    path.write_text(PENDULUM)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "backends"),
                                                        os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-m", "stw_tui.cli.main", "survey", str(path), "6", "seed=1",
                           "amplitude=3", "--scheduler", "serial", "--json"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    table = json.loads(done.stdout)
    assert table["done"] == 6 and table["optima"] and table["optima"][0]["rank"] == 1
    assert sum(o["count"] for o in table["optima"]) + len(table["unconverged"]) + len(table["failed"]) == 6
    assert "[6/6]" in done.stderr      # the progress line


def _result(index, objective, motion, converged=True):
    from stw_tui.session.survey import StartResult

    return StartResult(index, index, (), "converged" if converged else "iteration limit reached",
                       converged=converged, objective=objective, dofs=("x",), motion=np.asarray([motion], float))


def test_grouping_rules_objective_and_motion_tolerances_and_order():
    from stw_tui.session.survey import MOTION_TOL, OBJECTIVE_RTOL, group

    base = np.linspace(0, 1, 201)
    results = [_result(0, 10.0, base),
               _result(1, 10.0 * (1 + OBJECTIVE_RTOL / 2), base + MOTION_TOL / 2),   # the same optimum
               _result(2, 10.0, base + 0.5),                   # same objective, another motion
               _result(3, 10.0 * (1 + 10 * OBJECTIVE_RTOL), base),   # same motion, another objective
               _result(4, 9.0, base, converged=False)]          # never grouped, however good
    optima = group(results)
    assert [[m.index for m in o.members] for o in optima] == [[0, 1], [2], [3]]
    shuffled = group(results[::-1])
    assert [[m.index for m in o.members] for o in shuffled] == [[0, 1], [2], [3]]


def test_a_start_brings_back_its_stick_figures_for_the_gallery():
    # The worker draws the figures where it solved (the gallery only renders them): at FRAMES
    # evenly spaced times, the same geometry scene_figure gives on the curves the start reached.
    from stw_tui.session.figure import scene_figure
    from stw_tui.session.survey import FRAMES, preview_scene, solve_start

    session = Session()
    session.run_text(catalogue.problem("analytic_arm3").text + """dof SHOULDER = -pi/2 + t
constraint rest0: SHOULDER' = 0, ELBOW' = 0, WRIST' = 0 @ 0
constraint rest1: SHOULDER' = 0, ELBOW' = 0, WRIST' = 0 @ 1.5
objective effort: tau_SHOULDER, tau_ELBOW, tau_WRIST
iterate 20
""")
    result = solve_start(plan_tasks(session, SurveyPlan(1, seed=3, amplitude=0.1, iterations=30))[0])
    assert result.error == "" and len(result.frames) == FRAMES
    preview = preview_scene(session.scene, result)
    for frame, t in zip(result.frames, np.linspace(preview.t0, preview.t1, FRAMES)):
        expected = scene_figure(preview, float(t))
        assert frame.t == pytest.approx(t) and len(frame.segments) == len(expected.segments) == 3
        np.testing.assert_allclose(np.array(frame.segments), np.array(expected.segments), atol=1e-12)


def test_distributeds_interrupted_sync_race_is_not_reported_over_the_survey_line():
    # Ctrl+C inside a Dask client call can make distributed's own cancel callback raise
    # NameError('future') on its loop thread, which tornado logged as a traceback after stw's
    # "survey interrupted" line (seen once in test_ctrl_c_ends_a_headless_survey_at_once). Only
    # that record is dropped: the same error from elsewhere, and other errors, still show.
    import logging
    from stw_tui.session.survey_engines import _SYNC_RACE_FILTER

    def raised(filename):
        code = compile("def cancel():\n    future\n    future = 1\ncancel()\n", filename, "exec")
        try:
            exec(code, {})
        except NameError as exc:
            return exc
        raise AssertionError("no NameError")

    def record(exc):
        return logging.LogRecord("tornado.application", logging.ERROR, __file__, 1, "Exception in callback",
                                 None, (type(exc), exc, exc.__traceback__))

    in_dask = raised(os.path.join("site-packages", "distributed", "utils.py"))
    assert "'future'" in str(in_dask)
    assert not _SYNC_RACE_FILTER.filter(record(in_dask))
    assert _SYNC_RACE_FILTER.filter(record(raised(os.path.join("stw_tui", "utils.py"))))
    assert _SYNC_RACE_FILTER.filter(record(ValueError("future")))
    assert _SYNC_RACE_FILTER.filter(logging.LogRecord("tornado.application", logging.ERROR, __file__, 1, "x", None, None))
