"""The loop's cheaper paths give the answers of the full ones (issue 14: linear cost, bounded memory).

No timing here (speed is measured in bench/): every shortcut is checked against the computation it
replaces — the running-train list against SUMO's own, the train ahead from the route index against
a driving distance to every other train, the braking bound against the integrated stopping
distance, the health monitor's skipped steps against evaluating every step, the streamed CSV against
pandas, the receiver-indexed channel against its deliveries.
"""

from __future__ import annotations

import json
import math
import random

import numpy as np
import pandas as pd
import pytest

from vcsumo.control.base import Message, TrainStateMsg
from vcsumo.control.channel import Channel, ChannelConfig
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import RelativeBraking, RouteBraking, SeparationModel
from vcsumo.sim.health import GAP_TOLERANCE_M, HealthMonitor
from vcsumo.sim.records import CsvStream, RunningStats
from vcsumo.timetable import load_timetable, plan_trains


def _trains(line_factory, network_factory, line: str, timetable: str, dt: float = 0.5):
    ln = line_factory(line)
    net = network_factory(line)
    tt, p = load_timetable(timetable, ln)
    return ln, net, plan_trains(tt, p, ln, net.topology, dt=dt)


# ------------------------------------------------------------------------------------------ records
def test_streamed_csv_is_the_frame_pandas_writes(tmp_path):
    cols = ["time_s", "train", "gap_m", "leader", "flag", "x"]
    rows = []
    rnd = random.Random(4)
    for k in range(2503):
        gap = rnd.choice([None, math.nan, 0, 3, rnd.uniform(-1e6, 1e6), 1e-7 * rnd.random(), 1e17 * rnd.random(), np.float64(rnd.random())])
        rows.append((0.5 * k, rnd.choice(["T1", 'a,"b"', "c\nd", "é"]), gap, rnd.choice([None, "L", "M,N"]), rnd.random() < 0.5, rnd.randint(-5, 5)))
    s = CsvStream(tmp_path / "s.csv", cols, ["time_s", "gap_m"], chunk_rows=97)
    for r in rows:
        s.append(r)
        assert len(s.rows) < 97  # at most one chunk in memory
    s.close()
    df = pd.DataFrame(rows, columns=cols)
    df["gap_m"] = df["gap_m"].astype("float64")
    assert (tmp_path / "s.csv").read_bytes() == df.to_csv(index=False).encode()
    empty = CsvStream(tmp_path / "e.csv", cols)
    empty.close()
    assert (tmp_path / "e.csv").read_text() == ",".join(cols) + "\n"


def test_running_statistics_match_the_samples():
    rng = np.random.default_rng(1)
    x = rng.lognormal(-1.0, 1.0, 20000)
    a, b = RunningStats(), RunningStats()
    for v in x[:7000]:
        a.add(float(v))
    for v in x[7000:]:
        b.add(float(v))
    st = a.merge(b)
    assert st.count == len(x) and st.max == x.max() and st.mean == pytest.approx(x.mean(), rel=1e-12)
    for q in (0.5, 0.9, 0.99):
        assert st.quantile(q) == pytest.approx(np.quantile(x, q), rel=0.011)
    assert math.isnan(RunningStats().quantile(0.5))


# ------------------------------------------------------------------------------------------ channel
def _msg(sender: str, t: float) -> Message:
    return Message(sender=sender, sent_time_s=t, length_m=200.0, state=TrainStateMsg(t, 100.0 * t, 20.0))


def test_channel_delivers_each_receiver_its_own_links():
    ch = Channel(ChannelConfig(model="exponential", delay_s=0.2, mean_extra_s=0.5, loss_probability=0.1, seed=5,
                               outages=[{"start_s": 3.0, "end_s": 4.0}]))
    seen: dict[str, dict] = {"F1": {}, "F2": {}}
    for k in range(100):
        t = 0.1 * k
        ch.send(_msg("L", t), ["F1", "F2"], t)
        ch.send(_msg("F1", t), ["F2"], t)
        if k % 3 == 0:
            ch.advance(t)  # deliveries made for nobody in particular arrive all the same
        got = ch.deliver("F2", t)
        assert set(got) <= {"L", "F1"}
        for s, m in got.items():  # the latest message per sender, never an older one after a newer
            assert m.received_time_s <= t + 1e-9 and m.sent_time_s >= seen["F2"].get(s, -1.0)
            seen["F2"][s] = m.sent_time_s
        assert set(ch.latest("F1")) <= {"L"}
    assert ch.latest("nobody") == {}
    assert ch.sent == 300 and 0 < ch.lost < ch.sent
    got = ch.latest("F2")
    got.clear()  # a copy: the channel's record is not changed through it
    assert ch.latest("F2")


