"""`stw run` exits 0 only when every solve converged and the motion holds between the samples;
other outcomes have the codes the README documents (issue 54, item 11). The compiled-term
cache lives under XDG_CACHE_HOME when it is set."""

import pytest

from stw_tui.cli.main import main
from stw_tui.sym import compiler

HEAD = "time 0 1 knots=4\ndof x\n"
CASES = {
    0: HEAD + "constraint a: x = 0 @ 0\nconstraint b: x = 1 @ 1\nobjective e: x''\niterate 20\n",
    2: HEAD + "constraint a: x = nope @ 0\n",
    3: HEAD + "constraint a: x = 0 @ 0.5\nconstraint b: x = 1 @ 0.5\nobjective e: x''\niterate 20\n",
    4: "time 0 1 knots=6\ndof x\nconstraint a: sin(x) = 0.5 @ 0\nconstraint b: x^3 = 2 @ 1\n"
       "objective e: x''\niterate 1\n",
    5: HEAD + "set adaptive off\nconstraint a: x = sin(9*t) on [0, 1] samples=3\nobjective e: x''\niterate 30\n",
}


@pytest.mark.parametrize("code", sorted(CASES))
def test_exit_code_says_what_became_of_the_solves(code, tmp_path, capsys):
    path = tmp_path / "s.stw"
    path.write_text(CASES[code])
    assert main(["run", str(path)]) == code
    err = capsys.readouterr().err
    assert {0: err == "", 2: "nope" in err, 3: "cannot be met" in err, 4: "iteration limit" in err,
            5: "fails between the samples" in err}[code], err


def test_the_term_cache_lives_under_xdg_cache_home(tmp_path, monkeypatch):
    monkeypatch.delenv("STW_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    root = compiler._cache_root()
    assert root is not None and root[0] == tmp_path / "stw" / "terms"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/cache")    # the XDG spec ignores a relative one
    assert compiler._user_cache().endswith(".cache")
