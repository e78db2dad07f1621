"""Python warnings reach the user once per command, however often the code path repeats."""

from __future__ import annotations

import io
import logging
import warnings

from rich.console import Console

from vcsumo.log import ROOT_LOGGER, setup_logging


def test_a_warning_text_is_shown_once_per_command():
    buf = io.StringIO()
    before = warnings.showwarning
    lg = logging.getLogger(ROOT_LOGGER)
    handlers, level = list(lg.handlers), lg.level
    try:
        setup_logging(0, Console(file=buf, width=200))
        with warnings.catch_warnings():
            warnings.simplefilter("always")  # as after a library reset the filters: Python itself would repeat it
            for _ in range(3):
                warnings.warn("platform of FIRI too short", UserWarning)
            warnings.warn("another problem", UserWarning)
        text = buf.getvalue()
        assert text.count("platform of FIRI too short") == 1
        assert text.count("another problem") == 1
        setup_logging(0, Console(file=buf, width=200))  # a new command in the same process shows it again
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.warn("platform of FIRI too short", UserWarning)
        assert buf.getvalue().count("platform of FIRI too short") == 2
    finally:
        warnings.showwarning = before
        lg.handlers[:] = handlers
        lg.setLevel(level)
