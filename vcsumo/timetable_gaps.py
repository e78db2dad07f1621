"""A timetable whose departures leave half a day or more without any train: most likely a time
after midnight written as the next day's ``00:..`` (vcsumo's clock runs on past 24:00).

``23:58`` and ``00:00:01`` in one timetable are read as two times of the same day, 23 h 58 min
apart: the run then simulates the whole day between them with nothing to show for it.
"""

from __future__ import annotations

from vcsumo.units import format_clock

IDLE_GAP_S = 12 * 3600.0
"""A gap between consecutive departures this long or longer is said, s."""


def idle_gaps(trains: list, gap_s: float = IDLE_GAP_S) -> list[str]:
    """One sentence per gap of at least ``gap_s`` between consecutive departures of the planned
    trains (``timetable.PlannedTrain``), naming the trains on either side."""
    order = sorted(trains, key=lambda t: t.depart_s)
    out = []
    for a, b in zip(order, order[1:]):
        if b.depart_s - a.depart_s >= gap_s:
            out.append(f"no train departs between {format_clock(a.depart_s)} ({a.id}) and {format_clock(b.depart_s)} ({b.id}), "
                       f"{(b.depart_s - a.depart_s) / 3600.0:.1f} h: the run simulates that time too; a time after midnight is written "
                       f"from 24:00 on (24:00:01), not 00:00:01")
    return out
