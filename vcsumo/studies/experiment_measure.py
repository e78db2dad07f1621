"""What an offline experiment records and measures (:mod:`vcsumo.studies.experiment`).

:class:`Recorder` is the offline loop's ``on_step`` hook: it keeps every step's positions, speeds,
emergency flags, barrier values, τ̄ and modes in compact arrays (every counter armed from the
first step, whatever ``record_every`` is) and the rows of ``trajectories.csv`` (every
``record_every``-th step, plus every step a follower receives a packet or brakes in emergency).

:func:`measure` turns a run into tidy rows ``(train, window, quantity, value, unit)``: minimum gaps
front to rear and front to front, collisions, emergency activations and episodes, barrier extremes,
the wall-clock time of each follower's stack per step (``step_time_*_ms``) and its controller's solve
times, packets, the gaps in the file's windows (time and/or speed) and,
with ``measurements.stop``, the leader's stop: brake onset, stop delays, the gap at the onset
(``gap_at_brake_onset_m``) and once both stand (``gap_at_rest_m``).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from vcsumo.control.base import Command, Observation
from vcsumo.sim.offline import OfflineStep
from vcsumo.studies.experiment_model import Experiment, GapWindow

TRAJECTORY_COLUMNS = [
    "time_s", "train", "position_m", "speed_mps", "accel_mps2", "force_n", "force_cmd_n", "gap_front_to_rear_m", "gap_front_to_front_m", "mode",
    "nominal_mode", "emergency", "infeasible", "gap_ref_m", "robust_barrier_m", "true_barrier_m", "info_age_s", "tau_bar_s", "z_tau1_m", "z_tau2_m",
    "z_tau3_m", "packet_received", "packet_delay_s",
]
"""Columns of ``trajectories.csv`` (besides run, variant, seed): the true front position (m), the
applied force and the driver's command (N), the gaps to the train ahead (front of it to our front
minus its length: front-to-rear; without: front-to-front), the active mode and the nominal
controller's, the CBF's robust and true barrier (m), the age of the last packet (s), τ̄ (s), the
cruise references z_τ1..3 (m), and whether a new packet arrived this step with its delay (s)."""


class Timed:
    """A driver with the wall-clock time of each of its steps (``seconds``), for the measurements."""

    def __init__(self, driver):
        self.driver = driver
        self.seconds: list[float] = []

    def make_step(self, obs: Observation) -> Command:
        c0 = time.perf_counter()
        cmd = self.driver.make_step(obs)
        self.seconds.append(time.perf_counter() - c0)
        return cmd

    @property
    def events(self) -> list:
        return getattr(self.driver, "events", None) or []


@dataclass
class Recorder:
    """``on_step`` hook of :func:`~vcsumo.sim.offline.run_convoy` (see the module doc)."""

    ids: list[str]
    lengths_m: list[float]
    record_every: int
    t: list = field(default_factory=list)
    pos: list = field(default_factory=list)
    speed: list = field(default_factory=list)
    emergency: list = field(default_factory=list)
    robust_b: list = field(default_factory=list)
    true_b: list = field(default_factory=list)
    tau: list = field(default_factory=list)
    z2: list = field(default_factory=list)
    modes: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    infeasible: list = field(default_factory=list)
    packets: list = field(default_factory=list)
    """(follower index, time received, delay s) of every new packet from the predecessor."""

    def __post_init__(self) -> None:
        self._last_rx = [-math.inf] * len(self.ids)

    def __call__(self, step: OfflineStep) -> None:
        xs, cmds, obss = step.states, step.commands, step.observations
        n = len(xs)
        t = step.time_s
        self.t.append(t)
        self.pos.append([x.s_m for x in xs])
        self.speed.append([x.v_mps for x in xs])
        self.emergency.append([bool(c.emergency) for c in cmds])
        self.infeasible.append([bool(c.infeasible) for c in cmds])
        infos = [c.info if isinstance(c.info, dict) else {} for c in cmds]
        self.robust_b.append([infos[i].get("cbf_barrier_m", math.nan) for i in range(1, n)])
        self.true_b.append([infos[i].get("cbf_true_barrier_m", math.nan) for i in range(1, n)])
        self.tau.append([infos[i].get("tau_bar_s", math.nan) for i in range(1, n)])
        self.z2.append([infos[i].get("z_tau2_m", math.nan) for i in range(1, n)])
        self.modes.append([infos[i].get("nominal_mode", cmds[i].mode) for i in range(1, n)])
        rx = [False] * n
        delay = [math.nan] * n
        for i in range(1, n):
            msg = obss[i].received.get(self.ids[i - 1])
            if msg is not None and msg.received_time_s > self._last_rx[i]:
                self._last_rx[i] = msg.received_time_s
                rx[i] = True
                delay[i] = msg.received_time_s - msg.sent_time_s
                self.packets.append((i, t, delay[i]))
        if step.k % self.record_every and not any(rx) and not any(c.emergency for c in cmds):
            return
        for i, (x, c) in enumerate(zip(xs, cmds)):
            info = infos[i]
            ff = xs[i - 1].s_m - x.s_m if i else math.nan
            self.rows.append((
                t, self.ids[i], x.s_m, x.v_mps, x.accel_mps2, x.force_n, float(c.force_n), ff - self.lengths_m[i - 1] if i else math.nan, ff, c.mode,
                info.get("nominal_mode", c.mode), bool(c.emergency), bool(c.infeasible), info.get("gap_ref_m", math.nan), info.get("cbf_barrier_m", math.nan),
                info.get("cbf_true_barrier_m", math.nan), info.get("cbf_info_age_s", math.nan), info.get("tau_bar_s", math.nan), info.get("z_tau1_m", math.nan),
                info.get("z_tau2_m", math.nan), info.get("z_tau3_m", math.nan), rx[i], delay[i],
            ))

    def arrays(self) -> dict:
        """Every step: t (K), pos/speed/emergency (K × n), gaps (K × n−1, front to rear and front to front) and the followers' values."""
        pos = np.array(self.pos, dtype=float)
        ff = pos[:, :-1] - pos[:, 1:]
        lengths = np.array(self.lengths_m[:-1], dtype=float)
        return {
            "t": np.array(self.t, dtype=float), "pos": pos, "speed": np.array(self.speed, dtype=float), "emergency": np.array(self.emergency, dtype=bool),
            "infeasible": np.array(self.infeasible, dtype=bool), "gap_ff": ff, "gap_fr": ff - lengths, "robust_b": np.array(self.robust_b, dtype=float).reshape(len(self.t), -1),
            "true_b": np.array(self.true_b, dtype=float).reshape(len(self.t), -1), "tau": np.array(self.tau, dtype=float).reshape(len(self.t), -1),
            "z2": np.array(self.z2, dtype=float).reshape(len(self.t), -1),
            "modes": [[m[j] for m in self.modes] for j in range(len(self.ids) - 1)],
        }


