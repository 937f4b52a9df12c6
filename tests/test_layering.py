"""The core must not import the UI or torch (DESIGN.md principle 2)."""

import subprocess
import sys


def test_core_imports_neither_textual_nor_torch():
    code = (
        "import sys, stw_tui.session, stw_tui.cli, stw_tui.window, stw_tui.backend, stw_scipy\n"
        "from stw_tui.session import Session\n"
        "s = Session(); s.run_text('dof x\\nconstraint c: x = 1 @ 0\\nobjective o: x\\'\\'\\niterate 2')\n"
        "bad = [m for m in ('textual', 'torch', 'plotext') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
