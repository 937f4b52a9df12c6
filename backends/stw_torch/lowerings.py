"""Window problems lowered to torch, kept by structure for the next solve of the same structure.

Lowering a window problem (its programs and the fixed sparse patterns of its Jacobians and
Hessian) costs far more than a solve's iteration: basketball's 2 s, against 40 ms. It depends on
everything of the problem but its control points (``problem_key``), so the starts of a survey
share one (batch.py), and so do a user's `iterate`s of one window in a row: each builds its window
problem anew from the scene, and while nothing but the curves changed, the lowering is the same.
"""

from __future__ import annotations

import threading

import torch

from .batch_evaluate import problem_key
from .evaluate import TorchProblem


# The lowerings kept: a user's `iterate`s of one window in a row find theirs (basketball: 2 s of
# lowering and patterns once, not at every solve), and so do the rounds of an adaptive `iterate`,
# each a structure of its own (point_mass_2d's 4: with 2 kept, every `iterate` lowered them
# again, 17.8 against 10.6 ms), and the starts of a survey.
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
