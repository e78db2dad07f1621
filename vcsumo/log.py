"""Diagnostics through Python :mod:`logging`: one rich handler on stderr, its level set by ``-v``/``-q``.

Library modules log with ``logging.getLogger(__name__)`` (loggers under ``vcsumo``); results and
tables go to stdout and never through logging.  The command line calls :func:`setup_logging` once
and :func:`set_verbosity` for every ``-v``/``-q`` it sees.  Levels:

* ``-q`` (verbosity −1): errors only, and no progress bars;
* default (0): warnings (e.g. a line file's curve left out of the SUMO plant);
* ``-v`` (1): what vcsumo does (network reused or built, results folder written);
* ``-vv`` (2 or more): debugging detail, each message with the name of its logger.

Python warnings (:func:`warnings.warn`) become log lines of ``vcsumo.warnings`` (same handler), each text once
per command (a study repeats its planning for every bisection probe; libraries that reset Python's
warning filters would otherwise show it again every time).  SUMO's own messages do
not come here: they go into the results folder (``sumo_messages.log``, ``sumo_errors.log``).
"""

from __future__ import annotations

import logging
import warnings

ROOT_LOGGER = "vcsumo"
_state: dict = {"verbosity": 0, "shown": set()}


def level_for(verbosity: int) -> int:
    """The logging level of a verbosity (−1 quiet, 0 default, 1 verbose, 2+ debug)."""
    if verbosity < 0:
        return logging.ERROR
    return {0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG)


def verbosity() -> int:
    """The verbosity set last (−1 quiet, 0 default, 1 verbose, 2+ debug)."""
    return _state["verbosity"]


def _is_ours(h: logging.Handler) -> bool:
    return getattr(h, "_vcsumo_handler", False)


def setup_logging(verbosity: int = 0, console=None) -> None:
    """Send the ``vcsumo`` loggers and Python warnings to one rich handler on ``console`` (stderr).

    Idempotent: a second call replaces the handler it added before (the command can be run many
    times in one process, e.g. by tests or by ``vcsumo study run``).
    """
    from rich.logging import RichHandler

    handler = RichHandler(console=console, show_time=False, show_path=False, markup=False, rich_tracebacks=False)
    handler._vcsumo_handler = True  # type: ignore[attr-defined]
    lg = logging.getLogger(ROOT_LOGGER)
    for h in [h for h in lg.handlers if _is_ours(h)]:
        lg.removeHandler(h)
    lg.addHandler(handler)
    _state["shown"] = set()
    warnings.showwarning = show_warning
    set_verbosity(verbosity)


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings as one log line (``vcsumo.warnings``), without the source line Python adds;
    a text already shown since :func:`setup_logging` is not shown again."""
    text = str(message)
    if category is not UserWarning:
        text = f"{category.__name__}: {text}"
    if text in _state["shown"]:
        return
    _state["shown"].add(text)
    logging.getLogger(f"{ROOT_LOGGER}.warnings").warning("%s", text)


def set_verbosity(verbosity: int) -> None:
    """Set the level of the ``vcsumo`` loggers (warnings included) to that of ``verbosity``."""
    _state["verbosity"] = int(verbosity)
    lg = logging.getLogger(ROOT_LOGGER)
    lg.setLevel(level_for(verbosity))
    for h in lg.handlers:
        if _is_ours(h):
            h.setFormatter(logging.Formatter("%(name)s: %(message)s" if verbosity >= 2 else "%(message)s"))
