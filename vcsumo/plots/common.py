"""Shared pieces of the figures: reading tables, clock-time axes, a distance axis with station names
and signals (from ``infrastructure.csv``), and train styles that stay distinct for many trains."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from vcsumo.results import read_results_csv  # noqa: E402
from matplotlib.ticker import FuncFormatter, MultipleLocator  # noqa: E402

TABLEAU20 = list(plt.get_cmap("tab20").colors)
LINE_STYLES = ["-", "--", "-.", ":"]
FAILED_COLOUR = "#bbbbbb"
UNHEALTHY_COLOUR = "#cc3311"


def read_table(table: pd.DataFrame | Path | str | None, **kw) -> pd.DataFrame | None:
    """A results table given as a DataFrame or the path of its CSV (``None`` stays ``None``)."""
    if table is None or isinstance(table, pd.DataFrame):
        return table
    path = Path(table)
    return read_results_csv(path, **kw) if path.is_file() else None


def clock(seconds: float, with_seconds: bool = False) -> str:
    """Seconds after midnight as ``HH:MM`` (``HH:MM:SS``); the day wraps (``25:10`` is ``01:10``)."""
    s = int(round(seconds)) % 86400
    return f"{s // 3600:02d}:{(s % 3600) // 60:02d}" + (f":{s % 60:02d}" if with_seconds else "")


def set_clock_axis(axis, t0_s: float, t1_s: float, target_ticks: int = 8) -> None:
    """Ticks in clock time (``HH:MM``, or ``HH:MM:SS`` below 2 minutes a tick) on a seconds axis."""
    span = max(t1_s - t0_s, 1.0)
    steps = [10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600]
    major = next((s for s in steps if span / s <= target_ticks), steps[-1])
    axis.set_major_locator(MultipleLocator(major))
    minor = next((s for s in reversed(steps) if s < major and major % s == 0 and major / s <= 6), None)
    if minor:
        axis.set_minor_locator(MultipleLocator(minor))
    axis.set_major_formatter(FuncFormatter(lambda x, _pos: clock(x, with_seconds=major < 60)))


def service_of(train: str) -> str:
    """The service a train belongs to: its id without the repeat number (``FR9701.3`` → ``FR9701``)."""
    return re.sub(r"\.\d+$", "", str(train))


def train_styles(trains: list[str]) -> tuple[dict[str, dict], dict[str, str]]:
    """Line style of every train and its legend label.

    Up to 20 trains: a colour each (tab10, tab20).  More, in 2–20 services (``FR9701.1``,
    ``FR9701.2``, ... are one service): a colour per service and one legend entry per service.
    Otherwise a style per train from 20 colours × 4 line styles (80 distinct).  Returns
    ({train: {"color", "ls"}}, {train: legend label}); in a service only its first train has a label.
    """
    trains = list(dict.fromkeys(trains))
    if len(trains) <= 20:
        colours = list(plt.get_cmap("tab10").colors) if len(trains) <= 10 else TABLEAU20
        return {t: {"color": colours[i], "ls": "-"} for i, t in enumerate(trains)}, {t: t for t in trains}
    services = list(dict.fromkeys(service_of(t) for t in trains))
    if 2 <= len(services) <= 20:
        look = {g: {"color": TABLEAU20[(2 * i) % 20 + (i // 10) % 2], "ls": "-"} for i, g in enumerate(services)}
        count = {g: sum(1 for t in trains if service_of(t) == g) for g in services}
        labels: dict[str, str] = {}
        for t in trains:
            g = service_of(t)
            if g not in {service_of(u) for u in labels}:
                labels[t] = g if count[g] == 1 else f"{g} ({count[g]} trains)"
        return {t: dict(look[service_of(t)]) for t in trains}, labels
    styles = {t: {"color": TABLEAU20[(2 * i) % 20 + (i // 10) % 2], "ls": LINE_STYLES[(i // 20) % len(LINE_STYLES)]} for i, t in enumerate(trains)}
    return styles, {t: t for t in trains}


def station_ticks(infra: pd.DataFrame | None, section: str = "main", km_range: tuple[float, float] | None = None,
                  min_spacing: float = 0.0) -> list[tuple[float, str]]:
    """(km, label) of the stations (and junctions, in brackets) of a section, thinned so that no two
    are closer than ``min_spacing`` km (stations win over junctions)."""
    if infra is None or infra.empty:
        return []
    rows = infra[(infra["section"] == section) & infra["kind"].isin(["station", "junction"])]
    items = []
    for _, r in rows.iterrows():
        km = float(r["km"])
        if km_range is not None and not km_range[0] - 1e-6 <= km <= km_range[1] + 1e-6:
            continue
        name = str(r["name"]) if isinstance(r["name"], str) and r["name"] else str(r["id"])
        items.append((km, name if r["kind"] == "station" else f"({name})", r["kind"] == "station"))
    kept: list[tuple[float, str, bool]] = []
    for item in sorted(items, key=lambda x: (not x[2], x[0])):  # stations first
        if all(abs(item[0] - k[0]) >= min_spacing for k in kept):
            kept.append(item)
    return [(km, name) for km, name, _ in sorted(kept)]


def distance_axis(ax, infra: pd.DataFrame | None, directions: list[str] | tuple[str, ...] = ("up", "down"), section: str = "main",
                  axis: str = "y", signals: bool = True) -> None:
    """Station names on a km axis (the km themselves on the opposite side), light lines across at
    the stations, and the signals of ``directions`` as marks along the axis (▲ up, ▼ down)."""
    lo, hi = ax.get_ylim() if axis == "y" else ax.get_xlim()
    lo, hi = min(lo, hi), max(lo, hi)
    fig_inches = ax.get_window_extent().height / ax.figure.dpi if axis == "y" else ax.get_window_extent().width / ax.figure.dpi
    spacing = (hi - lo) * (0.11 if axis == "y" else 0.9) / max(fig_inches, 0.5)  # about a label's height (width)
    ticks = station_ticks(infra, section, (lo, hi), spacing)
    if axis == "y":
        sec = ax.secondary_yaxis("right")
        sec.set_ylabel("km")
        if ticks:
            ax.set_yticks([k for k, _ in ticks], [n for _, n in ticks], fontsize=7)
        for k, _ in ticks:
            ax.axhline(k, color="0.75", lw=0.6, zorder=0)
    else:
        sec = ax.secondary_xaxis("top")
        if ticks:
            sec.set_xticks([k for k, _ in ticks], [n for _, n in ticks], fontsize=6, rotation=30, ha="left")
        for k, _ in ticks:
            ax.axvline(k, color="0.75", lw=0.6, zorder=0)
    if not signals or infra is None or infra.empty:
        return
    sig = infra[(infra["kind"] == "signal") & (infra["section"] == section) & infra["direction"].isin(list(directions))]
    # just outside the axes, between the axis line and the station names
    for d, pos in (("up", -0.007), ("down", -0.018)):
        kms = sig.loc[sig["direction"] == d, "km"].to_numpy(dtype=float)
        kms = kms[(kms >= lo) & (kms <= hi)]
        if not len(kms):
            continue
        label = f"signal ({d})"
        if axis == "y":
            ax.plot(np.full(len(kms), pos), kms, ls="none", marker="^" if d == "up" else "v", ms=3, color="0.3",
                    transform=ax.get_yaxis_transform(), clip_on=False, label=label, zorder=3)
        else:
            ax.plot(kms, np.full(len(kms), pos * 1.6), ls="none", marker=">" if d == "up" else "<", ms=3, color="0.3",
                    transform=ax.get_xaxis_transform(), clip_on=False, label=label, zorder=3)
    if axis == "y":
        ax.tick_params(axis="y", which="major", pad=14)
    else:
        ax.tick_params(axis="x", which="major", pad=12)
