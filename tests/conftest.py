import os
import platform
import signal
import subprocess
from importlib import metadata
from pathlib import Path


def _pin_blas_kernels() -> None:
    """Have OpenBLAS (numpy's and scipy's) use its Haswell (AVX2) kernels on any x86-64 CPU that has
    them. It otherwise picks kernels by CPU, and AVX-512 ones round differently in the last bits:
    the snapshots (tests/__snapshots__) show rounding-level figures such as a violation of 7e-15,
    recorded with these kernels. Read once, when OpenBLAS loads: this runs before numpy is imported."""
    if platform.machine() != "x86_64" or "OPENBLAS_CORETYPE" in os.environ:
        return
    try:
        flags = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return
    if " avx2" in flags and " fma" in flags:
        os.environ["OPENBLAS_CORETYPE"] = "Haswell"


_pin_blas_kernels()

import pytest  # noqa: E402 - after the kernels are pinned

import catalogue  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SESSIONS = ROOT / "sessions"
# Lines after which the particle jet's `iterate N` runs all N iterations (until stopped): tolerances
# no solve meets, and steps of at most 1e-6 per control point, its motion being of unit size.
# (Uncapped, the solve reaches its optimum in one step and its rounding floor a few later, where a
# step that no longer lowers the merit ends it as stalled.)
ENDLESS = "set tol_violation 0\nset tol_kkt 0\nset tol_step 0\nbackend scipy max_step=1e-6\n"


def popen_foreground(args: list[str], **kwargs) -> subprocess.Popen:
    """``subprocess.Popen(args, **kwargs)`` with SIGINT at its default in the child, as a terminal's
    foreground job has it, for tests that press Ctrl+C. An ignored signal stays ignored through
    exec, and a background job of a non-interactive shell (`pytest &` in a script, `nohup … &`)
    ignores SIGINT: Python then leaves it ignored and the child never sees Ctrl+C. A handled
    signal is reset to its default by exec, so this process handles it while it starts the child."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return subprocess.Popen(args, **kwargs)
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.fixture
def session():
    from stw_tui.session.session import Session

    return Session()


def run_lines(session, text: str):
    """Execute a block of session text on ``session`` and return it."""
    session.run_text(text)
    return session


@pytest.fixture
def registered(monkeypatch):
    """Make `backend NAME` work for every in-tree backend whose library is installed, whether or
    not the distribution's entry points are installed yet (a checkout installed before the
    backend existed)."""
    import importlib.util

    import stw_tui.sos.backend as backend_module

    if importlib.util.find_spec("stw_scipy") is None:   # the backend packages, from the checkout
        monkeypatch.syspath_prepend(str(ROOT / "backends"))
    real = backend_module.available_backends

    def with_in_tree():
        found = dict(real())
        for name in catalogue.installed_backends():
            found.setdefault(name, metadata.EntryPoint(name, catalogue.IN_TREE[name][0],
                                                       backend_module.ENTRY_POINT_GROUP))
        return found

    monkeypatch.setattr(backend_module, "available_backends", with_in_tree)


@pytest.fixture(params=catalogue.problems(), ids=str)
def any_problem(request) -> catalogue.Problem:
    """Each problem of the catalogue in turn."""
    return request.param


@pytest.fixture(params=catalogue.installed_backends())
def any_backend(request, registered) -> str:
    """Each installed backend's name in turn (registered, so `backend NAME` works)."""
    return request.param
