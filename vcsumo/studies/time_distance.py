"""The capacity study's example sequences as a tidy table, ``time_distance.csv``, so that the
time–distance figure (:func:`vcsumo.plots.capacity.plot_time_distance_stairs`) reads only results.

One panel per regime: the first direction and stopping pattern, the largest convoy.  Rows:

* ``kind = block`` — FBS blocking time of one block for one unit: from the approach point's time to
  the tail clearing the next signal (``t_from_s``–``t_to_s``, ``km_from``–``km_to``);
* ``kind = band`` — MB / VC: the track reserved for a unit at one km of its leader's run, from the time
  the reservation ahead of the leader (its supervised braking distance + margin and position errors,
  the separation model's rule the headway is computed with) first reaches it until the rear of the
  unit's last train has passed (a convoy's followers at the coupled spacing the analytic headway
  takes): ``t_from_s``–``t_to_s`` at ``km_from`` (= ``km_to``);
* ``kind = schedule`` — the leader's unhindered run, shifted by the release interval (``t_from_s``, ``km_from``);
* ``kind = train`` — a simulated train of the run at the minimum headway (``train``, ``t_from_s``, ``km_from``);
* ``kind = failed`` — the case of the panel failed: ``note`` holds its error, the panel has no other rows.

Times are seconds after the first unit's release; km are main-line chainage.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from vcsumo.running_time import time_at

TIME_DISTANCE_COLUMNS = ["panel", "regime", "controller", "convoy_size", "direction", "stopping_pattern", "headway_s", "unit", "train", "kind",
                         "t_from_s", "t_to_s", "km_from", "km_to", "note"]
TIME_DISTANCE_FILE = "time_distance.csv"
TRACE_EVERY = 10
"""Every 10th step of a simulated train's trace is kept (a point every 1–5 s)."""


def reserved_from(reservation: pd.DataFrame, run: pd.DataFrame) -> np.ndarray:
    """Time at which the track reserved ahead of the leader (``reservation``: front ``s_m`` →
    ``reserved_to_m``) first reaches each position of the leader's run (``run``: ``time_s, s_m``), s;
    positions reserved already at the run's start get its first time."""
    s = run["s_m"].to_numpy(dtype=float)
    front = reservation["s_m"].to_numpy(dtype=float)
    reach = np.maximum.accumulate(reservation["reserved_to_m"].to_numpy(dtype=float))
    k = np.clip(np.searchsorted(reach, s, side="left"), 1, len(reach) - 1)  # the first front whose reservation reaches x
    lo, hi = reach[k - 1], reach[k]
    frac = np.where(hi > lo, (s - lo) / np.where(hi > lo, hi - lo, 1.0), 1.0)
    y = np.where(s <= reach[0], front[0], front[k - 1] + np.clip(frac, 0.0, 1.0) * (front[k] - front[k - 1]))
    return time_at(run, np.maximum(y, s[0]))


def _panel_rows(panel: int, regime: str, res, setups: dict) -> list[dict]:
    setup = setups[res.units[0][0].direction]
    full = setup.full
    run = res.run
    t = run.time_s.to_numpy()
    s = run.s_m.to_numpy()
    km = np.array([full.km_at(x)[1] for x in s])
    stock = res.units[0][0].stock
    n = len(res.units[0])
    base = dict(panel=panel, regime=regime, controller=res.row.get("controller") or "", convoy_size=n, direction=setup.direction,
                stopping_pattern=res.row.get("stopping_pattern", ""), headway_s=round(float(res.h), 3), train="", note="")
    rows: list[dict] = []
    for j in range(len(res.units)):
        shift = j * res.h
        if res.blocks is not None:
            for _, b in res.blocks.iterrows():
                rows.append(dict(base, unit=j, kind="block", t_from_s=b.t_approach_s + shift, t_to_s=b.t_clear_s + shift,
                                 km_from=full.km_at(b.block_start_m)[1], km_to=full.km_at(b.block_end_m)[1]))
        else:
            t_app = reserved_from(res.theory.reservation, run)
            t_clr = time_at(run, s + stock.length_m)  # the unit's last train's rear passes (its front at s + L)
            if res.theory.rear_lag is not None:
                t_clr = t_clr + res.theory.rear_lag(s + stock.length_m)
            rows += [dict(base, unit=j, kind="band", t_from_s=a + shift, t_to_s=c + shift, km_from=k, km_to=k)
                     for a, c, k in zip(t_app, t_clr, km) if c == c]
        rows += [dict(base, unit=j, kind="schedule", t_from_s=tt + shift, t_to_s=math.nan, km_from=k, km_to=math.nan)
                 for tt, k in zip(t[::TRACE_EVERY], km[::TRACE_EVERY])]
    traces = res.probe.sim.speed_traces if res.probe is not None else {}
    dt = float(run.time_s.iloc[1] - run.time_s.iloc[0]) if len(run) > 1 else 1.0
    for j, u in enumerate(res.units):
        for tr in u:
            if tr.id in traces:
                ts, _ = traces[tr.id]
                off = full.length_m - tr.profile.length_m
                idx = np.arange(len(ts))[::TRACE_EVERY]
                rows += [dict(base, unit=j, train=tr.id, kind="train", t_from_s=tr.depart_s + i * dt, t_to_s=math.nan,
                              km_from=full.km_at(ts[i] + off)[1], km_to=math.nan) for i in idx]
    return rows


def time_distance_table(examples: dict, setups: dict, failed: dict | None = None) -> pd.DataFrame:
    """The rows of every example (``{regime: CaseResult}``) and of every failed example
    (``{regime: (Case, error)}``), in the order FBS, MB, VC."""
    rows: list[dict] = []
    failed = failed or {}
    for panel, regime in enumerate(r for r in ("fbs", "mb", "vc") if r in examples or r in failed):
        if regime in examples:
            rows += _panel_rows(panel, regime, examples[regime], setups)
        else:
            case, error = failed[regime]
            rows.append(dict(panel=panel, regime=regime, controller=case.controller or "", convoy_size=case.convoy_size, direction=case.direction,
                             stopping_pattern=case.pattern, headway_s=math.nan, unit=0, train="", kind="failed", t_from_s=math.nan,
                             t_to_s=math.nan, km_from=math.nan, km_to=math.nan, note=str(error)))
    df = pd.DataFrame(rows, columns=TIME_DISTANCE_COLUMNS)
    for c in ("t_from_s", "t_to_s", "km_from", "km_to"):
        df[c] = df[c].astype(float).round(4)
    return df


def write_time_distance(examples: dict, setups: dict, out: Path, failed: dict | None = None) -> Path:
    """Write ``time_distance.csv`` into the results folder; returns its path."""
    path = Path(out) / TIME_DISTANCE_FILE
    time_distance_table(examples, setups, failed).to_csv(path, index=False)
    return path
