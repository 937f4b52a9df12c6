"""Many starts solved as one batch on torch (``TorchBackend.batch_solver``): the torch backend's
:class:`~stw_tui.sos.batch.BatchSolver`.

Each start (a job: replay, shake, `iterate`, dense check) runs the shared SQP on a thread of its
own, with a member backend (backend.BatchMember) that requests its heavy numerical work from the
batch: evaluations (evaluate.evaluations_of), merit values and, with ``linear=torch`` (the default
on cuda), LU factorizations and solves of KKT systems and the curvature control's Cholesky tests.
The calling thread serves the requests in lockstep rounds: once every running start waits on one,
it computes each kind for all of them at once (one call of each term's program; LU on a (B, n, n)
stack) and wakes them. On the CPU (``linear=scipy``) each start factorizes its own sparse KKT
systems: dense batched LU cost more than SuperLU's banded solves (arm throw, 4 starts: 36 s
against 23 s). Not one SQP vectorized over starts: its control flow differs per start; here each
takes exactly a serial solve's steps.

Determinism: a round holds one request of every running start, starts join only between rounds,
and requests are served in start order, so the batches do not depend on thread timing. Isolation:
a batched computation that raises is redone request by request, so an error is its start's alone.
"""

from __future__ import annotations

import threading
from typing import Any, Callable, Sequence

import torch

from stw_tui.sos.batch import BatchSolver, join_batch, leave_batch
from stw_tui.sos.sqp.algebra import KKTSystem, SingularSystem
from stw_tui.sym.errors import StwError

from .evaluate import TorchProblem, evaluations_of, merit_values_of
from .linalg import DenseAlgebra, kkt_matrix
from .lowerings import Lowerings


class Cancelled(StwError):
    """The batch was cancelled: the start's solve ends here."""


class _Request:
    __slots__ = ("job", "kind", "key", "payload", "result", "error", "done")

    def __init__(self, job: int, kind: str, key: Any, payload: Any):
        self.job, self.kind, self.key, self.payload = job, kind, key, payload
        self.result = self.error = None
        self.done = False


def _factor(Ks: list[torch.Tensor]) -> list[tuple]:
    LU, pivots, info = torch.linalg.lu_factor_ex(torch.stack(Ks))
    return [(LU[b], pivots[b], int(info[b])) for b in range(len(Ks))]


def _solve(items: list[tuple]) -> list[torch.Tensor]:
    LU = torch.stack([lu for lu, _, _ in items])
    pivots = torch.stack([p for _, p, _ in items])
    rhs = torch.stack([r for _, _, r in items]).unsqueeze(-1)
    x = torch.linalg.lu_solve(LU, pivots, rhs).squeeze(-1)
    return list(x.unbind(0))


def _positive_definite(Ms: list[torch.Tensor]) -> list[bool]:
    info = torch.linalg.cholesky_ex(torch.stack(Ms)).info
    return [bool(i == 0) for i in info.tolist()]


# kind -> (the batched computation of a list of payloads, the payload's batching key)
_KINDS: dict[str, Callable[[list], list]] = {
    "evaluate": lambda items: evaluations_of([tp for tp, _ in items], [s for _, s in items]),
    "merit": lambda items: merit_values_of([tp for tp, _ in items], [s for _, s in items]),
    "factor": _factor,
    "solve": _solve,
    "cholesky": _positive_definite,
}


