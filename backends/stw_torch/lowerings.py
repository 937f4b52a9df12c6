"""Window problems lowered to torch, kept by structure for the next solve of the same structure.

Lowering a window problem (its programs and the fixed sparse patterns of its Jacobians and
Hessian) costs far more than a solve's iteration: basketball's 2 s, against 40 ms. It depends on
everything of the problem but its control points (``problem_key``), so the starts of a survey
share one (batch.py), and so do a user's `iterate`s of one window in a row: each builds its window
problem anew from the scene, and while nothing but the curves changed, the lowering is the same.
"""

from __future__ import annotations

import hashlib
import threading

import numpy as np
import torch

from .evaluate import TorchProblem


def problem_key(problem, device: torch.device, host_linear: bool) -> str:
    """A digest of everything of a window problem but its control points: problems with equal
    keys share one lowering (:meth:`TorchProblem.with_problem`) and batch together. Compiled terms
    are named by identity (the core caches them, so the starts of a survey share them; printing
    an arm's torque expressions to hash them took 0.3 s)."""
    h = hashlib.sha256(repr((str(device), host_linear, type(problem.Pf).__name__, problem.Pf.shape,
                             sorted(problem.row_counts.items()))).encode())
    Pf = problem.Pf
    for array in (Pf.indptr, Pf.indices, Pf.data) if hasattr(Pf, "indptr") else (Pf.toarray(),):
        h.update(np.ascontiguousarray(array).tobytes())
    h.update(np.asarray(problem.free, np.int64).tobytes())
    h.update(np.ascontiguousarray(problem.damping, float).tobytes())
    for g in problem.groups:
        leaves = [(str(node), id(term), offset, tuple(problem.term_parameters(term)))
                  for node, term, offset in g.condition.leaves] if g.condition is not None else []
        h.update(repr((g.label, str(g.kind), g.n, g.slot_offset, g.row_offset, id(g.term),
                       tuple(float(p) for p in g.params),
                       str(g.condition.tree) if g.condition is not None else "", leaves)).encode())
        h.update(np.ascontiguousarray(g.times, float).tobytes())
        h.update(np.ascontiguousarray(g.weights, float).tobytes())
    return h.hexdigest()


# The lowerings kept: a user's `iterate`s of one window in a row find theirs, and so do the rounds
# of an adaptive `iterate`, each a structure of its own (point_mass_2d's 4: with 2 kept, every
# `iterate` lowered them again, 17.8 against 10.6 ms), and the starts of a survey.
KEPT = 8
# What the kept lowerings may hold together, in stored entries of their Jacobian and Hessian
# patterns (values and indices: about 12 bytes each): basketball's is 4.7 million, the other
# bundled sessions' 0.001-0.8 million. The one just used is kept whatever its size.
KEPT_ENTRIES = 16_000_000


class Lowerings:
    """The last ``kept`` lowerings, by structure (least recently used dropped first), as long as
    their patterns hold KEPT_ENTRIES entries at most together."""

    def __init__(self, kept: int = KEPT):
        self.kept = kept
        self._by_key: dict[tuple, TorchProblem] = {}
        self._lock = threading.Lock()   # held while one is built: starts of a survey wait for it

    def get(self, problem, device: torch.device, host_linear: bool, autograd: bool = False,
            ) -> tuple[TorchProblem, str]:
        """``problem`` lowered, and its ``problem_key``. Every caller, the first too, takes the
        fixed slot values the same way (``with_problem``): the numbers do not depend on which
        problem happened to build the lowering."""
        key = problem_key(problem, device, host_linear)
        with self._lock:
            template = self._by_key.pop((key, autograd), None)
            if template is None:
                while len(self._by_key) >= self.kept:
                    self._by_key.pop(next(iter(self._by_key)))
                template = TorchProblem(problem, device, host_linear, autograd)
            self._by_key[(key, autograd)] = template   # the most recently used last
            while len(self._by_key) > 1 and sum(t.entries() for t in self._by_key.values()) > KEPT_ENTRIES:
                self._by_key.pop(next(iter(self._by_key)))
        return template.with_problem(problem), key

    def clear(self) -> None:
        """Forget every lowering (what they hold: compiled terms and large index arrays)."""
        with self._lock:
            self._by_key.clear()