# ------------------------------------------------------------------------------------------ braking bound
@pytest.mark.parametrize("line,timetable", [("regional_graded", "all_stations"), ("felez_test", "dense")])
def test_stopping_bound_is_above_every_stopping_distance(line_factory, network_factory, line, timetable):
    _, _, trains = _trains(line_factory, network_factory, line, timetable)
    model = SeparationModel(load_assumptions())
    rnd = random.Random(2)
    for t in trains[:4]:
        for br in (RouteBraking(model, t.stock, t.profile), RouteBraking(model, t.stock, t.profile, "emergency"),
                   RelativeBraking(model, t.stock, t.stock, t.profile).follower):
            for _ in range(2000):
                s = rnd.uniform(0.0, t.profile.length_m + 50.0)  # fronts on the route (before its start the integral stops there)
                v = rnd.choice([0.0, rnd.uniform(0.0, 1.05 * t.stock.max_speed_ms)])
                dead = rnd.choice([0.0, model.dead_time_s, model.dead_time_s + 1.0])
                assert br.stopping_distance(s, v, dead) <= br.stopping_bound(v, dead)


# ------------------------------------------------------------------------------------------ health
def test_health_counters_are_those_of_evaluating_every_step(line_factory, network_factory):
    """The monitor skips the separation rule where the gap cannot set a new minimum margin or fall
    below it: over random approaches, retreats, standstills and lost leaders every counter (and
    every violation with its safe separation) equals the one of evaluating the rule at every step."""
    _, _, trains = _trains(line_factory, network_factory, "regional_graded", "all_stations")
    model = SeparationModel(load_assumptions())
    fast, full = HealthMonitor(model, trains), HealthMonitor(model, trains)
    rnd = random.Random(7)
    skipped = violations = 0
    for t in trains[:6]:
        s, v, gap = 100.0, 0.0, rnd.uniform(5.0, 3000.0)
        leader = trains[-1].id if t is not trains[-1] and rnd.random() < 0.5 else None
        for k in range(3000):
            v = min(max(0.0, v + rnd.uniform(-1.2, 0.8) * 0.5), t.stock.max_speed_ms)
            s = min(s + v * 0.5, t.profile.length_m - 1.0)
            gap = max(0.0, gap + rnd.uniform(-1.5, 1.0) * 10.0) if k % 500 else rnd.choice([math.inf, rnd.uniform(0.0, 5000.0)])
            if math.isinf(gap) and k % 500:
                gap = rnd.uniform(0.0, 5000.0)
            a, auth = rnd.uniform(-1.5, 1.0), rnd.choice([math.inf, rnd.uniform(-2.0, 5000.0)])
            got = fast.step(t.id, 0.5, s, v, a, gap, auth, True, leader, v)
            required = math.inf
            if math.isfinite(gap):
                required = full.relative_gap(t.id, s, v, leader, gap, v) if leader else full.absolute_gap(t.id, s, v)
                h = full.trains[t.id]
                skipped += gap - required >= max(h.min_margin_m, -GAP_TOLERANCE_M)
            started = full.update(t.id, 0.5, s, v, a, gap, required, auth, True)
            assert (got is not None) == started
            if started:
                violations += 1
                assert got == required
        assert fast.train_row(t.id) == full.train_row(t.id)
        assert fast.trains[t.id].min_margin_m == full.trains[t.id].min_margin_m
    assert skipped > 1000 and violations > 0  # both paths were taken


# ------------------------------------------------------------------------------------------ SUMO
@pytest.mark.sumo
@pytest.mark.parametrize("line,timetable,beyond", [("regional_graded", "all_stations", True), ("felez_test", "dense", False)])
def test_running_trains_and_the_train_ahead_are_sumos(tmp_path, line_factory, network_factory, line, timetable, beyond):
    """The running list kept from departures and arrivals is SUMO's own at every step, and the train
    ahead found from the route's edges is the one a driving distance to every other train finds."""
    from vcsumo.sim.route_leaders import RouteLeaders
    from vcsumo.sim.sumo_backend import SumoBackend, sumo_args
    from vcsumo.timetable import routes_xml

    ln, net, trains = _trains(line_factory, network_factory, line, timetable)
    plans = {t.id: t for t in trains}
    (tmp_path / "routes.rou.xml").write_text(routes_xml(trains, net.topology))
    begin = math.floor(min(t.depart_s for t in trains))
    args = sumo_args(net.net_file, tmp_path / "routes.rou.xml", [net.stations_file], tmp_path, 0.5, begin + 2400.0, moving_block=False,
                     full_outputs=False) + ["--begin", str(begin)]
    starts = {t.id: [float(x) for x in t.profile.starts_m] for t in trains}
    longest = max(t.stock.length_m for t in trains)
    compared = found = 0
    sync: dict[str, tuple[float, float]] = {}
    with SumoBackend(args, error_log=tmp_path / "err.log") as sim:
        leaders = RouteLeaders(sim, longest, 30000.0)
        while sim.time < begin + 2400.0 - 1e-9:
            sim.step()
            running = sim.running()
            assert running == sim.train_ids()
            observed = sim.observe_all(running)
            obs = dict(zip(running, observed))
            leaders.begin_step(running, observed, {t.id: t.stock.length_m for t in trains})
            on_edge: dict = {}
            for vid, o in obs.items():
                if not o[0].startswith(":"):
                    on_edge.setdefault(o[0], []).append((vid, o[1], plans[vid].stock.length_m))
                else:  # crossing a junction: a candidate on the edge it is leaving
                    e, pos, length = sim.crossing(vid, o[1], plans[vid].stock.length_m)
                    on_edge.setdefault(e, []).append((vid, pos, length))
            others = [(vid, o[0], o[1], plans[vid].stock.length_m) for vid, o in obs.items()]
            for vid, lead in zip(running, sim.leaders(running, 30000.0)):
                edge, pos, _, _, odo, ridx = obs[vid]
                prof = plans[vid].profile
                if not edge.startswith(":") and 0 <= ridx < len(prof.edges) and prof.edges[ridx] == edge:
                    sync[vid] = (starts[vid][ridx] + pos, odo)
                if vid not in sync or lead is not None or len(running) < 2:
                    continue
                s = sync[vid][0] + odo - sync[vid][1]
                got = sim.route_leader_indexed(vid, s, prof.edges, starts[vid], ridx, on_edge, longest, 30000.0)
                assert got == sim.route_leader(vid, others, 30000.0)
                assert leaders.leader(vid, s, prof.edges, starts[vid], ridx) == got  # kept from the last step or walked again
                compared += 1
                found += got is not None
    assert compared > 100 and (found > 10) == beyond  # on the graded line trains run beyond SUMO's look-ahead of each other
    assert leaders.kept_answers > compared / 2  # most answers were kept from the step before


