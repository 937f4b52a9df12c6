"""Short full garbage collections in the TUI process: the long-lived heap is frozen.

Python's full (generation 2) collection walks every tracked object. The TUI process holds about
150,000 of them once a session is loaded (numpy, scipy, sympy, Textual, the scene's terms), and a
collection, triggered by the plots' and reports' allocations while a solve runs, then held the UI
thread for 40-110 ms (measured with gc.callbacks in tmux on basketball): the keys pressed meanwhile
waited, which was the long tail of echo, F2 and F3 (p95 25-128 ms, medians 3-18). Objects that
live past a command are nearly all there to stay, so after each command the heap is collected and
frozen (``gc.freeze``: moved to a generation that collections skip); a full collection then walks
only what was made since, a few thousand objects (3-4 ms).

A frozen object that later becomes part of unreachable cycle is not reclaimed while frozen, so the
whole heap is unfrozen and collected again whenever the frozen part has grown by
``regrowth`` since the last time: that full walk costs in proportion to the heap and comes ever
more rarely (as a list's doubling does), and the garbage kept frozen stays under that fraction.
"""

from __future__ import annotations

import gc

REGROWTH = 1.0   # the frozen heap may grow by this fraction of itself before a full collection


class HeapSettler:
    """Collects and freezes the heap after each command (:meth:`settle`, in any thread)."""

    def __init__(self, regrowth: float = REGROWTH):
        self.regrowth = regrowth
        self.full_at: int | None = None   # the frozen count after the last full collection

    def settle(self) -> None:
        """Collect what is unfrozen and freeze what survives; then the whole heap if the frozen part
        has grown by ``regrowth`` since the last full collection (and the first time)."""
        if self.full_at is not None:
            gc.collect()
            gc.freeze()
            if gc.get_freeze_count() <= (1.0 + self.regrowth) * self.full_at:
                return
        gc.unfreeze()
        gc.collect()
        gc.freeze()
        self.full_at = gc.get_freeze_count()
