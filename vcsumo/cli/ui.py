"""Terminal output shared by every command: consoles, progress bars and result tables.

Results go to stdout (``out_console``), diagnostics and progress to stderr (``console``, also the
logging handler's console, see :mod:`vcsumo.log`).  Tables fit the terminal (100 columns when stdout
is not a terminal): short headers with units (:data:`LABELS`), values never cut, numbers rounded per
column, failed rows with their error text below the table; columns that do not fit are left out
and the CSV that holds them is named.
"""

from __future__ import annotations

import math
import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import pandas as pd
from rich import box
from rich.cells import cell_len
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from vcsumo.log import verbosity

PIPE_WIDTH = 100
"""Width of tables written to a pipe or a file (``$COLUMNS`` if set)."""

console = Console(stderr=True)
out_console = Console(width=None if sys.stdout.isatty() or os.environ.get("COLUMNS") else PIPE_WIDTH, soft_wrap=True)
"""Results on stdout; lines of text are not wrapped (a path stays on one line), tables fit the width."""


def progress_bar() -> Progress:
    """A progress bar on stderr; none with ``-q``."""
    return Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=False, disable=verbosity() < 0,
    )


@contextmanager
def progress_task(progress: Progress, description: str) -> Iterator:
    task = progress.add_task(description, total=1.0)

    def update(done: float, total: float) -> None:
        progress.update(task, completed=min(done / total, 1.0) if total else 1.0)

    yield update
    progress.update(task, completed=1.0)


# ----------------------------------------------------------------------------------------------
# Tables

LABELS = {
    # capacity, headway
    "direction": "dir", "stopping_pattern": "pattern", "regime": "regime", "controller": "controller", "convoy_size": "n",
    "headway_sim_s": "h sim s", "headway_analytic_s": "h theory s", "intra_convoy_gap_m": "convoy gap m",
    "capacity_trains_per_h": "capacity tr/h", "gain_vs_fbs": "gain ×FBS", "min_gap_m": "min gap m", "gap_violations": "gap viol.",
    "collisions": "coll.", "unhealthy_runs": "unhealthy", "emergency_brakes": "SUMO e-stops", "measuring_point_km": "point km", "deviation_pct": "dev. %",
    "speed_at_point_mps": "v m/s", "critical_section_km": "critical km", "release_interval_s": "release s", "simulations": "sims",
    "guard_interventions": "guard", "healthy": "healthy", "min_margin_m": "margin m", "convoy_formed": "formed",
    # run
    "run_min": "run min", "delay_s": "delay s",
    # batch
    "punct_3min_%": "punct. ≤3 min %", "punct_5min_%": "punct. ≤5 min %", "mean_arrival_delay_s": "mean delay s",
    "knock_on_delay_s": "knock-on delay s", "uic406_%": "UIC 406 %", "uic406_cyc_%": "UIC 406 cyclic %",
    # reproductions
    "stop_distance_m": "stop dist. m", "paper_stop_distance_m": "paper stop dist. m", "stop_delay_s": "stop delay s",
    "paper_stop_delay_s": "paper stop delay s", "gap_at_rest_m": "gap at rest m",
    # junction
    "junction_kind": "kind", "trains_per_h": "tr/h", "forms_before_m": "forms before m", "violations": "gap viol.",
    # safety
    "supervised": "CBF", "failed_runs": "failed", "scenarios_with_violation": "scen. with viol.", "min_gap_margin_m": "min margin m",
    "started_outside_safe_set": "outside safe set", "barrier_breaches": "barrier breaches", "emergency_activations_mean": "emerg. mean",
    "time_lost_s_mean": "time lost s",
}
"""Short table headers of CSV column names (units kept); others are derived by :func:`label`."""

_UNITS = [("_trains_per_h", " tr/h"), ("_per_h", " /h"), ("_mps2", " m/s²"), ("_mps", " m/s"), ("_kmh", " km/h"), ("_km", " km"),
          ("_pct", " %"), ("_min", " min"), ("_s", " s"), ("_m", " m"), ("_n", " N"), ("_w", " W")]
_COUNT_WORDS = ("violations", "collisions", "brakes", "runs", "failed", "simulations", "scenarios", "size", "breaches", "interventions",
                "activations", "trains", "count", "steps", "events")


def label(column: str) -> str:
    """Short header of a CSV column: :data:`LABELS`, else words with the unit (``time_loss_s`` → ``time loss s``)."""
    if column in LABELS:
        return LABELS[column]
    for suffix, unit in _UNITS:
        if column.endswith(suffix) and len(column) > len(suffix):
            return column[: -len(suffix)].replace("_", " ") + unit
    return column.replace("_", " ")


def _is_count(column: str) -> bool:
    if any(column.endswith(s) for s, _ in _UNITS):
        return False
    return any(w in column for w in _COUNT_WORDS)


def _missing(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v)) or v is pd.NA or v is pd.NaT


def column_formatter(values: pd.Series, column: str):
    """A function value → text for one column: counts as integers, measures to 1–3 decimals by the
    column's largest magnitude, missing values as ``–``."""
    num = pd.to_numeric(values, errors="coerce") if values.dtype.kind in "fiu" else None
    if values.dtype.kind == "b" or num is None:
        return lambda v: "–" if _missing(v) or (isinstance(v, str) and v.strip() == "") else ("yes" if v is True else "no" if v is False else str(v))
    finite = num[num.notna() & (num.abs() != math.inf)]
    integral = len(finite) == 0 or bool((finite == finite.round()).all())
    if values.dtype.kind in "iu" or (integral and _is_count(column)):
        return lambda v: "–" if _missing(v) else f"{int(v)}"
    biggest = float(finite.abs().max()) if len(finite) else 0.0
    decimals = 0 if biggest >= 10000 else 1 if biggest >= 10 else 2 if biggest >= 0.1 or biggest == 0 else 3

    def fmt(v) -> str:
        if _missing(v):
            return "–"
        text = f"{float(v):.{decimals}f}"
        return "0" if float(text) == 0 else text  # no "-0.0"

    return fmt


