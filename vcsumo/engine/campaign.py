"""One runner for every campaign of many runs (batch, capacity, safety).

A campaign is a list of :class:`Task` — a module-level function, its argument and the resume
key(s) of the rows it produces — run by a :class:`Runner` and recorded in a
:class:`~vcsumo.engine.store.ResultStore` by :func:`run_campaign`, which skips every task whose
rows the store already holds (so re-running the same command resumes it).

Where tasks run (one flag each):

* ``workers=1`` — in this process, one after the other;
* ``workers=N`` (N ≥ 2) — in N spawned processes (one libsumo per process).  Worker processes
  write what SUMO prints to ``workers.log`` and end themselves when the command that started
  them is gone (:func:`silence_worker`);
* ``scheduler="tcp://HOST:PORT"`` — on a Dask distributed cluster (workers need vcsumo and the
  input and results paths).  The runner connects and waits for a worker before anything is
  written; a scheduler that cannot be reached, that has no worker, or that loses every worker
  while tasks are left, stops the campaign within ``worker_wait_s`` seconds with one error line
  (the finished rows are kept).

``workers`` means the same everywhere: N ≥ 1, 1 runs in this process, ``None`` is the number of
CPUs; 0 or a negative number is an input error (:func:`check_workers`).

Crash isolation: a task that raises becomes an :class:`Outcome` with its ``error`` (the study
turns it into a failed row); a worker process that dies during a task (SIGKILL, out of memory,
SUMO aborting the process) fails only that task: it is run once more, alone, after the others,
and if its worker dies again the task fails with :data:`WORKER_DIED`.  Partial results folders
(``*.partial-<pid>``) of dead workers are removed, and those of processes found dead at the start.

Interruption: SIGINT and SIGTERM (:func:`sigterm_as_interrupt`) raise ``KeyboardInterrupt`` in
the command; the runner then asks its workers to stop (SIGTERM: each unwinds its task, so its
partial results folder is removed), waits up to 10 s, kills the rest and removes their partial
folders.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
import uuid
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing.connection import wait as wait_ready
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from vcsumo.engine.store import ResultStore
from vcsumo.errors import InputError, VcsumoError
from vcsumo.results import remove_stale_partials

WORKER_DIED = "the worker process died during the run (killed by a signal, out of memory, or SUMO aborted the process)"
SCHEDULERS = ("tcp://", "tls://", "inproc://", "ucx://")
STOP_GRACE_S = 10.0
"""How long interrupted workers get to unwind their task and remove their partial folders."""


class CampaignFailed(VcsumoError):
    """Every task of a campaign failed, or it has no result: the command says so and exits 1."""

    exit_code = 1


class Interrupted(KeyboardInterrupt):
    """SIGTERM, turned into ``KeyboardInterrupt`` so that everything unwinds as for Ctrl-C."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_interrupted(signum, frame) -> None:
    raise Interrupted(signum)


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While inside, SIGTERM raises :class:`Interrupted` (a ``KeyboardInterrupt``) in the main thread."""
    try:
        old = signal.signal(signal.SIGTERM, _raise_interrupted)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def check_workers(workers: int | None, option: str = "--workers") -> int:
    """The number of worker processes: ``None`` → CPUs; N ≥ 1 (1: in this process); else an input error."""
    if workers is None:
        return os.cpu_count() or 1
    if isinstance(workers, bool) or int(workers) != workers or workers < 1:
        raise InputError(None, option, f"{workers}: must be 1 or more (1 runs in this process; default: the number of CPUs)")
    return int(workers)


def check_scheduler(address: str | None, option: str = "--scheduler") -> str | None:
    if address is None:
        return None
    if not isinstance(address, str) or not address.startswith(SCHEDULERS) or len(address) <= address.index("://") + 3:
        raise InputError(None, option, f"'{address}' is not a Dask scheduler address (tcp://HOST:PORT)")
    return address


def error_message(exc: BaseException) -> str:
    """One line: a VcsumoError's own message, else the exception's type and message."""
    text = str(exc) if isinstance(exc, VcsumoError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def silence_worker(log_path: str | None) -> None:
    """Worker initializer: SUMO's console messages go to ``log_path``, not over the progress bar,
    and the worker ends itself when the command that started it is gone (killed or interrupted),
    instead of running on as an orphan."""
    if log_path:
        fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="vcsumo-parent-watch", daemon=True).start()


@dataclass(frozen=True)
class Task:
    """One unit of work: ``fn(arg)`` in some process (``fn`` a module-level function, both picklable)."""

    key: str
    """The task's resume key."""
    fn: Callable[[Any], Any]
    arg: Any
    label: str = ""
    keys: tuple[str, ...] = ()
    """The store keys of the rows the task produces (default: its own key); it is done when all are stored."""

    @property
    def store_keys(self) -> tuple[str, ...]:
        return self.keys or (self.key,)


