"""`stw run` in a process of its own pauses and freezes the cyclic collector around its imports
and before it exits (cli.main.console); main() called inside another program must not."""

import gc
import os
import subprocess
import sys

from stw_tui.cli.main import main

SESSION = "dof x\nconstraint c: x = 1 @ 0\nobjective o: x''\niterate 2\nprint x @ 0.5\n"


def test_main_inside_a_program_leaves_the_collector_alone(tmp_path, capsys):
    path = tmp_path / "s.stw"
    path.write_text(SESSION, encoding="utf-8")
    frozen = gc.get_freeze_count()
    assert main(["run", str(path)]) == 0
    assert gc.isenabled() and gc.get_freeze_count() == frozen
    assert "x @ 0.5" in capsys.readouterr().out


def test_a_process_of_its_own_prints_what_main_prints(tmp_path, capsys):
    path = tmp_path / "s.stw"
    path.write_text(SESSION, encoding="utf-8")
    assert main(["run", str(path)]) == 0
    inside = capsys.readouterr().out
    env = dict(os.environ, STW_CACHE_DIR="off")
    done = subprocess.run([sys.executable, "-m", "stw_tui.cli.main", "run", str(path)], env=env,
                          capture_output=True, text=True, check=True)

    def without_times(text):   # the iteration table's last column is milliseconds
        return [line.rsplit(None, 1)[0] if line[:5].strip().isdigit() else line
                for line in text.splitlines()]
    assert without_times(done.stdout) == without_times(inside)


def _run_in_own_process(script: str) -> list[str]:
    done = subprocess.run([sys.executable, "-c", script], env=dict(os.environ, STW_CACHE_DIR="off"),
                          capture_output=True, text=True, check=True)
    return done.stdout.strip().splitlines()


def test_a_process_of_its_own_never_runs_the_numpy_subpackages_scipy_only_lists(tmp_path):
    """scipy.sparse's array-API shim reads every name of numpy: numpy.f2py, testing and ctypeslib
    stay deferred through a whole `stw run` (lazy_numpy), and load on first use."""
    path = tmp_path / "s.stw"
    path.write_text(SESSION, encoding="utf-8")
    lines = _run_in_own_process(
        "import sys\n"
        "import stw_tui.cli.main as cli\n"
        "cli._OWN_PROCESS = True\n"
        f"assert cli.main(['run', {str(path)!r}]) == 0\n"
        "import scipy.sparse\n"
        "print(sorted(m for m in ('numpy.f2py', 'numpy.testing', 'numpy.ctypeslib')\n"
        "             if type(sys.modules[m]).__name__ != '_LazyModule'))\n"
        "import numpy\n"
        "numpy.testing.assert_allclose([1.0], [1.0])\n"
        "from numpy.f2py import crackfortran\n"
        "print(type(sys.modules['numpy.testing']).__name__, callable(crackfortran.crackfortran))\n")
    assert lines[-2:] == ["[]", "module True"]


def test_main_inside_a_program_defers_no_numpy_subpackage():
    lines = _run_in_own_process(
        "import sys\n"
        "from stw_tui.cli.main import _long_lived_imports\n"
        "with _long_lived_imports():\n"
        "    import scipy.sparse\n"
        "print(type(sys.modules['numpy.f2py']).__name__)\n")
    assert lines[-1] == "module"


def test_a_reader_that_leaves_early_gets_no_traceback():
    """`stw backends | head -1`: the pipe closes before stw writes; it ends quietly, with the
    status a shell gives a command that SIGPIPE ended."""
    child = subprocess.Popen([sys.executable, "-m", "stw_tui.cli.main", "backends"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    child.stdout.close()           # the reader is gone before the plugins are loaded
    error = child.stderr.read().decode()
    assert child.wait(timeout=60) == 141
    assert "Traceback" not in error and "BrokenPipeError" not in error, error


def test_run_with_a_backend_that_is_not_there_says_so_and_runs_nothing(tmp_path, capsys):
    path = tmp_path / "s.stw"
    path.write_text(SESSION, encoding="utf-8")
    assert main(["run", str(path), "--backend", "nosuch"]) == 2
    captured = capsys.readouterr()
    assert "--backend nosuch: no backend named 'nosuch' (installed:" in captured.err
    assert "Traceback" not in captured.err and captured.out == ""
    assert main(["run", str(path), "--backend", "scipy solver=bogus"]) == 2
    assert "option solver: 'bogus' is not one of" in capsys.readouterr().err


def test_the_tui_lets_textual_draw_120_frames_a_second_unless_the_user_says_otherwise(tmp_path):
    # A key's echo waits for the screen's next frame (cli/main.py TUI_FPS). The setting must be in
    # the environment before the TUI's first import of Textual, which reads it then: `stw` on a
    # missing file has imported the app when it refuses the file.
    script = ("import sys; from stw_tui.cli.main import _launch_tui\n"
              f"assert _launch_tui([{str(tmp_path / 'missing.stw')!r}]) == 2\n"
              "import textual.constants; print(textual.constants.MAX_FPS)\n")
    env = {k: v for k, v in os.environ.items() if k != "TEXTUAL_FPS"}
    ran = [subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=dict(env, **extra))
           for extra in ({}, {"TEXTUAL_FPS": "30"})]
    assert [r.stdout.strip() for r in ran] == ["120", "30"], [r.stderr for r in ran]
