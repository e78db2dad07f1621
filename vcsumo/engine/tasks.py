"""What a campaign runs: tasks, their outcomes, and the rules every worker process follows.

A :class:`Task` is a module-level function and its argument (both picklable: they travel to
worker processes and Dask workers by name); :func:`call` runs one and turns an exception into the
:class:`Outcome`'s one-line error, so that one failing task never stops a campaign.
:func:`sigterm_as_interrupt` makes SIGTERM unwind like Ctrl-C (``KeyboardInterrupt``), so results
folders being written are removed (:mod:`vcsumo.results`).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator

from vcsumo.errors import VcsumoError

WORKER_DIED = "the worker process died during the run (killed by a signal, out of memory, or SUMO aborted the process)"


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
