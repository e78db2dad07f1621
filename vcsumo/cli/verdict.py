"""The exit status of a command that ran: 0 only when every case finished and is healthy.

A command that wrote results whose cases did not all finish cleanly — a case failed (an error in
its row), or a finished case is not healthy (a collision, a gap below the safe separation, a
skipped stop, overspeed, an overrun, braking beyond service, a train that did not arrive) —
keeps its results, prints them, and ends with one line saying how many of how many and where
they are, exit status 1.  A script or a pipeline calling vcsumo can then trust a 0 as "every
case clean", as a test runner's 0 means "every test passed".
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from vcsumo.errors import VcsumoError


class NotClean(VcsumoError):
    """The command ran and wrote its results, but they are empty, failed or not healthy: exit status 1."""

    exit_code = 1


def not_healthy(healthy: pd.Series) -> pd.Series:
    """Which entries of a ``healthy`` column are not true (bools, or text read back from a CSV)."""
    return ~healthy.astype(str).str.strip().str.lower().isin(("true", "1", "1.0"))


def count_not_healthy(healthy: pd.Series) -> int:
    """How many entries of a ``healthy`` column are not true."""
    return int(not_healthy(healthy).sum())


def require_clean(what: str, total: int, failed: int, unhealthy: int, where: Path | str, noun: str = "cases", unhealthy_detail: str = "") -> None:
    """Raise :class:`NotClean` when ``failed`` cases failed or ``unhealthy`` finished cases are not healthy.

    ``what`` names the command's study ("the batch"), ``total`` its cases, ``where`` the table
    holding the rows (named in the message), ``unhealthy_detail`` what was wrong with the unhealthy
    ones ("2 with a collision"; written after their count).
    """
    if not failed and not unhealthy:
        return
    detail = f": {unhealthy_detail}" if unhealthy_detail else ""
    parts = ([f"{failed} failed"] if failed else []) + ([f"{unhealthy} not healthy{detail}"] if unhealthy else [])
    n = failed + unhealthy
    raise NotClean(f"{n} of {total} {noun} of {what} {'is' if n == 1 else 'are'} not clean ({', '.join(parts)}); results kept in {where}")


__all__ = ["NotClean", "count_not_healthy", "not_healthy", "require_clean"]
