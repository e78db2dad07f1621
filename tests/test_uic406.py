"""UIC 406 capacity consumption: blocking-time stairs, compression, sections (no SUMO)."""

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pytest

from vcsumo.signalling.blocking_time import BrakingRule
from vcsumo.errors import VcsumoError
from vcsumo.running_time import Stop, time_at, unhindered_run
from vcsumo.timetable import load_timetable, plan_trains
from vcsumo.signalling.uic406 import (
    capacity_consumption,
    compress,
    convoy_pairs,
    line_sections,
    stairs,
)
from vcsumo.signalling.scheduled_run import reference_arrivals, timetable_run

from .conftest import write


@dataclass(frozen=True)
class GapRule:
    """A constant approach distance (a hand-computable rule for :func:`stairs`), m."""

    gap_m: float

    def distance(self, v, s=None):
        return np.zeros_like(np.asarray(v, dtype=float)) + self.gap_m


def constant_run(v: float, length_m: float, t0: float = 0.0, dt: float = 0.5) -> pd.DataFrame:
    t = np.arange(0.0, length_m / v + dt, dt)
    return pd.DataFrame({"time_s": t0 + t, "s_m": v * t, "speed_mps": np.full_like(t, v), "accel_mps2": np.zeros_like(t)})


# uniform section: 8 blocks of B = 1000 m from 2000 m to 10000 m, L = 200 m
B, L = 1000.0, 200.0
MARKERS = [2000.0 + k * B for k in range(8)]
END = 10000.0


def test_stairs_on_a_uniform_section_are_braking_distance_plus_block_plus_length_over_speed():
    v, b = 50.0, 1.0
    rule = BrakingRule(b, 0.0)
    D = v * v / (2 * b)  # 1250 m
    st = stairs(constant_run(v, 12000.0), MARKERS, END, L, rule)
    assert len(st) == 8
    assert st["blocking_time_s"].to_numpy() == pytest.approx((D + B + L) / v)  # 49 s
    assert st["t_start_s"].to_numpy() == pytest.approx((np.array(MARKERS) - D) / v)
    assert st["t_end_s"].iloc[-1] == pytest.approx((END + L) / v)


def test_two_identical_trains_compress_to_one_headway_plus_one_stair():
    v, b = 50.0, 1.0
    rule = BrakingRule(b, 0.0)
    D = v * v / (2 * b)
    H = (D + B + L) / v  # 49 s: minimum headway (one blocking time)
    span = (D + len(MARKERS) * B + L) / v  # 189 s: one train's whole stair (running time over the section + D + L)
    starts, ends = [], []
    for t0 in (0.0, 300.0):  # scheduled 5 min apart
        st = stairs(constant_run(v, 12000.0, t0), MARKERS, END, L, rule)
        starts.append(st["t_start_s"].to_numpy())
        ends.append(st["t_end_s"].to_numpy())
    comp = compress(np.array(starts), np.array(ends))
    assert comp.shifts_s[1] == pytest.approx(H - 300.0)  # pulled 251 s forward
    assert comp.occupation_s == pytest.approx(H + span)  # 238 s
    assert comp.cycle_s == pytest.approx(2 * H)  # cycle closed: two minimum headways


def test_n_identical_trains_add_one_headway_each():
    v = 40.0
    rule = BrakingRule(0.8, 0.25)
    st = stairs(constant_run(v, 12000.0), MARKERS, END, L, rule)
    H = float(st["blocking_time_s"].max())
    occ = []
    for n in (1, 2, 3, 4):
        S = np.array([st["t_start_s"].to_numpy() + 120.0 * k for k in range(n)])
        E = np.array([st["t_end_s"].to_numpy() + 120.0 * k for k in range(n)])
        c = compress(S, E)
        occ.append(c.occupation_s)
        assert c.cycle_s == pytest.approx(n * H)
    assert np.diff(occ) == pytest.approx([H, H, H])


def test_fast_behind_slow_needs_the_headway_at_the_end_slow_behind_fast_at_the_start():
    rule = GapRule(500.0)  # approach point 500 m before each signal: hand-computable
    fast = stairs(constant_run(50.0, 12000.0), MARKERS, END, L, rule)
    slow = stairs(constant_run(25.0, 12000.0), MARKERS, END, L, rule)
    # slow behind fast: worst at the first block: end_fast(1) - start_slow(1) = 3200/50 - 1500/25 = 4 s
    c = compress(np.array([fast.t_start_s, slow.t_start_s]), np.array([fast.t_end_s, slow.t_end_s]))
    assert c.shifts_s[1] == pytest.approx(3200 / 50 - 1500 / 25)
    assert c.occupation_s == pytest.approx((END + L) / 25 + 4.0 - 1500 / 50)
    # fast behind slow: worst at the last block: end_slow(8) - start_fast(8) = 10200/25 - 8500/50 = 238 s
    c = compress(np.array([slow.t_start_s, fast.t_start_s]), np.array([slow.t_end_s, fast.t_end_s]))
    assert c.shifts_s[1] == pytest.approx(10200 / 25 - 8500 / 50)


