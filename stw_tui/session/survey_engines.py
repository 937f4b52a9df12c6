"""Engines that run a survey's starts, and :func:`run_survey`, which streams their results.

* :class:`SerialEngine`: one start after another in this process (the baseline of the benchmark).
* :class:`PoolEngine`: a local pool of worker processes (``concurrent.futures``), the default when
  Dask is not installed. A worker process that dies breaks the pool: a new pool takes over the
  unfinished starts (each start at most ``MAX_ATTEMPTS`` times), and the loss is reported.
* :class:`BatchEngine`: the starts as one batch on a backend that solves batches (the torch
  backend: vectorized over starts, on cuda when torch sees a GPU), in this process; the backend
  plugin supplies the batch solver, and is found by that capability, not by name.
* :class:`DaskEngine`: an embedded ``dask.distributed.LocalCluster`` (one single-threaded worker
  process per core), or an existing cluster at a scheduler address. Dask itself reschedules the
  tasks of a lost worker; the engine reports the loss.

Every engine calls ``on_result`` in the caller's thread as each start finishes, ``on_note`` with
what the user should know (a lost worker), and stops submitting once ``cancelled()`` is true.
Tasks are plain text (:class:`~stw_tui.session.survey.StartTask`), so any engine can run them anywhere.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import importlib.util
import itertools
import logging
import os
import socket
import struct
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Callable

from stw_tui.session.child_process import pool_worker, process_context, quiet_child
from stw_tui.session.survey import (StartResult, StartTask, SurveyPlan, SurveyTable, plan_tasks, replay_base,
                                   solve_start)
from stw_tui.sym.errors import StwError

HANDSHAKE_BYTES = 1 << 16   # a Dask scheduler's greeting is ~60 bytes; more is not one
HANDSHAKE_S = 10.0          # how long a scheduler may take to connect and greet
MAX_ATTEMPTS = 2      # a start whose worker dies this many times is counted as lost
POLL_S = 0.2          # how often a waiting engine looks at cancellation and the workers
DASK_POLL_S = 0.05    # the same for Dask, whose few starts submitted ahead must not run out meanwhile
AHEAD_PER_WORKER = 16  # starts submitted to a Dask cluster ahead of its results, per worker thread

OnResult = Callable[[StartResult], None]
OnNote = Callable[[str], None]
Cancelled = Callable[[], bool]


def dask_available() -> bool:
    """Whether dask.distributed is installed (found, not imported: importing it takes a second)."""
    return importlib.util.find_spec("distributed") is not None


def _lost(task: StartTask, why: str) -> StartResult:
    return StartResult(task.index, task.seed, task.lines, "lost", error=why)


class SerialEngine:
    """Each start in turn, in this process."""

    def describe(self) -> str:
        """Where the starts run, for the table and messages."""
        return "serial in this process"

    def run(self, tasks: list[StartTask], on_result: OnResult, on_note: OnNote, cancelled: Cancelled) -> None:
        """Solve the starts one after another, reporting each result."""
        for task in tasks:
            if cancelled():
                return
            on_result(solve_start(task))


class PoolEngine:
    """A local pool of ``workers`` processes (forked from a clean server, or spawned: no state of
    this process, and none of its threads, leak into them)."""

    def __init__(self, workers: int | None = None):
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.processes: list[int] = []    # the pids of the current pool (tests kill one)

    def describe(self) -> str:
        """Where the starts run, for the table and messages."""
        return f"local pool of {self.workers} process{'es' if self.workers > 1 else ''}"

    def run(self, tasks: list[StartTask], on_result: OnResult, on_note: OnNote, cancelled: Cancelled) -> None:
        """Solve the starts on the pool, retrying those whose worker died in a new pool."""
        pending = {t.index: t for t in tasks}
        attempts = dict.fromkeys(pending, 0)
        context = process_context()
        while pending and not cancelled():
            # (a worker from the fork server ends with stw, even one held in C: child_process.end_with_parent)
            pool = ProcessPoolExecutor(self.workers, mp_context=context, initializer=pool_worker,
                                       initargs=(context.get_start_method() == "forkserver",))
            broken = self._drain(pool, pending, on_result, cancelled)
            pool.shutdown(wait=not cancelled(), cancel_futures=True)
            if not broken:
                continue
            for index in broken:
                attempts[index] += 1
                if attempts[index] >= MAX_ATTEMPTS:
                    on_result(_lost(pending.pop(index), f"its worker process died {attempts[index]} times"))
            on_note(f"a worker process died; {len(pending)} unfinished start(s) go to a new pool")

    def _drain(self, pool, pending: dict, on_result: OnResult, cancelled: Cancelled) -> list[int]:
        """Run the pending tasks on ``pool``; the indexes of those a dead worker broke."""
        futures = {pool.submit(solve_start, task): index for index, task in pending.items()}
        self.processes = [p.pid for p in getattr(pool, "_processes", {}).values()]
        waiting, broken = set(futures), []
        while waiting:
            if cancelled():
                return []
            done, waiting = wait(waiting, timeout=POLL_S, return_when=FIRST_COMPLETED)
            self.processes = [p.pid for p in (getattr(pool, "_processes", None) or {}).values()]
            for future in sorted(done, key=futures.get):
                index = futures[future]
                try:
                    result = future.result()
                except BrokenProcessPool:
                    broken.append(index)
                    continue
                pending.pop(index)
                on_result(result)
        return broken


BATCH_SIZE = 64       # starts a batch solves at once by default (more wait for a place)


class BatchEngine:
    """The starts as one batch on a backend that solves batches (the torch backend: vectorized
    evaluations and batched KKT factorizations, on cuda when torch sees a GPU), in this process.
    Each start still replays, shakes, solves and is checked densely as in :func:`solve_start`.

    Args:
        size: starts solved at once (None: :data:`BATCH_SIZE`).
        backend: the scene's backend, and ``options`` its options: used if it solves batches;
            otherwise the first installed backend that does, with its defaults
            (:func:`~stw_tui.sos.batch.batch_backend`).
    """

    def __init__(self, size: int | None = None, backend: str | None = None, options: dict | None = None):
        self.size = size
        self.backend = backend
        self.options = dict(options or {})
        self._solver = None

    def solver(self):
        """The backend's batch solver (made on first use).

        Raises:
            StwError: no installed backend solves batches, bad options, or no device to run on.
        """
        from stw_tui.sos.batch import batch_backend, create_batch_solver

        if self._solver is None:
            cls = batch_backend(self.backend)
            options = self.options if cls.name == self.backend else {}
            self._solver = create_batch_solver(cls, self.size or BATCH_SIZE, options)
        return self._solver

    def describe(self) -> str:
        """Where the starts run, for the table and messages."""
        return self.solver().describe()

    def run(self, tasks: list[StartTask], on_result: OnResult, on_note: OnNote, cancelled: Cancelled) -> None:
        """Solve the starts as one batch, reporting each result as its start finishes."""
        solver = self.solver()
        if tasks:   # replay the session once here, not on every start's thread at once
            replay_base(tasks[0])
        solver.run([functools.partial(solve_start, task) for task in tasks],
                   lambda index, result: on_result(result if isinstance(result, StartResult) else
                                                    _failed(tasks[index], result)), cancelled)


def _failed(task: StartTask, error: BaseException) -> StartResult:
    return StartResult(task.index, task.seed, task.lines, "failed",
                       error=f"internal error ({type(error).__name__}: {error})")


# One embedded cluster per worker count, kept for the next survey and closed at exit.
_CLUSTERS: dict[int, object] = {}


def close_local_clusters() -> None:
    """Close the embedded clusters (at exit, or when a command is done with them)."""
    for client in _CLUSTERS.values():
        try:
            cluster = client.cluster
            client.close()
            cluster.close()
        except Exception:  # closing at exit: nothing left to report to
            pass
    _CLUSTERS.clear()


class DaskEngine:
    """Dask: an embedded LocalCluster of ``workers`` single-threaded processes, or the existing
    cluster whose scheduler is at ``address`` (tcp://HOST:PORT)."""

    def __init__(self, workers: int | None = None, address: str | None = None):
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.address = address

    def describe(self) -> str:
        """Where the starts run, for the table and messages."""
        if self.address:
            return f"Dask cluster at {self.address}"
        return f"Dask LocalCluster of {self.workers} worker process{'es' if self.workers > 1 else ''}"

    def client(self):
        """The Dask client (the embedded cluster is started on first use)."""
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise StwError("Dask is not installed: pip install 'stw-tui[survey]'") from None
        _quiet_interrupted_sync()
        if self.address:
            security = tls_security(self.address)
            check_scheduler(self.address, security)
            try:
                return Client(self.address, timeout="10s", set_as_default=False, security=security)
            except (OSError, TimeoutError, ValueError) as exc:
                raise StwError(f"cannot reach the Dask scheduler at {self.address}: {exc}") from exc
        if self.workers not in _CLUSTERS:
            try:
                cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", silence_logs=logging.ERROR)
            except Exception as exc:  # Dask's own errors are many kinds: say what failed
                raise StwError(f"could not start a Dask LocalCluster of {self.workers} worker(s): "
                               f"{type(exc).__name__}: {exc}") from exc
            if not _CLUSTERS:
                atexit.register(close_local_clusters)
            _CLUSTERS[self.workers] = Client(cluster, set_as_default=False)
            _CLUSTERS[self.workers].run(quiet_child)   # no worker output over the TUI
        return _CLUSTERS[self.workers]

    def run(self, tasks: list[StartTask], on_result: OnResult, on_note: OnNote, cancelled: Cancelled) -> None:
        """Solve the starts on the cluster, reporting results and lost workers as they come.

        At most :data:`AHEAD_PER_WORKER` starts a worker are submitted ahead, and more as they
        finish (``as_completed``, which gathers each result in Dask's own event loop), so a stop
        (``cancelled()``, looked at before each result, or Ctrl+C) is one ``Client.cancel`` of the
        few starts in flight, whatever the number of starts: with every start submitted at once,
        `survey 100000 iterate=1` took 19 s to submit and 33 s to stop."""
        from distributed import as_completed

        client = self.client()
        pending = iter(tasks)
        flying: dict = {}   # key -> (future, task) of the starts submitted and not yet reported
        try:
            workers = client.ncores()   # asked of the scheduler (scheduler_info() is a cache)
            finished = as_completed(loop=client.loop, with_results=True, raise_errors=False)
            while True:
                ahead = AHEAD_PER_WORKER * max(1, sum(workers.values()))
                chunk = list(itertools.islice(pending, max(0, ahead - len(flying))))
                if chunk and not cancelled():
                    futures = client.map(solve_start, chunk, pure=False)
                    flying.update((f.key, (f, t)) for f, t in zip(futures, chunk))
                    finished.update(futures)
                if finished.is_empty() or cancelled():
                    return
                batch = finished.next_batch(block=False)
                if not batch:
                    time.sleep(DASK_POLL_S)
                for future, result in batch:
                    if cancelled():
                        return
                    task = flying[future.key][1]
                    if future.status == "finished":
                        del flying[future.key]
                        on_result(result if isinstance(result, StartResult) else
                                  _lost(task, f"the cluster returned a {type(result).__name__}, not a start's result"))
                    elif future.status in ("error", "cancelled"):
                        del flying[future.key]
                        why = future.exception() if future.status == "error" else "cancelled"
                        on_result(_lost(task, f"Dask gave up on it: {why!r}"))
                    else:   # its result died with a worker before it was gathered: Dask recomputes it
                        finished.add(future)
                # After every pass, not only idle ones: results can come batch after batch to the
                # last, and a worker lost meanwhile went unreported.
                workers = self._watch(client, workers, on_note)
        finally:   # stopped, interrupted or failed: the cluster drops what was submitted
            if flying:
                with contextlib.suppress(Exception):   # a cluster gone meanwhile has dropped them
                    client.cancel([future for future, _ in flying.values()])
            if self.address:
                client.close()

    @staticmethod
    def _watch(client, known: dict, on_note: OnNote) -> dict:
        """Report workers that left the cluster (Dask reschedules their tasks on the others);
        the cluster's workers now, with their threads."""
        now = client.ncores()
        for address in sorted(set(known) - set(now)):
            on_note(f"Dask worker {address} was lost; its starts go to the remaining workers")
        return now


class _InterruptedSyncRace(logging.Filter):
    """Drops tornado's report of a race inside distributed's ``sync``: Ctrl+C in a client call
    schedules a cancel that can read the call's future before it is set (``NameError: cannot
    access free variable 'future'``, distributed 2025), logged as a callback error over stw's own
    "survey interrupted" line. The survey ends there anyway; nothing else is filtered."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not (isinstance(exc, NameError) and "'future'" in str(exc)
                    and exc.__traceback__ is not None
                    and any(frame.f_code.co_filename.endswith(os.path.join("distributed", "utils.py"))
                            for frame, _ in traceback.walk_tb(exc.__traceback__)))


_SYNC_RACE_FILTER = _InterruptedSyncRace()


def _quiet_interrupted_sync() -> None:
    logging.getLogger("tornado.application").addFilter(_SYNC_RACE_FILTER)   # once: filters are a set


def tls_security(address: str):
    """Dask's ``Security`` for a tls:// address, from Dask's configuration (None for tcp://).

    Raises:
        StwError: the configuration names no CA file or client certificate (Dask would fail
            inside its connect with a TypeError).
    """
    if not address.startswith("tls://"):
        return None
    from distributed.security import Security

    security = Security()
    if not (security.tls_ca_file and security.tls_client_cert):
        raise StwError(f"{address} is a TLS address: set Dask's TLS files first (distributed.comm.tls "
                       "in Dask's config, or DASK_DISTRIBUTED__COMM__TLS__CA_FILE and "
                       "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT, ...__CLIENT__KEY)")
    return security


def check_scheduler(address: str, security=None) -> None:
    """Read the greeting a Dask scheduler sends on connect, bounded in size and time and without
    unpickling anything, so that a service that is not one fails here with a clear error instead
    of inside Dask's reader (which allocates whatever length the peer announces).

    Raises:
        StwError: nothing listens there, it does not answer in time, or its answer is not Dask's.
    """
    import msgpack
    from distributed.comm.addressing import parse_host_port
    from distributed.protocol.utils import unpack_frames

    host, port = parse_host_port(address.split("://", 1)[1])
    not_dask = f"{address} is not a Dask scheduler"
    try:
        with socket.create_connection((host, port), timeout=HANDSHAKE_S) as raw:
            raw.settimeout(HANDSHAKE_S)
            conn = raw
            if security is not None:
                context = security.get_connection_args("client")["ssl_context"]
                conn = context.wrap_socket(raw, server_hostname=host if context.check_hostname else None)
            (size,) = struct.unpack("Q", _read_exactly(conn, 8))
            if not 8 <= size <= HANDSHAKE_BYTES:
                raise StwError(f"{not_dask}: it announced a first message of {size} bytes")
            frames = unpack_frames(memoryview(_read_exactly(conn, size)), partial=True)[0]
            greeting = msgpack.loads(bytes(frames[0])) if frames else None
    except StwError:
        raise
    except (OSError, EOFError) as exc:   # refused, timed out, closed, TLS failed
        raise StwError(f"cannot reach the Dask scheduler at {address}: {exc}") from exc
    except Exception as exc:  # whatever a stranger's bytes make of the frame and msgpack parsers
        raise StwError(f"{not_dask}: its greeting does not read as Dask's ({type(exc).__name__})") from exc
    if not (isinstance(greeting, dict) and "python" in greeting):
        raise StwError(f"{not_dask}: its greeting does not read as Dask's")


def _read_exactly(conn, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise EOFError(f"the connection closed after {len(data)} of {n} bytes")
        data += chunk
    return data


def choose_engine(workers: int | None = None, scheduler: str | None = None, backend: str | None = None,
                  options: dict | None = None):
    """(engine, note) for `set scheduler`'s value: "serial", "pool", "batch", a Dask scheduler address, or
    None (Dask's LocalCluster when Dask is installed, else a local pool). ``backend`` and
    ``options``: the scene's (`backend torch device=cpu`), which a batch honours if that backend
    solves batches."""
    if scheduler == "serial":
        return SerialEngine(), ""
    if scheduler == "pool":
        return PoolEngine(workers), ""
    if scheduler == "batch":
        return BatchEngine(workers, backend, options), ""
    if scheduler:
        return DaskEngine(workers, scheduler), ""
    if dask_available():
        return DaskEngine(workers), ""
    engine = PoolEngine(workers)
    return engine, (f"Dask is not installed: the survey runs on a {engine.describe()} "
                    "(pip install 'stw-tui[survey]' for Dask)")


def run_survey(session, plan: SurveyPlan, engine=None, *, scheduler: str | None = None,
               on_progress: Callable[[SurveyTable, StartResult | None], None] | None = None,
               cancelled: Cancelled | None = None) -> SurveyTable:
    """Survey ``session``'s scene: plan the starts, run them on ``engine`` (chosen by
    :func:`choose_engine` when None) and group them as they arrive.

    Args:
        on_progress: called with the table so far after each start (and each note; then the
            result is None), in the calling thread.
        cancelled: polled; once it returns True no more starts are solved and the table says so.
    Raises:
        StwError: a bad plan (see :func:`~stw_tui.session.survey.plan_tasks`), an unreachable
            cluster, or Ctrl+C (KeyboardInterrupt) while the starts ran.
    """
    tasks = plan_tasks(session, plan)
    if engine is None:
        scene = session.scene
        engine, note = choose_engine(plan.workers, scheduler, scene.backend, scene.backend_options)
    else:
        note = ""
    table = SurveyTable(plan, tasks[0].base_text, engine.describe(), notes=[note] if note else [])
    cancelled = cancelled or (lambda: False)
    started = time.perf_counter()

    def on_result(result: StartResult) -> None:
        table.results.append(result)
        table.seconds = time.perf_counter() - started
        if on_progress is not None:
            on_progress(table, result)

    def on_note(text: str) -> None:
        table.notes.append(text)
        if on_progress is not None:
            on_progress(table, None)

    try:
        engine.run(tasks, on_result, on_note, cancelled)
    except KeyboardInterrupt:   # headless Ctrl+C: the engine has dropped its starts (its finally)
        table.seconds, table.cancelled = time.perf_counter() - started, True
        raise StwError(f"survey interrupted (Ctrl+C) after {len(table.results)} of {len(tasks)} start(s); "
                       f"the scene is unchanged\n{table.summary()}") from None
    table.seconds = time.perf_counter() - started
    table.cancelled = len(table.results) < len(tasks) and cancelled()
    table.results.sort(key=lambda r: r.index)
    return table