@dataclass
class Outcome:
    """What a task gave: its value, or the one-line error that stopped it."""

    value: Any = None
    error: str = ""
    wall_time_s: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.error


def call(fn: Callable[[Any], Any], arg: Any) -> Outcome:
    """Run one task here; an exception becomes the outcome's error (``KeyboardInterrupt`` passes)."""
    t0 = time.perf_counter()
    try:
        value = fn(arg)
    except Exception as exc:  # noqa: BLE001 - crash isolation: a task never stops the campaign
        return Outcome(None, error_message(exc) or type(exc).__name__, time.perf_counter() - t0)
    return Outcome(value, "", time.perf_counter() - t0)


# -----------------------------------------------------------------------------------------------
# Local worker processes


def _worker_interrupted(signum, frame) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # one interruption: let the task unwind in peace
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise Interrupted(signum)


def _worker_main(conn, log_path: str | None) -> None:
    """A worker process: run tasks sent over ``conn`` until told to stop or the command is gone."""
    silence_worker(log_path)
    signal.signal(signal.SIGTERM, _worker_interrupted)
    signal.signal(signal.SIGINT, _worker_interrupted)
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return
            if msg is None:
                return
            fn, arg = msg
            out = call(fn, arg)
            try:
                conn.send(out)
            except Exception as exc:  # noqa: BLE001 - an unpicklable result is that task's error
                conn.send(Outcome(None, f"the result could not be sent back: {error_message(exc)}", out.wall_time_s))
    except KeyboardInterrupt:
        return


class _Worker:
    def __init__(self, ctx, log_path: str | None):
        self.conn, child = ctx.Pipe(duplex=True)
        self.proc = ctx.Process(target=_worker_main, args=(child, log_path), name="vcsumo-worker", daemon=True)
        self.proc.start()
        child.close()
        self.task: Task | None = None
        self.alone = False

    @property
    def pid(self) -> int:
        return self.proc.pid or -1


