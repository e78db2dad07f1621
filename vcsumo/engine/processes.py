"""Tasks in local worker processes (spawned: one libsumo per process), with crash isolation.

Each worker runs one task at a time, so a worker that dies (SIGKILL, out of memory, SUMO aborting
the process) is known to have been running exactly that task: the task is run once more, alone,
after the others (a worker killed from outside or short of memory may well succeed then); if its
worker dies again it fails with :data:`~vcsumo.engine.tasks.WORKER_DIED`.  The others go on in the
surviving and replacement workers.  On an interruption (``KeyboardInterrupt``: Ctrl-C or SIGTERM)
every worker gets SIGTERM, unwinds its task (removing its partial results folder) and ends; one
that has not ended after :data:`STOP_GRACE_S` is killed.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections import deque
from multiprocessing.connection import wait as wait_ready
from pathlib import Path
from typing import Callable

from vcsumo.engine.tasks import WORKER_DIED, Interrupted, Outcome, Task, call, error_message, silence_worker

STOP_GRACE_S = 10.0
"""How long interrupted workers get to unwind their task and remove their partial folders."""


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


def run_in_processes(tasks: list[Task], on_outcome: Callable[[Task, Outcome], None], workers: int, log_path: Path | None,
                     on_dead: Callable[[set[int]], None]) -> None:
    """Run the tasks in ``workers`` spawned processes; ``on_dead(pids)`` after workers died or were killed."""
    ctx = multiprocessing.get_context("spawn")
    log = str(log_path) if log_path else None
    if log_path:
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    n = min(workers, len(tasks))
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
            on_dead({w.pid})
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
                on_dead({w.pid})
                if w.alone:
                    on_outcome(task, Outcome(None, WORKER_DIED))
                else:
                    suspects.append(task)
    except BaseException:
        everyone = busy + idle
        _stop(everyone, graceful=True)
        on_dead({w.pid for w in everyone})
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
