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

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from vcsumo.engine.cluster import connect, run_on_cluster
from vcsumo.engine.processes import run_in_processes
from vcsumo.engine.store import ResultStore
from vcsumo.engine.tasks import (  # the engine's names, in one place for the studies and the command line (__all__)
    WORKER_DIED,
    Interrupted,
    Outcome,
    Task,
    call,
    error_message,
    sigterm_as_interrupt,
    silence_worker,
)
from vcsumo.errors import InputError, VcsumoError
from vcsumo.results import remove_stale_partials

__all__ = ["WORKER_DIED", "CampaignFailed", "CampaignResult", "Interrupted", "Outcome", "Runner", "Task", "call", "check_scheduler",
           "check_workers", "error_message", "run_campaign", "sigterm_as_interrupt", "silence_worker"]
SCHEDULERS = ("tcp://", "tls://", "inproc://", "ucx://")


class CampaignFailed(VcsumoError):
    """Every task of a campaign failed, or it has no result: the command says so and exits 1."""

    exit_code = 1


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
            self._client = connect(self.scheduler, self.connect_timeout_s, self.worker_wait_s)
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
            run_on_cluster(self._client, self.scheduler, tasks, on_outcome, self.worker_wait_s)
        elif self.workers == 1:
            for t in tasks:
                on_outcome(t, call(t.fn, t.arg))
        else:
            run_in_processes(tasks, on_outcome, self.workers, self.log_path, self._clean_after)

    def _clean_after(self, pids: set[int]) -> None:
        for root in self.partial_roots:
            remove_stale_partials(root, pids=pids)


@dataclass
class CampaignResult:
    new: int
    """Tasks run now."""
    resumed: int
    """Tasks found finished in the store."""
    failed: int
    """Tasks run now that failed (an error, or a worker that died): a row with an ``error``."""


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
        state["failed"] += not out.ok or any(r.get("error") for r in rows)
        if progress:
            progress(state["done"], total, rows)

    runner.run(pending, on_outcome)
    return CampaignResult(new=total, resumed=len(tasks) - total, failed=state["failed"])
