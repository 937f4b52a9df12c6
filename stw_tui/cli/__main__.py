"""``python -m stw_tui.cli``: the same as the ``stw`` command."""
from stw_tui.cli.main import console

console()
