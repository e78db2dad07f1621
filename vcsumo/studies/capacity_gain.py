"""The capacity study's gain over FBS: quoted only between results that are shown safe.

``gain_vs_fbs`` = capacity / FBS capacity in the same direction and stopping pattern, for a row
that finished and is healthy, against an FBS row that finished and is healthy; otherwise NaN.  An
unhealthy row (a gap below the safe separation, a collision, overspeed, a skipped stop, ...) is not
a result to quote, and neither is a ratio that rests on one: until unseen-studies (2026-12-01) the
gain was the plain ratio whatever the health of either row, so a healthy VC row read "×2.0" over an
FBS capacity measured in a run that was not healthy, and an unhealthy VC row carried its gain in
the table and on the chart like any other.
"""

from __future__ import annotations

import math

import pandas as pd


def _text(x) -> str:
    """A cell as text; NaN (an empty cell read back from a CSV) is ''."""
    return "" if x is None or (isinstance(x, float) and math.isnan(x)) else str(x).strip()


def _clean(row: pd.Series) -> bool:
    """Finished (no error) and healthy (bools, or text read back from a CSV)."""
    healthy = str(row.get("healthy", "")).strip().lower() in ("true", "1", "1.0")
    return healthy and not _text(row.get("error", ""))


def gains_vs_fbs(df: pd.DataFrame) -> pd.Series:
    """``gain_vs_fbs`` of every row of a capacity table (index of ``df``), rounded to 3 digits."""
    out = pd.Series(math.nan, index=df.index, dtype=float)
    for _, g in df.groupby(["direction", "stopping_pattern"]):
        fbs = g[(g.regime == "fbs") & g.capacity_trains_per_h.notna()]
        if not len(fbs) or not _clean(fbs.iloc[0]):
            continue  # no FBS result shown safe in this direction and pattern: no gain to quote
        base = float(fbs.iloc[0].capacity_trains_per_h)
        for i, r in g.iterrows():
            if _clean(r) and r.capacity_trains_per_h == r.capacity_trains_per_h:
                out[i] = round(float(r.capacity_trains_per_h) / base, 3)
    return out


__all__ = ["gains_vs_fbs"]