# -------------------------------------------------------------------------------------------
# Measurements


def stop_time(t: np.ndarray, v: np.ndarray, after: float = 0.0, v_stop: float = 0.01) -> float:
    """First time ≥ ``after`` from which the train stays below ``v_stop`` to the end of the run (NaN: moving at the end)."""
    moving = np.flatnonzero((v > v_stop) & (t >= after - 1e-9))
    if len(moving) == 0:
        idx = np.flatnonzero(t >= after - 1e-9)
        return float(t[idx[0]]) if len(idx) else math.nan
    last = moving[-1]
    return float(t[last + 1]) if last + 1 < len(t) else math.nan


def onsets(flags: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Times of the rising edges of a boolean series."""
    f = flags.astype(bool)
    return t[np.flatnonzero(f & ~np.concatenate(([False], f[:-1])))]


def episodes(flags: np.ndarray, t: np.ndarray, gap_s: float = 10.0) -> int:
    """Emergency episodes: activations more than ``gap_s`` after the previous release start a new one."""
    f = flags.astype(bool)
    on_t = onsets(f, t)
    off_t = t[np.flatnonzero(~f & np.concatenate(([False], f[:-1])))]
    n = 0
    for t_on in on_t:
        prev = off_t[off_t <= t_on]
        if n == 0 or len(prev) == 0 or t_on - prev[-1] > gap_s:
            n += 1
    return n


def window_mask(w: GapWindow, t: np.ndarray, v_lead: np.ndarray, v_f: np.ndarray, dt: float) -> np.ndarray:
    """Steps of a gap window: its time span, both trains at its speed, in stretches of ≥ min_hold_s."""
    m = (t >= w.from_s - 1e-9) & (t < (w.to_s if w.to_s is not None else np.inf) - 1e-9)
    if w.speed_mps is not None:
        m &= (np.abs(v_lead - w.speed_mps) <= w.tolerance_mps) & (np.abs(v_f - w.speed_mps) <= w.tolerance_mps)
    if w.min_hold_s > 0 and m.any():
        edges = np.diff(np.concatenate(([0], m.astype(int), [0])))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        keep = np.zeros_like(m)
        for a, b in zip(starts, ends):
            if (b - a) * dt >= w.min_hold_s - 1e-9:
                keep[a:b] = True
        m = keep
    return m


def _stats(values: np.ndarray) -> tuple[float, float, float]:
    v = values[np.isfinite(values)]
    return (float(v.mean()), float(v.min()), float(v.max())) if len(v) else (math.nan, math.nan, math.nan)


def measure(exp: Experiment, arr: dict[str, np.ndarray], ids: list[str], lengths_m: list[float], followers: list, timers: list[Timed],
            leader_brake_s: float | None, packets: list, channel) -> list[tuple[str, str, str, float, str]]:
    """Tidy measurement rows (train, window, quantity, value, unit) of one run (see the module doc)."""
    out: list[tuple[str, str, str, float, str]] = []

    def add(train: str, window: str, quantity: str, value, unit: str) -> None:
        out.append((train, window, quantity, float(value) if value is not None else math.nan, unit))

    t, v = arr["t"], arr["speed"]
    dt = exp.step_s
    if channel is not None:
        add("", "", "packets_sent", channel.sent, "-")
        add("", "", "packets_delivered", channel.delivered, "-")
        add("", "", "packets_lost", channel.lost, "-")
    for i, tid in enumerate(ids):
        add(tid, "", "max_speed_mps", v[:, i].max(), "m/s")
        add(tid, "", "stop_time_s", stop_time(t, v[:, i]), "s")
    add(ids[0], "", "leader_final_position_m", arr["pos"][-1, 0], "m")
    for j, setup in enumerate(followers):
        i = j + 1
        tid = ids[i]
        fr, ff = arr["gap_fr"][:, j], arr["gap_ff"][:, j]
        add(tid, "", "min_gap_front_to_rear_m", fr.min(), "m")
        add(tid, "", "min_gap_front_to_front_m", ff.min(), "m")
        add(tid, "", "collisions", int(np.sum((fr[1:] < 0) & (fr[:-1] >= 0)) + int(fr[0] < 0)), "-")
        em = arr["emergency"][:, i]
        add(tid, "", "emergency_activations", len(onsets(em, t)), "-")
        add(tid, "", "emergency_episodes", episodes(em, t), "-")
        add(tid, "", "emergency_time_s", em.sum() * dt, "s")
        add(tid, "", "infeasible_steps", int(arr["infeasible"][:, i].sum()), "-")
        rb, tb = arr["robust_b"][:, j], arr["true_b"][:, j]
        if np.isfinite(rb).any():
            add(tid, "", "robust_barrier_max_m", np.nanmax(rb), "m")
            add(tid, "", "robust_barrier_min_m", np.nanmin(rb), "m")
        if np.isfinite(tb).any():
            add(tid, "", "true_barrier_max_m", np.nanmax(tb), "m")
            add(tid, "", "true_barrier_positive_steps", int(np.sum(tb > 0)), "-")
        sup = getattr(setup.stack, "supervisor", None)
        stats = getattr(sup, "stats", None)
        if stats is not None and hasattr(stats, "tmax_activations"):
            add(tid, "", "tmax_activations", stats.tmax_activations, "-")
        cpu = np.array(timers[j].seconds) * 1e3
        if len(cpu):
            add(tid, "", "step_time_mean_ms", cpu.mean(), "ms")
            add(tid, "", "step_time_p99_ms", np.percentile(cpu, 99), "ms")
            add(tid, "", "step_time_max_ms", cpu.max(), "ms")
        nominal = setup.stack.nominal
        st = getattr(nominal, "stats", None)
        solve = np.array(getattr(st, "solve_times_s", []) or [], dtype=float) * 1e3
        if len(solve):
            add(tid, "", "solve_time_median_ms", np.median(solve), "ms")
            add(tid, "", "solve_time_mean_ms", solve.mean(), "ms")
            add(tid, "", "solve_time_p99_ms", np.percentile(solve, 99), "ms")
        if hasattr(nominal, "solves"):
            add(tid, "", "qp_solves", nominal.solves, "-")
            add(tid, "", "qp_failures", getattr(nominal, "failed_solves", 0), "-")
        counts = Counter(arr["modes"][j])
        total = sum(counts.values()) or 1
        for mode, c in sorted(counts.items()):
            add(tid, "", f"share_{mode}", c / total, "-")
        d = [p[2] for p in packets if p[0] == i]
        if d:
            add(tid, "", "packet_delay_mean_s", np.mean(d), "s")
            add(tid, "", "packet_delay_max_s", np.max(d), "s")
        for w in exp.measurements.gap_windows:
            m = window_mask(w, t, v[:, 0], v[:, i], dt)
            add(tid, w.name, "window_duration_s", m.sum() * dt, "s")
            if not m.any():
                continue
            for name, series in (("front_to_rear", fr), ("front_to_front", ff)):
                mean, lo, hi = _stats(series[m])
                add(tid, w.name, f"gap_{name}_mean_m", mean, "m")
                add(tid, w.name, f"gap_{name}_min_m", lo, "m")
                add(tid, w.name, f"gap_{name}_max_m", hi, "m")
            add(tid, w.name, "leader_speed_mean_mps", v[m, 0].mean(), "m/s")
            add(tid, w.name, "speed_mean_mps", v[m, i].mean(), "m/s")
            tau = arr["tau"][m, j]
            if np.isfinite(tau).any():
                add(tid, w.name, "tau_bar_mean_s", np.nanmean(tau), "s")
            z2 = arr["z2"][m, j]
            if np.isfinite(z2).any():
                add(tid, w.name, "reference_gap_mean_m", np.nanmean(arr["pos"][m, i - 1] - lengths_m[i - 1] - z2), "m")
    if exp.measurements.stop is not None:
        out += stop_rows(exp, arr, ids, leader_brake_s)
    return out


def stop_rows(exp: Experiment, arr: dict[str, np.ndarray], ids: list[str], leader_brake_s: float | None) -> list[tuple[str, str, str, float, str]]:
    """The leader's stop: brake onset, stop times and delays, gaps at the onset, at the leader's stop and at rest."""
    t, v = arr["t"], arr["speed"]
    rows: list[tuple[str, str, str, float, str]] = []
    t_l = stop_time(t, v[:, 0])
    i_l = int(np.searchsorted(t, t_l)) if math.isfinite(t_l) else len(t) - 1
    onset_v = exp.measurements.stop.onset_speed_mps
    before = t < (t_l if math.isfinite(t_l) else np.inf)
    stopped = math.isfinite(t_l)  # a leader still running at the end (its brake event never came): no stop to measure
    if leader_brake_s is not None:
        i_b = int(np.searchsorted(t, leader_brake_s - 1e-9))
    elif not stopped:
        i_b = None
    elif onset_v is not None:
        run = np.flatnonzero((v[:, 0] >= onset_v - 0.05) & before)
        i_b = int(run[-1]) if len(run) else i_l
    else:
        acc = np.diff(v[:, 0], prepend=v[0, 0]) / exp.step_s
        run = np.flatnonzero((acc >= -0.05) & before & (v[:, 0] > 0.01))
        i_b = int(run[-1]) if len(run) else i_l
    i_b = None if i_b is None else min(i_b, len(t) - 1)
    at_onset = (lambda x: float(x[i_b])) if i_b is not None else (lambda x: math.nan)
    at_stop = (lambda x: float(x[min(i_l, len(t) - 1)])) if stopped else (lambda x: math.nan)
    rows.append((ids[0], "stop", "leader_brake_onset_s", at_onset(t), "s"))
    rows.append((ids[0], "stop", "leader_stop_time_s", t_l, "s"))
    rows.append((ids[0], "stop", "leader_stop_position_m", at_stop(arr["pos"][:, 0]), "m"))
    for j in range(arr["gap_fr"].shape[1]):
        i = j + 1
        fr, ff = arr["gap_fr"][:, j], arr["gap_ff"][:, j]
        t_f = stop_time(t, v[:, i])
        i_f = int(np.searchsorted(t, t_f)) if math.isfinite(t_f) else len(t) - 1
        i_both = min(max(i_l, i_f), len(t) - 1)
        at_rest = (lambda x: float(x[i_both])) if stopped and math.isfinite(t_f) else (lambda x: math.nan)
        rows += [
            (ids[i], "stop", "gap_at_brake_onset_m", at_onset(fr), "m"),
            (ids[i], "stop", "gap_at_brake_onset_front_to_front_m", at_onset(ff), "m"),
            (ids[i], "stop", "max_gap_before_brake_onset_m", float(fr[: i_b + 1].max()) if i_b is not None else math.nan, "m"),
            (ids[i], "stop", "gap_at_leader_stop_m", at_stop(fr), "m"),
            (ids[i], "stop", "gap_at_rest_m", at_rest(fr), "m"),
            (ids[i], "stop", "gap_at_rest_front_to_front_m", at_rest(ff), "m"),
            (ids[i], "stop", "stop_time_s", t_f, "s"),
            (ids[i], "stop", "stop_delay_s", t_f - t_l, "s"),
        ]
        if onset_v is not None:
            cruise = (v[:, 0] > onset_v - 0.05) & before
            rows.append((ids[i], "stop", "cruise_gap_median_m", float(np.median(fr[cruise])) if cruise.any() else math.nan, "m"))
    return rows


__all__ = ["TRAJECTORY_COLUMNS", "Timed", "Recorder", "stop_time", "onsets", "episodes", "window_mask", "measure", "stop_rows"]
