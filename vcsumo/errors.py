"""Errors raised to the user.

Every problem the user can fix (a malformed file, an unknown name, an infeasible timetable, a
SUMO failure) is raised as :class:`VcsumoError` with one message naming the file and the field.
The CLI prints that message and exits with status 2; it never prints a traceback for them.
"""

from __future__ import annotations

from pathlib import Path


class VcsumoError(Exception):
    """A problem the user can fix, with a message that names the file and the field."""


class InfeasibleBraking(VcsumoError, ValueError):
    """A train's guaranteed brake cannot hold it on a descent under the assumption set: no run of it
    can be safe.  (Also a ValueError: callers that add the train and the set catch it as such.)"""

    def for_train(self, train_id: str, assumptions: str) -> VcsumoError:
        """The same, said of one train of a run under the named assumption set."""
        return VcsumoError(f"infeasible: train {train_id}: {self} of its route under the assumption set '{assumptions}'")


class InputError(VcsumoError):
    """A malformed or inconsistent input file (line, timetable, rolling stock, study, controller)."""

    def __init__(self, path: str | Path | None, field: str | None, message: str):
        self.path = None if path is None else str(path)
        self.field = field
        # one line: line breaks echoed from a hostile file (a name written '\n') are shown escaped
        self.message = message.replace("\r", "\\r").replace("\n", "\\n")
        where = [x for x in (self.path, field) if x]
        super().__init__(": ".join(where + [self.message]).replace("\r", "\\r").replace("\n", "\\n"))


class SumoError(VcsumoError):
    """netconvert or SUMO failed; the message carries SUMO's own error lines."""