def _row_failed(row: pd.Series) -> str:
    err = row.get("error")
    return "" if _missing(err) else str(err).strip()


def _row_key(row: pd.Series, cols: list[str], numeric: set[str]) -> str:
    # (yes/no columns — healthy, convoy_formed — name no case: "False False" said nothing)
    parts = [str(row[c]) for c in cols if c not in numeric and not _missing(row[c]) and str(row[c]).strip() and str(row[c]) not in ("True", "False")]
    if "convoy_size" in row.index and not _missing(row["convoy_size"]) and row.get("regime") == "vc":
        parts.append(f"n={int(row['convoy_size'])}")
    return " ".join(parts)


def _two_line_width(text: str) -> int:
    words = text.split()
    if len(words) < 2:
        return cell_len(text)
    return min(max(cell_len(" ".join(words[:k])), cell_len(" ".join(words[k:]))) for k in range(1, len(words)))


HEALTH_COUNTERS = ("gap_violations", "collisions", "stops_skipped", "short_dwells", "overspeed_events", "beyond_service_brakings",
                   "authority_overruns", "sumo_emergency_stops", "sumo_emergency_brakings", "sumo_stop_warnings", "teleports")
"""Columns of a study row that make it not healthy when not 0 (named in the table's note)."""


def build_table(df: pd.DataFrame, title: str, columns: list[str] | None = None, width: int = PIPE_WIDTH,
                csv_path: Path | str | None = None, drop_first: list[str] | None = None) -> tuple[Table, list[str]]:
    """The table of ``columns`` of ``df`` fitting ``width`` terminal columns, and the notes to print
    below it (failed and unhealthy rows with their error text; columns left out and where they are).

    When the columns do not fit, ``drop_first`` are left out first, then the others from the last.
    """
    cols = [c for c in (columns or list(df.columns)) if c in df.columns]
    numeric = {c for c in cols if df[c].dtype.kind in "fiu"}
    fmts = {c: column_formatter(df[c], c) for c in cols}
    failed = [_row_failed(r) for _, r in df.iterrows()]
    cells: dict[str, list[str]] = {c: [fmts[c](v) for v in df[c]] for c in cols}
    for i, err in enumerate(failed):  # "failed" in the first empty number of a failed row
        blank = next((c for c in cols if c in numeric and cells[c][i] == "–"), None)
        if err and blank is not None:
            cells[blank][i] = "failed"
    notes = []
    for (_, row), err in zip(df.iterrows(), failed):
        if err:
            notes.append(f"failed: {_row_key(row, cols, numeric)}: {err}")
        elif str(row.get("healthy", "")) == "False":
            why = [f"{c} {row[c]:g}" for c in HEALTH_COUNTERS if c in row.index and isinstance(row[c], (int, float)) and row[c] == row[c] and row[c] != 0]
            notes.append(f"not healthy: {_row_key(row, cols, numeric)}" + (f" ({', '.join(why)})" if why else ""))

    def need(c: str) -> int:
        words = max((cell_len(w) for w in label(c).split()), default=1)
        return max([words] + [cell_len(x) for x in cells[c]])

    shown = list(cols)
    order = [c for c in (drop_first or []) if c in cols] + [c for c in reversed(cols) if c not in (drop_first or [])]
    while len(shown) > 1 and sum(need(c) for c in shown) + 2 * (len(shown) - 1) + 1 > width:  # 2 between columns, 1 at the end
        shown.remove(next(c for c in order if c in shown))
    dropped = [c for c in cols if c not in shown]
    if dropped:
        verb = "are" if len(dropped) > 1 else "is"
        where = f" {verb} in {csv_path}" if csv_path else f" {verb} left out"
        notes.append(f"{len(dropped)} more column{'s' if len(dropped) > 1 else ''} ({', '.join(dropped)}){where}")
    # widths: every column its widest cell and longest header word; what is left goes to headers,
    # first so that each fits on two lines, then on one, the cheapest first (rich's own shrinking
    # of columns may cut cells)
    widths = {c: need(c) for c in shown}
    spare = width - (sum(widths.values()) + 2 * (len(shown) - 1) + 1)
    for target in (_two_line_width, lambda text: cell_len(text)):
        for c in sorted(shown, key=lambda c: target(label(c)) - widths[c]):
            extra = target(label(c)) - widths[c]
            if 0 < extra <= spare:
                widths[c] += extra
                spare -= extra
    table = Table(title=title, box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False, collapse_padding=True, padding=(0, 1))
    for c in shown:
        table.add_column(label(c), justify="right" if c in numeric else "left", width=widths[c], overflow="fold")
    for i in range(len(df)):
        table.add_row(*[cells[c][i] for c in shown], style="red" if failed[i] else None)
    return table, notes


def print_table(df: pd.DataFrame, title: str, columns: list[str] | None = None, csv_path: Path | str | None = None,
                to: Console | None = None, drop_first: list[str] | None = None) -> None:
    """Print a result table on stdout (or ``to``), fitting its width; see :func:`build_table`."""
    con = to or out_console
    table, notes = build_table(df, title, columns, width=con.width, csv_path=csv_path, drop_first=drop_first)
    con.print(table)
    for n in notes:
        con.print(n, markup=False, highlight=False, soft_wrap=False)  # prose: wrapped to the width