class TorchBatch(BatchSolver):
    """Up to ``size`` jobs at once, their numbers computed in lockstep rounds on ``device``.

    ``member(batch, job, **options)`` makes the backend of a start (the torch backend's
    BatchMember), which asks the batch for its :meth:`algebra` and :meth:`evaluator`; ``linear``
    says where KKT systems are solved: dense LU on the device, batched over starts ("torch", the
    default on cuda), or each start's own sparse factorization on the host ("scipy", the default
    on the CPU, where it measured faster: banded KKT systems of a few hundred rows)."""

    def __init__(self, size: int, device: torch.device, options: dict[str, Any], linear: str,
                 member: Callable[..., Any]):
        self.size = max(1, int(size))
        self.device = device
        self.options = dict(options)
        self.linear = linear
        self._member = member
        self.rounds = 0            # rounds served in the last run (the benchmark shows it)
        self._cond = threading.Condition()
        self._pending: dict[int, _Request] = {}
        self._running: set[int] = set()
        self._finished: list[tuple[int, Any]] = []
        self._cancelled = False
        self._lowerings = Lowerings()     # shared by the starts of a structure

    def describe(self) -> str:
        """Where the batch runs."""
        return f"torch batch of up to {self.size} on {self.device.type}" + \
            (", sparse KKT solves on the host" if self.linear == "scipy" else "")

    # --- a job's side --------------------------------------------------------------------------
    def request(self, job: int, kind: str, key: Any, payload: Any) -> Any:
        """Hand one computation to the batch and wait for its result (on a job's thread)."""
        request = _Request(job, kind, key, payload)
        with self._cond:
            if self._cancelled:
                raise Cancelled("the survey was cancelled")
            self._pending[job] = request
            self._cond.notify_all()
            while not request.done:
                self._cond.wait()
        if request.error is not None:
            raise request.error
        return request.result

    def member(self, job: int) -> Callable[[str, dict], Any]:
        """The backend factory of job ``job``: the scene's SQP options, solved in this batch."""
        def make(name: str, options: dict):
            known = {o.name for o in self._member.options} - {"device", "linear"}
            chosen = {k: v for k, v in {**self.options, **options}.items() if k in known}
            return self._member(self, job, **chosen)
        return make

    def algebra(self, job: int) -> "BatchAlgebra":
        """Job ``job``'s dense algebra on the device (linear=torch), its solves in the rounds."""
        return BatchAlgebra(self, job)

    def evaluator(self, job: int, problem) -> "BatchEvaluator":
        """Job ``job``'s evaluator of ``problem``, its evaluations in the rounds. Starts whose
        problems have the same structure share one lowering (building an arm's took 0.45 s, per
        start and solve) and batch together."""
        tp, key = self._lowerings.get(problem, self.device, self.linear == "scipy")
        return BatchEvaluator(self, job, tp, key)

    def _job(self, index: int, job: Callable[[], Any]) -> None:
        token = join_batch(self.member(index))
        try:
            result = job()
        except BaseException as exc:  # noqa: BLE001 - jobs catch their own errors; never hang the batch
            result = exc
        finally:
            leave_batch(token)
            with self._cond:
                self._running.discard(index)
                self._pending.pop(index, None)
                self._finished.append((index, result))
                self._cond.notify_all()

    # --- the calling thread's side -----------------------------------------------------------
    def run(self, jobs: Sequence[Callable[[], Any]], on_done: Callable[[int, Any], None],
            cancelled: Callable[[], bool]) -> None:
        """Run the jobs, at most ``size`` at a time, serving their requests in rounds."""
        if self.device.type == "cpu":
            torch.set_num_threads(1)   # small batched work on 2 cores: threads cost ~50x (DESIGN.md)
        self.rounds, self._cancelled = 0, False
        threads: list[threading.Thread] = []
        try:
            self._loop(jobs, on_done, cancelled, threads)
        finally:   # also when on_done raised: fail the jobs' requests, so that none waits for ever
            with self._cond:
                if self._running:
                    self._cancel()
            for thread in threads:
                thread.join()

    def _loop(self, jobs, on_done, cancelled, threads: list) -> None:
        waiting = list(range(len(jobs)))
        while True:
            with self._cond:
                while not self._wakes():
                    self._cond.wait(timeout=0.2)
                    if cancelled() and not self._cancelled:
                        self._cancel()
                finished, self._finished = self._finished, []
                idle = not self._running
                round_ = [] if finished or idle else sorted(self._pending.values(), key=lambda r: r.job)
            if idle and not finished and (not waiting or self._cancelled):
                return
            for index, result in sorted(finished, key=lambda item: item[0]):
                if not self._cancelled:
                    on_done(index, result)
            if cancelled() and not self._cancelled:
                with self._cond:
                    self._cancel()
            if round_:
                self._serve(round_)
                continue
            # Jobs start only between rounds: which starts share a round depends on nothing else.
            while waiting and len(self._running) < self.size and not self._cancelled:
                index = waiting.pop(0)
                with self._cond:
                    self._running.add(index)
                thread = threading.Thread(target=self._job, args=(index, jobs[index]),
                                          name=f"stw-batch-{index}", daemon=True)
                threads.append(thread)
                thread.start()

    def _wakes(self) -> bool:
        """Whether the calling thread has work: a job finished, every running job waits on a
        request (a round), or none runs (start some, or stop). The lock is held."""
        return bool(self._finished or not self._running or len(self._pending) == len(self._running))

    def _cancel(self) -> None:
        """Fail every waiting request and every later one (the lock is held)."""
        self._cancelled = True
        for request in self._pending.values():
            request.error, request.done = Cancelled("the survey was cancelled"), True
        self._pending.clear()
        self._cond.notify_all()

    def _serve(self, requests: list[_Request]) -> None:
        """Compute one round: each (kind, key) group at once, then wake the jobs."""
        self.rounds += 1
        groups: dict[tuple, list[_Request]] = {}
        for request in requests:
            groups.setdefault((request.kind, request.key), []).append(request)
        for (kind, _), members in groups.items():
            compute = _KINDS[kind]
            try:
                results = compute([r.payload for r in members])
                for r, value in zip(members, results):
                    r.result = value
            except Exception:  # one start's bad numbers: redo one by one, so only it fails
                for r in members:
                    try:
                        r.result = compute([r.payload])[0]
                    except Exception as exc:  # noqa: BLE001 - the start's driver reports it
                        r.error = exc
        with self._cond:
            for r in requests:
                r.done = True
                self._pending.pop(r.job, None)
            self._cond.notify_all()


