"""Surveys solved as one batch on the torch backend (`set scheduler batch`, BatchEngine; the batch
solver is backends/stw_torch/batch.py).

The reference is the serial engine on the same pendulum swing-up survey as tests/test_survey.py
(there with the scipy backend: the batch takes the same SQP steps, its numbers from batched torch
evaluations and batched dense LU factorizations). Converged optima must agree to OBJECTIVE_RTOL.
"""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import catalogue  # noqa: E402

catalogue.backend_package("stw_torch")
from stw_torch import batch as torch_batch  # noqa: E402
from stw_torch.batch import TorchBatch  # noqa: E402

from stw_tui.session.session import Session  # noqa: E402
from stw_tui.session.survey import SurveyPlan  # noqa: E402
from stw_tui.session.survey_engines import BatchEngine, SerialEngine, run_survey  # noqa: E402
from stw_tui.sym.errors import StwError  # noqa: E402

PENDULUM = catalogue.problem("analytic_pendulum_swing_up").text
PLAN = SurveyPlan(12, seed=1, amplitude=3.0, iterations=100)   # as tests/test_survey.py
OBJECTIVE_RTOL = 1e-6   # batched and serial objectives of one start (both stop at tol_kkt)
MOTION_ATOL = 1e-6      # and their DOF values at the survey's samples


@pytest.fixture(scope="module")
def pendulum() -> Session:
    session = Session()
    session.run_text(PENDULUM)
    return session


@pytest.fixture(scope="module")
def serial_table(pendulum):
    return run_survey(pendulum, PLAN, SerialEngine())


@pytest.fixture(scope="module", params=["torch", "scipy"])
def batch_table(request, pendulum):
    """linear=torch: KKT systems LU-factorized as one (B, n, n) stack (the default on cuda);
    linear=scipy: each start's sparse factorization on the host (the default on the CPU)."""
    return run_survey(pendulum, PLAN, BatchEngine(options={"device": "cpu", "linear": request.param}))


def shape(table) -> list:
    """Per optimum its member starts (in index order: members whose objectives agree to 1e-12
    may come in either order), then the unconverged and failed starts."""
    return [tuple(sorted(m.index for m in o.members)) for o in table.optima] + \
        [tuple(r.index for r in table.unconverged), tuple(r.index for r in table.failed)]


def test_batch_finds_the_serial_optima(serial_table, batch_table):
    assert batch_table.engine.startswith("torch batch of up to 64 on cpu")
    assert len(serial_table.optima) == 2   # the straight and the pumping swing-up (test_survey.py)
    assert shape(batch_table) == shape(serial_table)
    for a, b in zip(serial_table.optima, batch_table.optima):
        assert b.best.objective == pytest.approx(a.best.objective, rel=OBJECTIVE_RTOL)
    for a, b in zip(serial_table.results, batch_table.results):   # every start, not only the best
        assert (b.index, b.status, b.converged) == (a.index, a.status, a.converged)
        assert b.objective == pytest.approx(a.objective, rel=OBJECTIVE_RTOL)
        np.testing.assert_allclose(b.motion, a.motion, atol=MOTION_ATOL)
        assert b.dense_violation < 1e-6 and len(b.frames) == len(a.frames)
    assert sorted(batch_table.as_dict()["optima"][0]["starts"]) == sorted(serial_table.as_dict()["optima"][0]["starts"])


def test_batch_is_deterministic(pendulum, batch_table):
    linear = "scipy" if batch_table.engine.endswith("on the host") else "torch"
    again = run_survey(pendulum, PLAN, BatchEngine(options={"device": "cpu", "linear": linear}))
    assert shape(again) == shape(batch_table)
    for a, b in zip(again.results, batch_table.results):
        assert (a.objective, a.iterations) == (b.objective, b.iterations)
        np.testing.assert_array_equal(a.motion, b.motion)


def test_a_start_that_diverges_in_the_batch_fails_alone(pendulum, serial_table, monkeypatch):
    """Start 2's evaluations turn non-finite at its third: the driver's check fails that start
    (as it would a serial solve), and the other starts reach what they reach serially."""
    seen = {"n": 0}
    request = TorchBatch.request

    def diverging(self, job, kind, key, payload):
        result = request(self, job, kind, key, payload)
        if job == 2 and kind == "evaluate":
            seen["n"] += 1
            if seen["n"] >= 3:
                result.objective = float("nan")
        return result

    monkeypatch.setattr(TorchBatch, "request", diverging)
    table = run_survey(pendulum, PLAN, BatchEngine(options={"device": "cpu", "linear": "torch"}))
    assert [r.index for r in table.failed] == [2]
    assert "non-finite" in table.failed[0].error and seen["n"] >= 3
    for a, b in zip(serial_table.results, table.results):
        if b.index != 2:
            assert b.converged == a.converged and b.objective == pytest.approx(a.objective, rel=OBJECTIVE_RTOL)


