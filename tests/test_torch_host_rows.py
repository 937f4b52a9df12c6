"""Host programs on rows (backends/stw_torch/host_levels.py): the same numbers as TorchScript, bit
for bit, on every call after the first (which plans the rows), across changing instance counts,
and nothing a caller holds is written over by the next call."""

import random

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import stw_torch.host_levels as host_levels  # noqa: E402
from stw_torch.host import host_function, tape_of  # noqa: E402
from stw_torch.lower import _HOST_NAMES, _compile  # noqa: E402
from stw_torch.evaluate import TorchProblem  # noqa: E402
from test_torch_backend import _random_expression  # noqa: E402

import catalogue  # noqa: E402
from stw_tui.sos.window import WindowProblem  # noqa: E402

NAMES = ["_v0", "_v1", "_t", "_p0"]


def _arguments(n: int, shift: float = 0.0) -> list[np.ndarray]:
    return [np.linspace(0.1, 2.9, n) + shift, np.linspace(-1.7, 1.3, n) - shift,
            np.linspace(0.0, 1.0, n), np.asarray(1.7 + shift)]


def _torchscript(program, values: list[np.ndarray]) -> list[np.ndarray]:
    return [r.numpy() for r in program([torch.from_numpy(a) for a in values], torch.from_numpy(values[2]))]


def _random_programs(seed: int, count: int):
    """(TorchScript program, host function) of seeded random programs large enough to run on rows."""
    rng = random.Random(seed)
    for _ in range(count):
        try:
            outputs = [_random_expression(rng, 5) for _ in range(4)]
        except RuntimeError:              # symengine refuses a construct (cos of infinity)
            continue
        program, source = _compile(NAMES, outputs)
        tape = tape_of(source, _HOST_NAMES) if source is not None else None
        if tape is not None:
            program.host_fn = host_function(tape, _HOST_NAMES)
            yield program, program.host_fn, tape


def _same(got, want) -> bool:
    return len(got) == len(want) and all(np.array_equal(a, b, equal_nan=True) for a, b in zip(got, want))


def test_programs_on_rows_give_torchscripts_numbers_call_after_call():
    """Each random program, called on 23 instances, then 1, then 23 again with other numbers: every
    call equals TorchScript's, the plan on rows runs from the second call on, and what an earlier
    call returned is not changed by the later ones (the rows are kept and written again)."""
    on_rows = grouped = 0
    for program, host, tape in _random_programs(5, 40):
        calls = [_arguments(23), _arguments(1, 0.3), _arguments(23, -0.2), _arguments(23, 0.4)]
        with np.errstate(all="ignore"):
            wants = [_torchscript(program, values) for values in calls]
            gots = [[a.copy() for a in program.host(values, values[2])] if i == 0 else program.host(values, values[2])
                    for i, values in enumerate(calls)]
        assert all(_same(got, want) for got, want in zip(gots, wants)), tape
        plans = [p for p in host.plans.values() if p is not None]
        if len(tape[2]) >= 8 and plans:
            on_rows += 1
            grouped += any(step[0] == "group" for p in plans for step in p.schedule)
    assert on_rows >= 25 and grouped >= 10


def test_a_program_another_thread_is_running_runs_as_its_tape():
    """While its rows are in use (the plan's lock held elsewhere), a call runs the tape as it is."""
    program, host, _ = next((p, h, t) for p, h, t in _random_programs(7, 40) if len(t[2]) >= 30)
    values = _arguments(17)
    with np.errstate(all="ignore"):
        want = _torchscript(program, values)
        program.host(values, values[2])                    # plans the rows
        (plan,) = [p for p in host.plans.values() if p is not None]
        with plan._lock:
            busy = program.host(values, values[2])
        again = program.host(values, values[2])
    assert _same(busy, want) and _same(again, want)