class Runner:
    """Where a campaign's tasks run: this process, N local processes, or a Dask cluster.

    Use as a context manager: entering connects to the Dask scheduler (and waits up to
    ``worker_wait_s`` for a worker) so that a cluster that cannot run anything is reported
    before anything is written.  ``log_path``: where worker processes' output goes;
    ``partial_roots``: folders where tasks write ``*.partial-<pid>`` results folders (those of
    dead workers are removed).
    """

    def __init__(self, workers: int | None = None, scheduler: str | None = None, log_path: Path | None = None,
                 partial_roots: Iterable[Path] = (), worker_wait_s: float = 10.0, connect_timeout_s: float = 10.0):
        self.workers = check_workers(workers)
        self.scheduler = check_scheduler(scheduler)
        self.log_path = log_path
        self.partial_roots = [Path(p) for p in partial_roots]
        self.worker_wait_s = worker_wait_s
        self.connect_timeout_s = connect_timeout_s
        self._client = None

    @property
    def where(self) -> str:
        if self.scheduler:
            return f"Dask scheduler {self.scheduler}"
        return "this process" if self.workers == 1 else f"{self.workers} processes"

    def __enter__(self) -> "Runner":
        if self.scheduler:
            self._client = _connect(self.scheduler, self.connect_timeout_s, self.worker_wait_s)
        return self

    def __exit__(self, *exc) -> None:
        if self._client is not None:
            try:
                self._client.close(timeout=5)
            except Exception:  # noqa: BLE001 - closing a broken connection
                pass
            self._client = None

    def run(self, tasks: list[Task], on_outcome: Callable[[Task, Outcome], None]) -> None:
        """Run every task; ``on_outcome(task, outcome)`` in this process as each one finishes."""
        for root in self.partial_roots:
            remove_stale_partials(root)
        if not tasks:
            return
        if self.scheduler:
            if self._client is None:
                raise RuntimeError("Runner.run with a scheduler must be inside 'with runner:'")
            _run_dask(self._client, self.scheduler, tasks, on_outcome, self.worker_wait_s)
        elif self.workers == 1:
            for t in tasks:
                on_outcome(t, call(t.fn, t.arg))
        else:
            self._run_processes(tasks, on_outcome)

    def _clean_after(self, pids: set[int]) -> None:
        for root in self.partial_roots:
            remove_stale_partials(root, pids=pids)

    def _run_processes(self, tasks: list[Task], on_outcome: Callable[[Task, Outcome], None]) -> None:
        ctx = multiprocessing.get_context("spawn")
        log = str(self.log_path) if self.log_path else None
        if self.log_path:
            Path(self.log_path).parent.mkdir(parents=True, exist_ok=True)
        n = min(self.workers, len(tasks))
        queue: deque[Task] = deque(tasks)
        suspects: deque[Task] = deque()
        idle: list[_Worker] = []
        busy: list[_Worker] = []

        def start(task: Task, alone: bool) -> None:
            w = idle.pop() if idle else _Worker(ctx, log)
            w.task, w.alone = task, alone
            try:
                w.conn.send((task.fn, task.arg))
            except (BrokenPipeError, EOFError, OSError):  # the idle worker died meanwhile
                w.task = None
                _stop([w], graceful=False)
                self._clean_after({w.pid})
                start(task, alone)
                return
            except Exception as exc:  # noqa: BLE001 - an argument that cannot be pickled
                w.task = None
                idle.append(w)
                on_outcome(task, Outcome(None, f"the task could not be sent to a worker: {error_message(exc)}"))
                return
            busy.append(w)

        try:
            while queue or suspects or busy:
                if queue:
                    while queue and len(busy) < n:
                        start(queue.popleft(), False)
                elif suspects and not busy:
                    start(suspects.popleft(), True)  # a task whose worker died runs again, alone
                if not busy:
                    continue
                ready = wait_ready([w.conn for w in busy] + [w.proc.sentinel for w in busy], timeout=1.0)
                if not ready:
                    continue
                for w in list(busy):
                    if w.conn not in ready and w.proc.sentinel not in ready:
                        continue
                    out = None
                    try:
                        if w.conn.poll():
                            out = w.conn.recv()
                    except (EOFError, OSError):
                        out = None
                    task = w.task
                    busy.remove(w)
                    w.task = None
                    if isinstance(out, Outcome):
                        if w.proc.is_alive():
                            idle.append(w)
                        else:
                            _stop([w], graceful=False)
                        on_outcome(task, out)
                        continue
                    if w.proc.is_alive() and w.proc.sentinel not in ready:
                        busy.append(w)  # readable but nothing whole yet
                        w.task = task
                        continue
                    _stop([w], graceful=False)
                    self._clean_after({w.pid})
                    if w.alone:
                        on_outcome(task, Outcome(None, WORKER_DIED))
                    else:
                        suspects.append(task)
        except BaseException:
            everyone = busy + idle
            _stop(everyone, graceful=True)
            self._clean_after({w.pid for w in everyone})
            raise
        _stop(idle, graceful=True, polite=True)


def _stop(workers: list[_Worker], graceful: bool, polite: bool = False) -> None:
    """End worker processes: ``polite`` asks idle ones to leave, ``graceful`` sends SIGTERM and
    waits up to :data:`STOP_GRACE_S`; whatever is left is killed."""
    live = [w for w in workers if w.proc.pid is not None]
    for w in live:
        try:
            if polite:
                w.conn.send(None)
            elif graceful and w.proc.is_alive():
                os.kill(w.proc.pid, signal.SIGTERM)
        except (OSError, ValueError):
            pass
    deadline = time.monotonic() + (STOP_GRACE_S if graceful or polite else 1.0)
    for w in live:
        w.proc.join(max(0.0, deadline - time.monotonic()))
        if w.proc.is_alive():
            w.proc.kill()
            w.proc.join(5.0)
        try:
            w.conn.close()
        except OSError:
            pass


# -----------------------------------------------------------------------------------------------
# Dask


_TASK_LOCK = threading.Lock()
"""libsumo is one simulation per process: tasks in threads of one Dask worker take turns."""


def _dask_call(fn: Callable[[Any], Any], arg: Any) -> Outcome:
    with _TASK_LOCK:
        return call(fn, arg)