def test_a_request_that_raises_fails_its_own_job_only(monkeypatch):
    """The batch redoes a raising computation request by request: only the bad one fails. Rounds
    are lockstep: each holds one request of every running job, served in job order."""
    batches = []

    def halve(items):
        batches.append(list(items))
        if any(x < 0 for x in items):
            raise ValueError("negative")
        return [x / 2 for x in items]

    monkeypatch.setitem(torch_batch._KINDS, "halve", halve)
    solver = TorchBatch(3, torch.device("cpu"), {}, "scipy", None)

    def job(i):
        def run():
            values = []
            for step in range(2 + i):
                try:
                    values.append(solver.request(i, "halve", "halve", float(i - 1 if step == 1 else i)))
                except ValueError as exc:
                    values.append(str(exc))
            return values
        return run

    done = []
    solver.run([job(i) for i in range(4)], lambda i, r: done.append((i, r)), lambda: False)
    assert sorted(done) == [(0, [0.0, "negative"]), (1, [0.5, 0.0, 0.5]), (2, [1.0, 0.5, 1.0, 1.0]),
                            (3, [1.5, 1.0, 1.5, 1.5, 1.5])]
    assert batches[0] == [0.0, 1.0, 2.0]                # round 1: jobs 0, 1, 2 (size 3)
    assert batches[1] == [-1.0, 0.0, 1.0]               # round 2 raises: redone one by one
    assert batches[2:5] == [[-1.0], [0.0], [1.0]]


def test_a_scene_backend_without_batches_gives_way_to_one_with_them_and_its_defaults():
    """Chosen by capability: the scene's scipy (and its options, which are scipy's) cannot batch."""
    solver = BatchEngine(backend="scipy", options={"solver": "minres", "device": "cuda"}).solver()
    assert solver.describe().startswith("torch batch of up to 64 on ")
    assert solver.options["solver"] == "direct" and solver.options["device"] == "auto"   # torch's defaults


def test_bad_batch_options_are_one_message():
    with pytest.raises(StwError, match="option linear: 'dense' is not one of"):
        BatchEngine(backend="torch", options={"device": "cpu", "linear": "dense"}).solver()


def test_console_set_scheduler_batch():
    session = Session()
    session.run_text(PENDULUM)
    assert "one batch on the torch backend" in session.execute("set scheduler batch").message
    outcome = session.execute("survey 12 seed=1 amplitude=3")
    assert "2 distinct optima" in outcome.message
    assert session.survey.engine.startswith("torch batch of up to 64 on ")


def test_batched_evaluations_are_each_starts_own():
    """Two starts of a window that frees x only: their fixed y control points differ, yet they
    share one lowering and one batched evaluation, which gives each start its own numbers."""
    from stw_torch.evaluate import TorchProblem, evaluations_of, merit_values_of
    from stw_torch.lowerings import problem_key

    from stw_tui.sos.window import WindowProblem

    problems = []
    for seed in (1, 2):
        session = Session()
        session.run_text(catalogue.problem("analytic_landing").text
                         + "constraint lift: x >= 0.2 on [0, 1] when y > 0\n"   # a `when` condition
                         + f"shake amplitude=0.3 seed={seed}\nwindow wx dofs=x\nuse wx\n")
        problems.append(WindowProblem(session.scene))
    cpu = torch.device("cpu")
    assert problem_key(problems[0], cpu, False) == problem_key(problems[1], cpu, False)
    template = TorchProblem(problems[0], cpu, host_linear=False)
    members = [template.with_problem(p) for p in problems]
    points = [p.initial() + 0.01 * k for k, p in enumerate(problems)]
    lam_eq, lam_ge = [np.linspace(-1, 1, problems[0].row_counts[kind]) for kind in ("eq", "ge")]
    for problem, point, ev, merit in zip(problems, points, evaluations_of(members, points),
                                         merit_values_of(members, points)):
        own = TorchProblem(problem, cpu, host_linear=False).evaluate(point)
        assert ev.objective == pytest.approx(own.objective, rel=1e-12)
        assert merit.objective == pytest.approx(own.objective, rel=1e-12)
        np.testing.assert_allclose(ev.gradient, own.gradient, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ev.c_eq, own.c_eq, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(merit.c_eq, own.c_eq, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ev.c_ge, own.c_ge, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(ev.active_ge, own.active_ge)
        np.testing.assert_array_equal(merit.active_ge, own.active_ge)
        assert 0 < own.active_ge.sum() < own.active_ge.size   # the condition holds at some instances
        np.testing.assert_allclose(ev.J_ge.toarray(), own.J_ge.toarray(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ev.J_eq.toarray(), own.J_eq.toarray(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ev.lagrangian_hessian(lam_eq, lam_ge).numpy(),
                                   own.lagrangian_hessian(lam_eq, lam_ge).numpy(), rtol=1e-12, atol=1e-12)
    assert abs(members[0].v_fixed - members[1].v_fixed).max() > 0.01   # y differs between the starts


def test_a_cancelled_batch_reports_nothing_more_and_ends_its_threads(monkeypatch):
    import threading

    monkeypatch.setitem(torch_batch._KINDS, "echo", lambda items: list(items))
    solver = TorchBatch(3, torch.device("cpu"), {}, "scipy", None)
    stop = {"asked": False}

    def job(i, n):
        def run():
            for k in range(n):
                solver.request(i, "echo", "echo", k)
            return i
        return run

    done = []

    def on_done(index, result):
        done.append((index, result))
        stop["asked"] = True    # cancel once the short job is back

    solver.run([job(0, 1), job(1, 10**6), job(2, 10**6), job(3, 1)], on_done, lambda: stop["asked"])
    assert done == [(0, 0)]
    assert not [t for t in threading.enumerate() if t.name.startswith("stw-batch-")]
