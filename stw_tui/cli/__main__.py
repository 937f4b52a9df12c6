"""``python -m stw_tui.cli``: the same as the ``stw`` command."""
import sys

from stw_tui.cli.main import main

sys.exit(main())