@pytest.mark.sumo
def test_sumo_fcd_only_on_request_and_trajectories_streamed(in_tmp):
    """trajectories.csv is written during the run and read back on demand; SUMO's fcd.xml (the same
    samples) only with --sumo-fcd."""
    import xml.etree.ElementTree as ET

    from vcsumo.cli.main import main

    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", "a", "-q"]) == 0
    assert main(["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", "b", "--sumo-fcd", "-q"]) == 0
    assert not (in_tmp / "a" / "fcd.xml").exists() and (in_tmp / "b" / "fcd.xml").is_file()
    for f in ("trajectories.csv", "summary.csv", "stop_events.csv", "violations.csv"):  # the fcd output changes nothing else
        assert (in_tmp / "a" / f).read_bytes() == (in_tmp / "b" / f).read_bytes(), f
    traj = pd.read_csv(in_tmp / "a" / "trajectories.csv")
    fcd = {v.get("id") for v in ET.parse(in_tmp / "b" / "fcd.xml").getroot().iter("vehicle")}
    assert set(traj.train) == fcd == {"T.1", "T.2", "T.3"}
    summary = json.loads((in_tmp / "a" / "summary.json").read_text())
    assert set(summary["loop_cpu_s"]) >= {"sumo", "observation", "supervision", "health", "recording", "io"}
    assert summary["train_steps"] >= len(traj)  # a row per running train and second, a train-step per running train and step


def test_overspeed_is_checked_against_the_limit_under_the_whole_train(line_factory, network_factory):
    """The monitor keeps a train's permitted speed while its front and rear stay on the same edges:
    driving every route in small steps just above and just below the limit under the whole train,
    each step is counted exactly as the limit of that very position says."""
    _, net, trains = _trains(line_factory, network_factory, "regional_graded", "all_stations")
    model = SeparationModel(load_assumptions())
    health = HealthMonitor(model, trains)
    tol = health.tol_mps
    rnd = random.Random(3)
    for t in {t.service: t for t in trains}.values():
        expected, s, k = 0.0, 0.0, 0
        while s < t.profile.length_m:
            limit = min(t.profile.speed_limit_train(s, t.stock.length_m), t.stock.max_speed_ms)
            over = k % 3 == 0
            v = limit + tol + (1e-6 if over else -1e-6)
            expected += 0.5 * over
            health.update(t.id, 0.5, s, v, 0.0, math.inf, math.inf)
            s += rnd.choice([0.37, 5.0, 31.0, 0.001])
            k += 1
        assert health.trains[t.id].overspeed_time_s == pytest.approx(expected)
        assert health.trains[t.id].overspeed_events == math.ceil(k / 3)


def test_service_floor_is_below_every_service_limit(line_factory, network_factory):
    """Braking beyond service is looked up only above a floor: the hardest service brake and the
    running resistance at the lowest speed of the 1 m/s band (+1 m/s) — never above the limit the
    monitor would find at any speed of the band and any gradient."""
    from vcsumo.signalling.separation import strongest_decel

    trains = []
    for line, tt in (("regional_graded", "all_stations"), ("felez_test", "dense"), ("milano_bologna", "base")):
        trains += _trains(line_factory, network_factory, line, tt)[2][:1]
    model = SeparationModel(load_assumptions())
    health = HealthMonitor(model, trains)
    rnd = random.Random(5)
    for t in trains:
        for _ in range(3000):
            v = rnd.uniform(0.0, t.stock.max_speed_ms)
            v_band = int(v) + rnd.random()  # the limit cached for the band may come from any speed in it
            g = rnd.uniform(-0.04, 0.04)
            assert health.service_floor(t.id, v) <= strongest_decel(t.stock, model.assumptions, "service", v_band + 1.0, g)