def _connect(address: str, timeout_s: float, worker_wait_s: float):
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - dask[distributed] is a dependency
        raise VcsumoError("--scheduler: dask.distributed is not installed (pip install 'dask[distributed]')") from None
    if address.startswith("tcp://"):  # nothing listening: say so at once (the client would retry until its timeout)
        import socket
        from urllib.parse import urlsplit

        try:
            u = urlsplit(address)
            socket.create_connection((u.hostname, u.port or 8786), timeout=timeout_s).close()
        except (OSError, ValueError) as exc:
            raise VcsumoError(f"--scheduler: cannot connect to the Dask scheduler at {address}: {error_message(exc)}") from None
    try:
        client = Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except Exception as exc:  # noqa: BLE001 - refused, unreachable, not a scheduler
        raise VcsumoError(f"--scheduler: cannot connect to the Dask scheduler at {address} within {timeout_s:g} s: {error_message(exc)}") from None
    try:
        client.wait_for_workers(1, timeout=worker_wait_s)
    except Exception:  # noqa: BLE001 - TimeoutError (the type differs between versions)
        client.close()
        raise VcsumoError(f"--scheduler: the Dask scheduler at {address} has no workers (waited {worker_wait_s:g} s); "
                          f"start some with 'dask worker {address}'") from None
    return client


def _n_workers(client) -> int:
    return len(client.nthreads())


def _run_dask(client, address: str, tasks: list[Task], on_outcome: Callable[[Task, Outcome], None], worker_wait_s: float) -> None:
    """Each task is one Dask task; a lost worker's task is retried once by Dask, then fails;
    a cluster without workers for ``worker_wait_s`` stops the campaign with one error."""
    tag = uuid.uuid4().hex[:8]
    futures = {client.submit(_dask_call, t.fn, t.arg, key=f"vcsumo-{t.key}-{tag}", pure=False, retries=1): t for t in tasks}
    pending = dict(futures)
    no_workers_since: float | None = None
    last_check = 0.0
    try:
        while pending:
            finished = [f for f in pending if f.done()]
            for f in finished:
                task = pending.pop(f)
                try:
                    out = f.result()
                except Exception as exc:  # noqa: BLE001 - the task itself never raises; a lost worker does
                    out = Outcome(None, f"dask: {error_message(exc)}")
                on_outcome(task, out)
            if not pending:
                break
            if finished:
                continue
            now = time.monotonic()
            if now - last_check >= 1.0:
                last_check = now
                try:
                    n = _n_workers(client)
                except Exception as exc:  # noqa: BLE001 - the scheduler went away
                    raise VcsumoError(f"--scheduler: lost the Dask scheduler at {address} ({error_message(exc)}); "
                                      f"{len(pending)} of {len(tasks)} tasks unfinished (finished rows are kept: run again to resume)") from None
                if n:
                    no_workers_since = None
                elif no_workers_since is None:
                    no_workers_since = now
                elif now - no_workers_since >= worker_wait_s:
                    raise VcsumoError(f"--scheduler: the Dask cluster at {address} has no workers left (for {worker_wait_s:g} s); "
                                      f"{len(pending)} of {len(tasks)} tasks unfinished (finished rows are kept: run again to resume)")
            time.sleep(0.1)
    finally:
        if pending:
            try:
                client.cancel(list(pending), force=True)
            except Exception:  # noqa: BLE001
                pass


# -----------------------------------------------------------------------------------------------
# The campaign


@dataclass
class CampaignResult:
    new: int
    """Tasks run now."""
    resumed: int
    """Tasks found finished in the store."""
    failed: int
    """Tasks run now that failed (an error, or a worker that died)."""


def run_campaign(store: ResultStore, tasks: list[Task], runner: Runner,
                 to_rows: Callable[[Task, Outcome], tuple[list[dict], dict[str, list[dict]]]],
                 progress: Callable[[int, int, list[dict] | None], None] | None = None) -> CampaignResult:
    """Run the tasks whose rows are not in the store yet and record each one's rows as it finishes.

    ``to_rows(task, outcome)`` → (main rows, {child table name: rows}); a failed outcome must
    give rows too (with the error), so that the task counts as finished.
    ``progress(done, total, rows)`` is called before the first task (rows None) and after each
    one with the main rows it gave.
    """
    pending = [t for t in tasks if not all(k in store for k in t.store_keys)]
    total = len(pending)
    state = {"done": 0, "failed": 0}
    if progress:
        progress(0, total, None)

    def on_outcome(task: Task, out: Outcome) -> None:
        rows, children = to_rows(task, out)
        store.record(rows, children)
        state["done"] += 1
        state["failed"] += not out.ok
        if progress:
            progress(state["done"], total, rows)

    runner.run(pending, on_outcome)
    return CampaignResult(new=total, resumed=len(tasks) - total, failed=state["failed"])