def test_rows_too_large_to_keep_run_as_the_tape(monkeypatch):
    """A plan whose rows for n instances would pass WORKSPACE_FLOATS keeps nothing: the tape runs."""
    program, host, _ = next((p, h, t) for p, h, t in _random_programs(9, 40) if len(t[2]) >= 30)
    monkeypatch.setattr(host_levels, "WORKSPACE_FLOATS", 64)
    values = _arguments(40)
    with np.errstate(all="ignore"):
        want = _torchscript(program, values)
        got = [program.host(values, values[2]) for _ in range(3)]
    (plan,) = [p for p in host.plans.values() if p is not None]
    assert plan._kept is None and all(_same(g, want) for g in got)


@pytest.mark.parametrize("problem", catalogue.problems(*catalogue.QUICK, "arm_throw"), ids=str)
def test_repeated_evaluations_on_the_host_give_the_device_paths_numbers(problem):
    """A window's evaluations repeated on the host (its calls' programs on rows together from the
    second: calls.Together) equal the torch ops' and TorchScript's (the device path) bit for bit,
    at two points in turn."""
    window = WindowProblem(problem.setup().scene)
    points = [window.initial() + 0.01 * np.sin(np.arange(window.n_free) + k) for k in range(2)]
    host = TorchProblem(window, torch.device("cpu"), host_linear=True)
    device = TorchProblem(window, torch.device("cpu"), host_linear=True)
    device.host = False
    for s in points * 2:
        got, want = host.evaluate(s), device.evaluate(s)
        assert np.array_equal(got.gradient, want.gradient) and np.array_equal(got.c_eq, want.c_eq)
        assert np.array_equal(got.J_eq.data, want.J_eq.data)
        lam = np.linspace(-1.0, 2.0, window.row_counts["eq"])
        lam_ge = -np.linspace(0.0, 1.5, window.row_counts["ge"])
        assert np.array_equal(got.lagrangian_hessian(lam, lam_ge).data, want.lagrangian_hessian(lam, lam_ge).data)
        assert np.array_equal(host.merit_values(s).c_eq, device.merit_values(s).c_eq)
    together = [t for t in host.plan.together.values() if t.buckets]
    assert together and all(len(p.programs) >= 1 for t in together for p, _ in t.buckets)
    if problem.name == "arm_throw":       # a linkage: many terms share rows
        assert max(len(p.programs) for t in together for p, _ in t.buckets) >= 5


def test_a_constant_jacobian_is_handed_on_not_made_again():
    """A kind whose rows are all affine has one Jacobian for the whole solve on the host: the
    first evaluation's values (read-only) and one scipy matrix, which the next evaluations hand
    on, with the numbers a fresh product of their own gradients gives; a kind with a nonlinear
    row (the arm's release) gets new values at every evaluation."""
    window = WindowProblem(catalogue.problems("particle_jet")[0].setup().scene)
    tp = TorchProblem(window, torch.device("cpu"), host_linear=True)
    assert "eq" in tp.constant_kinds
    points = [window.initial() + 0.1 * np.sin(np.arange(window.n_free) + k) for k in range(3)]
    evaluations = [tp.evaluate(s) for s in points]
    first = evaluations[0]
    for ev in evaluations[1:]:
        assert ev.J_eq is first.J_eq and ev.t_J["eq"] is first.t_J["eq"]
        fresh = tp.jac["eq"].values(ev.t_local["g"] * tp.host_arrays["w_slot"])
        assert np.array_equal(ev.J_eq.data, fresh)
    assert not first.t_J["eq"].flags.writeable
    again = tp.with_problem(window).evaluate(points[0])   # a new solve keeps its own
    assert again.J_eq is not first.J_eq and np.array_equal(again.J_eq.data, first.J_eq.data)

    arm = WindowProblem(catalogue.problems("arm_throw")[0].setup().scene)
    tp = TorchProblem(arm, torch.device("cpu"), host_linear=True)
    assert "eq" not in tp.constant_kinds
    s = arm.initial()
    one, two = tp.evaluate(s), tp.evaluate(s + 0.05)
    assert one.J_eq is not two.J_eq and not np.array_equal(one.J_eq.data, two.J_eq.data)


