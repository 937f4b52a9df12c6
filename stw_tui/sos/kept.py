"""Results kept in memory between `iterate`s, and a way to forget them all.

Every `iterate` needs the window problem of the scene as it is now; the parts that depend only
on what did not change are kept where they are made: subexpression expansions (scene.py), free
symbols, passed size checks and the disk cache's checked directories (compiler.py), exact
degrees and the relations' instance and check-grid times (instances.py), B-spline basis
matrices (spline.py), product plans and whole window problems by structure (window.py). Each
is keyed by everything it depends on. (A backend keeps its own: the scipy backend's
factorization plans pass from one `iterate`'s algebra to the next, backends/stw_scipy/linear.py.)
:func:`forget` empties them, for a benchmark that times a build from nothing but the compiled
terms on disk, as a new process would do it.
"""

from __future__ import annotations


def forget() -> None:
    """Empty every in-memory cache of window building (the compiled terms' own cache included)."""
    from stw_tui.sos import instances, scene, spline, window
    from stw_tui.sym import compiler

    with scene._EXPANDED_LOCK:
        scene._EXPANDED.clear()
    spline._kept_basis.cache_clear()
    spline._kept_nonzero_basis.cache_clear()
    window._plan_set_of.cache_clear()
    window.forget_builds()
    compiler.free_symbols.cache_clear()
    compiler._check_size.cache_clear()
    instances._exact_degree.cache_clear()
    with instances._KEPT_LOCK:
        instances._KEPT.clear()
    compiler._SAFE_ROOTS.clear()   # the disk cache's checks: made again once, as in a new process
    with compiler._CACHE_LOCK:
        compiler._CACHE.clear()
