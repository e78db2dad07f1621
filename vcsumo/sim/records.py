"""Per-step records with bounded memory: CSV files written in chunks, running statistics.

A full day on a network produces millions of per-second rows; held in memory until the end they
grow with simulated time.  :class:`CsvStream` takes rows as plain tuples and writes them to the
file in chunks, producing the same bytes as one ``pandas.DataFrame(rows, columns).to_csv(index=False)``
of all rows (the float columns are named, so a chunk whose floats happen to be all missing is
formatted as the whole table would be).  :class:`RunningStats` keeps the count, mean, maximum and
quantiles (to 1 %, from logarithmic bins) of a per-step measurement such as a controller's
solve time, without keeping the samples.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Sequence

import pandas as pd


VC_RECORD_COLUMNS = ["time_s", "train", "predecessor", "km", "speed_mps", "predecessor_speed_mps", "gap_m", "sensed_gap_m", "communicated_gap_m",
                     "force_n", "mode", "emergency", "infeasible", "barrier_true_m", "barrier_robust_m", "speed_nominal_mps", "speed_guard_mps",
                     "speed_command_mps"]
"""Columns of the VC driver's vc_followers.csv (one row per coupled follower and record period)."""
VC_RECORD_FLOATS = [c for c in VC_RECORD_COLUMNS if c not in ("train", "predecessor", "mode", "emergency", "infeasible")]


class CsvStream:
    """Rows (tuples in ``columns`` order) appended to ``path`` every ``chunk_rows`` rows.

    The file is written with the csv module as pandas writes a frame: minimal quoting, '\\n'
    line ends, a float as its shortest repr, a missing value (None, or NaN in a float column) as
    an empty field, a value of a float column (an int too) as a float."""

    def __init__(self, path: Path, columns: Sequence[str], float_columns: Sequence[str] = (), chunk_rows: int = 50_000, floats_checked: bool = False):
        self.path = Path(path)
        self.columns = list(columns)
        self.float_columns = [c for c in float_columns if c in self.columns]
        self._float_idx = [self.columns.index(c) for c in self.float_columns]
        self.floats_checked = floats_checked
        """The caller's rows hold in their float columns only floats (never NaN) or None: written as they
        are (the same bytes; the per-row check of the other rows is skipped)."""
        self.chunk_rows = chunk_rows
        self.rows: list[tuple] = []
        self.lines: list[str] = []
        """Rows the caller formatted itself (:meth:`extend_lines`)."""
        self.written = 0
        self._started = False
        self.closed = False

    def append(self, row: tuple) -> None:
        self.rows.append(row)
        if len(self.rows) >= self.chunk_rows:
            self.flush()

    def extend(self, rows: list[tuple]) -> None:
        self.rows.extend(rows)
        if len(self.rows) >= self.chunk_rows:
            self.flush()

    def extend_lines(self, lines: list[str]) -> None:
        """Rows already formatted as the csv module writes them (fields joined by ',', a float as its
        repr, a missing value empty, a line ending in '\\n'; only text that needs no quoting, see
        :func:`csv_plain`) — the same bytes as :meth:`extend` of the rows, without the csv module's
        per-field work.  A stream takes either rows or lines, not both."""
        self.lines.extend(lines)
        if len(self.lines) >= self.chunk_rows:
            self.flush()

    def frame(self, rows: list[tuple] | None = None) -> pd.DataFrame:
        """The rows held in memory (or ``rows``) as a DataFrame with the float columns as float64."""
        df = pd.DataFrame(self.rows if rows is None else rows, columns=self.columns)
        for c in self.float_columns:
            if df[c].dtype != "float64":
                df[c] = df[c].astype("float64")
        return df

    def _cells(self, row: tuple) -> tuple:
        for i in self._float_idx:
            x = row[i]
            if x is not None and (type(x) is not float or x != x):  # noqa: PLR0124  (NaN)
                row = list(row)
                for k in self._float_idx:
                    y = row[k]
                    row[k] = None if y is None or y != y else float(y)  # noqa: PLR0124
                return tuple(row)
        return row

    def flush(self) -> None:
        if not self.rows and not self.lines and self._started:
            return
        with open(self.path, "a" if self._started else "w", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            if not self._started:
                w.writerow(self.columns)
            cells = self._cells
            w.writerows([cells(r) for r in self.rows] if self._float_idx and not self.floats_checked else self.rows)
            f.write("".join(self.lines))
        self._started = True
        self.written += len(self.rows) + len(self.lines)
        self.rows = []
        self.lines = []

    def close(self) -> None:
        if not self.closed:
            self.flush()
            self.closed = True


def csv_plain(text: str) -> bool:
    """The csv module writes ``text`` as it is (no delimiter, quote or line break in it, not empty)."""
    return bool(text) and not any(ch in text for ch in ',"\r\n')


class RunningStats:
    """Count, mean, max and quantiles of positive samples (e.g. ms), in constant memory.

    Quantiles come from logarithmic bins 1 % wide (the value reported is the bin's geometric
    middle), which is finer than the scatter of a timing on a shared machine."""

    _STEP = math.log(1.01)

    def __init__(self) -> None:
        self.count = 0
        self.total = 0.0
        self.max = -math.inf
        self._bins: dict[int, int] = {}

    def add(self, x: float) -> None:
        self.count += 1
        self.total += x
        if x > self.max:
            self.max = x
        k = math.floor(math.log(x) / self._STEP) if x > 0.0 else -10_000
        self._bins[k] = self._bins.get(k, 0) + 1

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else math.nan

    def quantile(self, q: float) -> float:
        """The q-quantile (0..1) to 1 %, nan without samples."""
        if not self.count:
            return math.nan
        need = q * (self.count - 1)
        seen = 0
        for k in sorted(self._bins):
            seen += self._bins[k]
            if seen > need:
                return 0.0 if k == -10_000 else math.exp((k + 0.5) * self._STEP)
        return self.max

    def merge(self, other: "RunningStats") -> "RunningStats":
        out = RunningStats()
        for s in (self, other):
            out.count += s.count
            out.total += s.total
            out.max = max(out.max, s.max)
            for k, n in s._bins.items():
                out._bins[k] = out._bins.get(k, 0) + n
        return out
