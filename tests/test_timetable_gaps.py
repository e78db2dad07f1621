"""A time after midnight written as 00:.. in a timetable that runs up to midnight is read as the
same day's start: the run simulates almost a day of nothing, without a word (found with a timetable
at 23:58 and 00:00:01).  The plan now says so."""

from __future__ import annotations

import warnings

import pytest

from vcsumo.cli.commands import network
from vcsumo.line import load_line
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write

TT = """
name: late
line: felez_test
services:
  - {{id: A, train: felez2019, origin: ORIG, destination: STOP, departure: "23:58"}}
  - {{id: B, train: felez2019, origin: ORIG, destination: STOP, departure: "{b}"}}
"""


def _plan(tmp_path, b: str):
    line = load_line("felez_test")
    tt, path = load_timetable(write(tmp_path / "late.yaml", TT.format(b=b)), line)
    return plan_trains(tt, path, line, network(line, None).topology)


def test_a_day_without_departures_is_said(tmp_path):
    with pytest.warns(UserWarning, match=r"no train departs between 00:00:01 \(B\) and 23:58:00 \(A\), 24\.0 h: .*written from 24:00 on"):
        _plan(tmp_path, "00:00:01")


def test_after_midnight_written_from_24_is_quiet(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        trains = _plan(tmp_path, "24:00:01")
    assert sorted(t.depart_s for t in trains) == [86280.0, 86401.0]
