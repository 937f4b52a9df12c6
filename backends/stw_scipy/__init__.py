"""stw's reference backend: the paper's SQP (Lagrange–Newton) with sparse linear algebra.

Registered under the entry-point group ``stw_tui.backends`` as ``scipy``, exactly as a third
party's backend would be.
"""

from .sqp import ScipyBackend

__all__ = ["ScipyBackend"]
