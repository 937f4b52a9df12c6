"""Batched solving: many independent solves (a survey's starts) run as one batch by a backend that
can vectorize their numerical work over the batch (the torch backend's ``batch_solver``).

The core stays backend-neutral. A backend offers the capability :attr:`Capability.BATCH` and a
classmethod ``batch_solver(size, options)`` returning a :class:`BatchSolver`;
:func:`batch_backend` finds one by that capability, never by name. The solver runs plain Python
jobs (a start: replay, shake, `iterate`, dense check), each on its own thread, and while a job
runs, every backend the interpreter creates for it is the solver's member backend
(:func:`joined_backend`), whose evaluations and KKT factorizations the solver gathers from all
jobs and computes as one batch. So each job takes exactly the steps of a serial solve, and only
where its numbers are computed changes.
"""

from __future__ import annotations

import contextvars
from abc import ABC, abstractmethod
from typing import Any, Callable, Sequence

from stw_tui.sos.backend import PLUGIN_FAULTS, Backend, available_backends, create_backend, load_backend
from stw_tui.sym.errors import StwError
from stw_tui.sym.kinds import Capability

# Set on a batch job's thread: (backend name, options) -> the member backend to solve with.
_MEMBER: contextvars.ContextVar[Callable[[str, dict], Backend] | None] = contextvars.ContextVar(
    "stw_batch_member", default=None)


def joined_backend(name: str, options: dict[str, Any]) -> Backend:
    """The backend a solve uses: the batch's member backend inside a batch job, else a new
    instance of backend ``name`` with ``options``.

    Raises:
        StwError: an unknown backend or bad options (see :func:`~stw_tui.sos.backend.create_backend`).
    """
    member = _MEMBER.get()
    if member is not None:
        return member(name, options)
    return create_backend(load_backend(name), options)


def batch_backend(preferred: str | None = None) -> type[Backend]:
    """The backend a batch of starts runs on: ``preferred`` (the scene's) if it solves batches
    (:attr:`Capability.BATCH`), else the first installed backend that does, by name. A backend
    that fails to load is passed over.

    Raises:
        StwError: no installed backend solves batches.
    """
    installed = sorted(available_backends())
    for name in ([preferred] if preferred in installed else []) + installed:
        try:
            cls = load_backend(name)
        except StwError:
            continue
        if Capability.BATCH in cls.capabilities:
            return cls
    raise StwError("no installed backend can solve a batch of starts "
                   f"(installed: {', '.join(installed) or 'none'})")


def create_batch_solver(cls: type[Backend], size: int, options: dict[str, Any]) -> "BatchSolver":
    """Backend ``cls``'s batch solver of ``size`` jobs; the backend validates ``options``.

    Raises:
        StwError: bad options, no device to run on, or the plugin raised (SystemExit included).
    """
    try:
        solver = cls.batch_solver(size, options)
    except StwError:
        raise
    except PLUGIN_FAULTS as exc:
        raise StwError(f"backend {cls.name} could not start a batch: {type(exc).__name__}: {exc}") from exc
    if solver is None:
        raise StwError(f"backend {cls.name} cannot solve a batch of starts")
    return solver


def join_batch(member: Callable[[str, dict], Backend]) -> contextvars.Token:
    """Make ``member`` the backend factory of the calling thread's solves (a batch job's first
    call); returns the token that :func:`leave_batch` takes."""
    return _MEMBER.set(member)


def leave_batch(token: contextvars.Token) -> None:
    """Undo :func:`join_batch`."""
    _MEMBER.reset(token)


class BatchSolver(ABC):
    """Runs jobs concurrently and solves their window problems as one batch."""

    @abstractmethod
    def describe(self) -> str:
        """Where the batch runs ("torch batch of 12 on cpu"), for tables and messages."""

    @abstractmethod
    def run(self, jobs: Sequence[Callable[[], Any]], on_done: Callable[[int, Any], None],
            cancelled: Callable[[], bool]) -> None:
        """Run every job, calling ``on_done(index, result)`` in the calling thread as each one
        finishes. Once ``cancelled()`` is true no result is reported and no job is started.
        A job that raises is the job's own business: jobs must catch their errors."""
