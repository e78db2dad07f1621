"""Tasks on a Dask distributed cluster (``--scheduler tcp://HOST:PORT``).

:func:`connect` reaches the scheduler and waits for a worker before anything is written: nothing
listening, no scheduler, or a scheduler without workers is one error line within seconds.
:func:`run_on_cluster` submits each task once (Dask retries a task whose worker was lost once;
then it fails with the reason) and watches the cluster: if it has had no worker for
``worker_wait_s`` while tasks are left, the campaign stops with one error line (finished rows are
kept: run again to resume).  Workers need vcsumo and the input and results paths.
"""

from __future__ import annotations

import threading
import time
import uuid
from typing import Any, Callable

from vcsumo.engine.tasks import Outcome, Task, call, error_message
from vcsumo.errors import VcsumoError


_TASK_LOCK = threading.Lock()
"""libsumo is one simulation per process: tasks in threads of one Dask worker take turns."""


def _dask_call(fn: Callable[[Any], Any], arg: Any) -> Outcome:
    with _TASK_LOCK:
        return call(fn, arg)


def connect(address: str, timeout_s: float, worker_wait_s: float):
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


def run_on_cluster(client, address: str, tasks: list[Task], on_outcome: Callable[[Task, Outcome], None], worker_wait_s: float) -> None:
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