def test_a_convoy_follower_approaching_its_leader_at_the_coupled_gap_compresses_closer():
    v = 50.0
    leader = stairs(constant_run(v, 12000.0), MARKERS, END, L, BrakingRule(1.0, 0.0))
    coupled = stairs(constant_run(v, 12000.0), MARKERS, END, L, GapRule(50.0))
    S = np.array([leader.t_start_s, leader.t_start_s])
    E = np.array([leader.t_end_s, leader.t_end_s])
    absolute = compress(S, E)
    relative = compress(S, E, pair_starts={(0, 1): coupled.t_start_s.to_numpy()})
    assert relative.shifts_s[1] == pytest.approx((50.0 + B + L) / v)  # (d + block + L)/v instead of (D + block + L)/v
    assert relative.occupation_s < absolute.occupation_s


def test_compress_ignores_blocks_a_train_does_not_use():
    S = np.array([[0.0, 10.0, np.nan], [0.0, 10.0, 20.0]])
    E = np.array([[30.0, 40.0, np.nan], [30.0, 40.0, 50.0]])
    c = compress(S, E)
    assert c.shifts_s[1] == pytest.approx(30.0)
    assert c.occupation_s == pytest.approx(80.0)


@pytest.fixture(scope="module")
def bofi(network_factory, line_factory):
    return line_factory("firenze_bologna"), network_factory("firenze_bologna")


def test_sections_run_between_stations_and_junctions_per_direction(bofi):
    line, net = bofi
    secs = line_sections(line, net.topology)
    up = [s for s in secs if s.direction == "up"]
    names = [s.from_name for s in up] + [up[-1].to_name]
    assert names == ["start", "BOAV", "J:san_ruffillo", "FIRI", "FISMN", "end"]
    for d in ("up", "down"):
        ds = [s for s in secs if s.direction == d]
        assert all(a.to_km == b.from_km for a, b in zip(ds, ds[1:]))
    assert [s.from_name for s in secs if s.direction == "down"][:3] == ["end", "FISMN", "FIRI"]


def test_scheduled_profile_spreads_the_margin_and_keeps_the_stops(bofi):
    line, net = bofi
    tt, p = load_timetable("base", line)
    t = next(x for x in plan_trains(tt, p, line, net.topology) if x.id == "FR9511.1")
    run = timetable_run(t)
    firi = t.stops[0]
    assert run["time_s"].iloc[0] == t.depart_s
    assert run["time_s"].iloc[-1] == pytest.approx(t.scheduled_arrival_s, abs=0.01)  # recovery margin spent running
    assert float(time_at(run, firi.s_m)[0]) == pytest.approx(firi.arrival_s, abs=0.01)
    standing = run[(abs(run.s_m - firi.s_m) < 0.6) & (run.speed_mps == 0)]
    assert standing.time_s.max() == pytest.approx(firi.departure_s, abs=0.01)
    unhindered = unhindered_run(t.stock.params(), t.profile, s0=t.start_s_m, stops=[Stop(firi.s_m, firi.dwell_s)], end_s=t.profile.length_m - t.profile.lengths_m[-1] + t.end_pos_m)
    assert run["speed_mps"].max() < unhindered["speed_mps"].max()  # slowed, not waiting


def test_reference_arrival_without_a_schedule_is_the_unhindered_run(tmp_path, line_factory, network_factory):
    line, net = line_factory("felez_test"), network_factory("felez_test")
    path = write(tmp_path / "t.yaml", "name: t\nline: felez_test\nservices:\n  - {id: A, train: felez2019, origin: ORIG, destination: STOP, departure: 100}\n"
                 "  - {id: B, train: felez2019, origin: ORIG, destination: end, departure: 200}\n")
    tt, p = load_timetable(path, line)
    trains = plan_trains(tt, p, line, net.topology)
    ref = reference_arrivals(trains)
    for t in trains:
        end_s = float(t.profile.starts_m[-1] + t.end_pos_m)
        run = unhindered_run(t.stock.params(), t.profile, s0=t.start_s_m, end_s=end_s)
        extra = 0.0 if t.final_stop is not None else 1.0  # SUMO's 1 s stop at the end of the track
        assert ref[t.id] == pytest.approx(t.depart_s + run["time_s"].iloc[-1] + extra)