# --- a start's view of the batch ---------------------------------------------------------------
class BatchKKT(KKTSystem):
    """K = [[H, Aᵀ], [A, -diag(e)]] factorized and solved in the batch's rounds."""

    def __init__(self, batch: TorchBatch, job: int, H: torch.Tensor, A: torch.Tensor, e):
        K = kkt_matrix(H, A, e)
        self.batch, self.job = batch, job
        self.LU, self.pivots, info = batch.request(job, "factor", ("factor", K.shape), K)
        if info > 0:
            raise SingularSystem("KKT matrix is exactly singular")
        self.iterations, self.fallbacks = 1, 0

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        return self.batch.request(self.job, "solve", ("solve", self.LU.shape), (self.LU, self.pivots, rhs))


class BatchAlgebra(DenseAlgebra):
    """Dense torch algebra whose factorizations and Cholesky tests go through the batch."""

    def __init__(self, batch: TorchBatch, job: int):
        super().__init__(batch.device)
        self.batch, self.job = batch, job

    def kkt(self, H, A, e, exact=False):
        return BatchKKT(self.batch, self.job, H, A, e)

    def positive_definite(self, m):
        return self.batch.request(self.job, "cholesky", ("cholesky", m.shape), m)


class BatchEvaluator:
    """A start's window problem on torch, evaluated in the batch's rounds."""

    def __init__(self, batch: TorchBatch, job: int, tp: TorchProblem, key: str):
        self.batch, self.job, self.tp, self.key = batch, job, tp, key
        self.damping = tp.damping

    def evaluate(self, s):
        """:meth:`TorchProblem.evaluate`, batched with the other starts' (second derivatives
        always: the starts of a round disagree on whether they will use them)."""
        return self.batch.request(self.job, "evaluate", ("evaluate", self.key), (self.tp, s))

    def merit_values(self, s):
        """:meth:`TorchProblem.merit_values`, batched with the other starts'."""
        return self.batch.request(self.job, "merit", ("merit", self.key), (self.tp, s))
