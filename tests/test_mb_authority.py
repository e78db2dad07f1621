"""Moving block: every follower's movement authority ends behind the train ahead's rear as of that
train's last position report — the same step's readings for every pair, whatever the order the loop
takes the trains in.

Found while making the loop faster: each train's odometer was recorded as the loop reached it, so a
follower taken before its leader built its authority from the leader's reading one step old: up to
one step of the leader's run (≈ 42 m at 300 km/h and 0.5 s steps) beyond the reported rear, for
about half the pairs.  Now all readings of a step are taken before any authority is built
(:meth:`BrakingCurveSupervisor.observe_all`)."""

from __future__ import annotations

import math

import pytest

from vcsumo.sim import sumo_backend, supervision
from vcsumo.timetable import load_timetable, plan_trains

pytestmark = pytest.mark.sumo


@pytest.mark.parametrize("fixed_time_s", [0.0, 3.0])
def test_every_mb_authority_is_built_from_the_leaders_reported_position(tmp_path, monkeypatch, line_factory, network_factory, fixed_time_s):
    from vcsumo.sim.loop import Scenario, simulate

    readings: dict[float, dict[str, float]] = {}  # time -> train -> odometer, as SUMO gave them
    clock = {}
    observe_all, step = sumo_backend.SumoBackend.observe_all, sumo_backend.SumoBackend.step

    def stepped(self):
        clock["t"] = step(self)
        return clock["t"]

    def observed(self, ids):
        out = observe_all(self, ids)
        readings[clock["t"]] = {vid: o[4] for vid, o in zip(ids, out)}
        return out

    checked = []
    authority = supervision.BrakingCurveSupervisor.authority_distance

    def checked_authority(self, train_id, s_m, gap_m, leader_id, now_s, fouling=False):
        d = authority(self, train_id, s_m, gap_m, leader_id, now_s, fouling)
        assert not fouling  # (no junction on felez_test: a gap to a fouling point is tested in test_unseen6_junction_fouling)
        if leader_id is None or math.isinf(gap_m):
            return d
        t_ref = self.information_time(leader_id, now_s)
        first = self.curves[leader_id].first_seen_s
        then = readings.get(max(t_ref, first))  # (reports fall on steps here: 0.5 s steps, 2 s reports, fixed time 0 or 3 s)
        assert then is not None and leader_id in then, (now_s, t_ref, leader_id)
        moved = readings[now_s][leader_id] - then[leader_id]
        a = self.model.assumptions
        expected = gap_m - moved - a.safety_margin_m - self.model.assumptions.position_uncertainty_m
        assert d == pytest.approx(expected, abs=1e-6), (train_id, leader_id, now_s, d, expected)
        checked.append(moved)
        return d

    monkeypatch.setattr(sumo_backend.SumoBackend, "step", stepped)
    monkeypatch.setattr(sumo_backend.SumoBackend, "observe_all", observed)
    monkeypatch.setattr(supervision.BrakingCurveSupervisor, "authority_distance", checked_authority)
    line = line_factory("felez_test")
    tt, path = load_timetable("dense", line)
    trains = plan_trains(tt, path, line, network_factory("felez_test").topology)
    simulate(Scenario(line, network_factory("felez_test"), trains, "mb", step_length_s=0.5, full_outputs=False, fixed_time_s=fixed_time_s), tmp_path / "out")
    assert len(checked) > 300 and max(checked) > 20.0, (len(checked), max(checked))  # followers close behind moving leaders were checked