def _felez_tt(tmp_path, n: int, line, net, every: float = 60.0):
    path = write(tmp_path / f"n{n}.yaml", f"name: n{n}\nline: felez_test\nservices:\n  - {{id: T, train: felez2019, origin: ORIG, destination: STOP, "
                 f"departure: 0, arrival: 210, repeat: {{count: {n}, every_s: {every}}}}}\n")
    tt, p = load_timetable(path, line)
    return tt, plan_trains(tt, p, line, net.topology)


def test_consumption_on_a_real_line_grows_by_one_headway_per_train(tmp_path, line_factory, network_factory):
    line, net = line_factory("felez_test"), network_factory("felez_test")
    occ, cyc = [], []
    for n in (1, 2, 3):
        _, trains = _felez_tt(tmp_path, n, line, net)
        df = capacity_consumption(line, net.topology, trains, "fbs")
        assert list(df.direction) == ["up"] and df.trains.iloc[0] == n
        occ.append(df.occupation_s.iloc[0])
        cyc.append(df.cycle_s.iloc[0])
    h = cyc[0]  # one train: the cycle is its largest blocking time
    # (occupations and cycles are reported to 0.01 s)
    assert occ[1] - occ[0] == pytest.approx(h, abs=0.011) and occ[2] - occ[1] == pytest.approx(h, abs=0.011)
    assert cyc == pytest.approx([h, 2 * h, 3 * h], abs=0.016)  # cycles reported to 0.01 s: 3h carries 3 roundings
    # the scheduled spacing does not matter once compressed
    _, trains = _felez_tt(tmp_path, 3, line, net, every=300.0)
    assert capacity_consumption(line, net.topology, trains, "fbs").occupation_s.iloc[0] == pytest.approx(occ[2])
    # window: consumption = occupation / window
    df = capacity_consumption(line, net.topology, trains, "fbs", window_s=1800.0)
    assert df.consumption_pct.iloc[0] == pytest.approx(100 * occ[2] / 1800.0, abs=0.0051)  # reported to 0.01 %


def test_moving_block_and_virtual_coupling_consume_less(line_factory, network_factory):
    line, net = line_factory("felez_test"), network_factory("felez_test")
    tt, p = load_timetable("convoy", line)
    trains = plan_trains(tt, p, line, net.topology)
    pairs = convoy_pairs(tt, trains)
    assert ("UL.1", "UF.1") in pairs and len(pairs) == 6
    cache: dict = {}
    res = {r: capacity_consumption(line, net.topology, trains, r, pairs, cache=cache) for r in ("fbs", "mb", "vc")}
    for col in ("occupation_s", "cycle_s"):
        for d in ("up", "down"):
            f, m, v = (float(res[r].loc[res[r].direction == d, col].iloc[0]) for r in ("fbs", "mb", "vc"))
            assert f > m > v, (col, d, f, m, v)
    # without convoys, vc is moving block
    assert capacity_consumption(line, net.topology, trains, "vc", None, cache=cache).cycle_s.tolist() == res["mb"].cycle_s.tolist()


def test_shipped_dense_timetables_are_at_capacity_under_fbs_and_within_it_under_mb(line_factory, network_factory):
    # on the separation model's rules (guaranteed braking, dead time, overlap, position errors): the densified
    # peaks use the whole hour under fixed block (firenze_bologna 102 %, hcmc_line1 104 % cyclic on their busiest
    # section) and fit under moving block (81 %, 77 %); their peak timetables use less
    for name in ("firenze_bologna", "hcmc_line1"):
        line, net = line_factory(name), network_factory(name)
        cyc = {}
        for tt_name in ("peak", "dense"):
            tt, p = load_timetable(tt_name, line)
            trains = plan_trains(tt, p, line, net.topology)
            for regime in ("fbs", "mb"):
                cyc[tt_name, regime] = capacity_consumption(line, net.topology, trains, regime).cyclic_consumption_pct.max()
        assert cyc["dense", "fbs"] > 95.0 and cyc["dense", "mb"] < 100.0, (name, cyc)
        assert cyc["peak", "fbs"] < cyc["dense", "fbs"] and cyc["peak", "mb"] < cyc["dense", "mb"], (name, cyc)
        assert cyc["dense", "mb"] < cyc["dense", "fbs"] and cyc["peak", "mb"] < cyc["peak", "fbs"], (name, cyc)


def test_bad_regime_or_window(line_factory, network_factory, tmp_path):
    line, net = line_factory("felez_test"), network_factory("felez_test")
    _, trains = _felez_tt(tmp_path, 1, line, net)
    with pytest.raises(VcsumoError, match="unknown regime"):
        capacity_consumption(line, net.topology, trains, "etcs3")
    with pytest.raises(VcsumoError, match="window"):
        capacity_consumption(line, net.topology, trains, "fbs", window_s=0.0)
    assert not math.isnan(capacity_consumption(line, net.topology, trains, "mb").consumption_pct.iloc[0])
