"""Results kept between `iterate`s (expansions, free symbols, basis matrices, the backend scan)
are only reused where they cannot have changed."""

import numpy as np
import pytest

from stw_tui.session.session import Session
from stw_tui.sos import backend
from stw_tui.sos.spline import DofCurve


def test_redefining_a_subexpression_changes_what_the_next_iterate_solves():
    s = Session()
    s.run_text("time 0 1 knots=6\ndof x\nlet f = x\nconstraint c: f = 1 @ 0.5\n"
               "objective smooth: x''\niterate 10")
    assert s.scene.dofs["x"].curve.evaluate([0.5])[0] == pytest.approx(1.0, abs=1e-9)
    s.execute("let f = 2*x")                    # the same constraint text, a new expansion
    s.execute("iterate 10")
    assert s.scene.dofs["x"].curve.evaluate([0.5])[0] == pytest.approx(0.5, abs=1e-9)


def test_a_kept_basis_is_read_only_and_is_the_curve_s_derivative():
    rng = np.random.default_rng(3)
    curve = DofCurve.uniform(0.0, 2.0, 7).with_coef(rng.standard_normal(10))
    times = np.linspace(0.0, 2.0, 33)
    first, again = curve.basis(times, 2), curve.basis(times, 2)
    assert again is first
    with pytest.raises(ValueError):
        first.data[0] = 1.0
    # The same matrix on another curve with the same knots: the key is the knots, not the curve.
    other = curve.with_coef(rng.standard_normal(10))
    assert other.basis(times, 2) is first
    np.testing.assert_allclose(first @ other.coef, other.evaluate(times, 2), rtol=0, atol=1e-9)


def test_the_backend_scan_is_kept_and_an_unknown_name_scans_again(monkeypatch):
    calls = []
    real = backend.metadata.entry_points

    def counted(**kwargs):
        calls.append(kwargs)
        return real(**kwargs)

    monkeypatch.setattr(backend.metadata, "entry_points", counted)
    backend.forget_installed()
    names = backend.available_backends()
    backend.available_backends()
    assert "scipy" in names and len(calls) == 1
    with pytest.raises(Exception, match="no backend named 'nonesuch'"):
        backend.load_backend("nonesuch")
    assert len(calls) == 2                      # looked again before saying it is not there


def test_forgetting_empties_every_cache_a_window_build_fills():
    from stw_tui.sos import instances, kept, scene, spline, window
    from stw_tui.sym import compiler

    s = Session()
    s.run_text("time 0 1 knots=6\ndof x\nlet f = x^2\nconstraint c: f' = 1 on [0.2, 0.8]\n"
               "objective smooth: x''\niterate 2")
    window.WindowProblem(s.scene)
    assert scene._EXPANDED and spline._kept_basis.cache_info().currsize
    assert compiler.free_symbols.cache_info().currsize and instances._KEPT
    kept.forget()
    assert not scene._EXPANDED and spline._kept_basis.cache_info().currsize == 0
    assert window._plan_set_of.cache_info().currsize == 0
    assert not compiler._CACHE
    assert compiler.free_symbols.cache_info().currsize == 0
    assert compiler._check_size.cache_info().currsize == 0
    assert instances._exact_degree.cache_info().currsize == 0
    assert not instances._KEPT
