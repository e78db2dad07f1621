"""Unit conversions at the file boundary.

Inside vcsumo everything is SI: m, s, m/s, m/s², N, W, kg.  Line and timetable files use the
units railway engineers write (km, km/h, ‰); they are converted once, here.
"""

from __future__ import annotations

G = 9.81
"""Gravitational acceleration, m/s²."""


def kmh_to_ms(v_kmh: float) -> float:
    """Speed in km/h to m/s."""
    return v_kmh / 3.6


def ms_to_kmh(v_ms: float) -> float:
    """Speed in m/s to km/h."""
    return v_ms * 3.6


def km_to_m(km: float) -> float:
    """Distance in km to m."""
    return km * 1000.0


def permille_to_ratio(g_permille: float) -> float:
    """Gradient in ‰ (m per km) to a dimensionless rise over run."""
    return g_permille / 1000.0


def parse_clock(value: str | int | float) -> float:
    """A time of day ``"HH:MM[:SS]"`` or a number of seconds, to seconds after midnight."""
    if isinstance(value, (int, float)):
        return float(value)
    parts = str(value).strip().split(":")
    if not 2 <= len(parts) <= 3 or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"'{value}' is not a time: write HH:MM, HH:MM:SS or seconds")
    h, m = int(parts[0]), int(parts[1])
    s = int(parts[2]) if len(parts) == 3 else 0
    if m >= 60 or s >= 60:
        raise ValueError(f"'{value}' is not a valid time of day")
    return float(h * 3600 + m * 60 + s)


def format_clock(seconds: float) -> str:
    """Seconds after midnight to ``HH:MM:SS``."""
    s = int(round(seconds))
    return f"{s // 3600:02d}:{(s % 3600) // 60:02d}:{s % 60:02d}"