def test_calls_too_large_for_one_workspace_are_split(monkeypatch):
    """With room for only a few rows, the calls of a window are planned in smaller buckets (or
    left to run one by one) and give the same numbers."""
    import catalogue as cat

    monkeypatch.setattr(host_levels, "WORKSPACE_FLOATS", 40_000)
    window = WindowProblem(cat.problems("arm_throw")[0].setup().scene)
    s = window.initial() + 0.01 * np.cos(np.arange(window.n_free))
    host = TorchProblem(window, torch.device("cpu"), host_linear=True)
    device = TorchProblem(window, torch.device("cpu"), host_linear=True)
    device.host = False
    for _ in range(2):
        assert np.array_equal(host.evaluate(s).gradient, device.evaluate(s).gradient)
    sizes = [len(p.programs) for t in host.plan.together.values() for p, _ in t.buckets]
    assert sizes and all(p.fits() for t in host.plan.together.values() for p, _ in t.buckets)
    assert len(sizes) > len(host.plan.together)     # split: more buckets than program kinds


def test_programs_run_together_return_rows_where_an_output_is_not_a_row():
    """Random programs run on rows together (calls.Together) give TorchScript's rows, each an
    (n,) float64 array, on every call, including outputs that no row holds (a number, a
    comparison's result: LevelPlan.loose, the only ones the rows' finish converts)."""
    from stw_torch.calls import Together

    programs = [p for p, _, _ in _random_programs(11, 40)][:16]
    lengths = [23, 23, 9, 23] * 4
    loose = 0
    for shift in (0.0, 0.3, -0.2):
        inputs = [_arguments(n, shift) for n in lengths[:len(programs)]]
        times = [values[2] for values in inputs]
        with np.errstate(all="ignore"):
            wants = [_torchscript(p, values) for p, values in zip(programs, inputs)]
            if shift == 0.0:
                got, together = Together.first(programs, inputs, times)
            else:
                got = together.run(inputs)
        for rows, want, n in zip(got, wants, lengths):
            assert all(r.__class__ is np.ndarray and r.shape == (n,) and r.dtype == np.float64 for r in rows)
            assert _same(rows, want)
        loose = sum(len(x) for plan, _ in together.buckets for x in plan.loose)
    assert together.buckets and loose > 0


@pytest.mark.parametrize("name", ["arm_throw", "acrobat", "particle_jet"])
def test_outputs_read_in_place_from_the_rows_are_the_copied_ones(name):
    """From the second evaluation on, local_host and values_host put the programs' arguments in
    their rows from the slot values (calls.RowInputs) and read every output straight from the
    rows into their arrays (calls.RowLayout): the values, the slots' gradient and the second
    derivatives must be those of the arguments copied in and the rows copied out program by
    program, bit for bit, whether an output lies in a row, in the registers (LevelPlan.loose)
    or is a number."""
    window = WindowProblem(catalogue.problems(name)[0].setup().scene)
    tp = TorchProblem(window, torch.device("cpu"), host_linear=True)
    plan = tp.plan
    for k, second in enumerate((True, False) * 2):
        v = tp.host_arrays["v_fixed"] + tp.Pf @ (window.initial() + 0.01 * np.sin(np.arange(window.n_free) + k))
        got = plan.local_host(v, second)
        layout = plan.layouts.get(("full" if second else "first", np.dtype(float)))
        if k >= 2:                                  # the rows are planned at the first call
            assert layout is not None
            kept, plan.layouts = plan.layouts, {key: None for key in plan.layouts}
            want = plan.local_host(v, second)       # the rows copied out, as before
            plan.layouts = kept
            assert all(a is b is None or a.tobytes() == b.tobytes() for a, b in zip(got, want))
            values = plan.values_host(v)           # values alone, the arguments put in place too
            assert plan.layouts[("value", np.dtype(float))] is not None
            kept, plan.layouts = plan.layouts, {key: None for key in plan.layouts}
            assert values.tobytes() == plan.values_host(v).tobytes()
            plan.layouts = kept
        else:
            plan.values_host(v)
    layouts = [layout for layout in plan.layouts.values() if layout is not None]
    if name == "arm_throw":    # two programs' values are not on rows: read from the registers
        assert any(loose for layout in layouts for *_, loose in layout.gathers)
    if name == "particle_jet":   # affine terms: constant gradients, filled in as numbers
        assert any(layout.numbers for layout in layouts)
