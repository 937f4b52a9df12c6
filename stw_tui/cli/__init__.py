"""The ``stw`` command and its headless tools (run, compare, bench, survey). The TUI is imported only
when ``stw`` opens it."""
