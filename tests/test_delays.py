"""Primary delays: strict configuration, seeded draws, injection into planned trains (no SUMO)."""

from types import SimpleNamespace

import numpy as np
import pytest

from vcsumo.delays import NO_DELAYS, DelayConfig, DelaySpec, apply_delays, config_digest, draw_delays, inject_delays, load_delay_config
from vcsumo.errors import InputError
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write


def fake_trains(n: int, stops: int = 0) -> list:
    """Objects with what draw_delays reads (id, stops)."""
    return [SimpleNamespace(id=f"T{k}", stops=[None] * stops) for k in range(n)]


def test_defaults():
    cfg = DelayConfig()
    assert (cfg.origin.probability, cfg.origin.distribution, cfg.origin.mean_s) == (0.3, "exponential", 120.0)
    assert (cfg.dwell.probability, cfg.dwell.distribution, cfg.dwell.mean_s) == (0.1, "exponential", 30.0)
    assert load_delay_config(None) == cfg


@pytest.mark.parametrize(
    "text,field,words",
    [
        ("origin: {probability: 0.5, mean_s: 60, colour: red}", "origin.colour", "unknown key"),
        ("dwel: {probability: 0.5}", "dwel", "unknown key"),
        ("origin: {probability: 1.5, mean_s: 60}", "origin.probability", "less than or equal to 1"),
        ("origin: {probability: 0.5, distribution: exponential}", "origin", "needs mean_s"),
        ("origin: {probability: 0.5, distribution: uniform, min_s: 60, max_s: 10}", "origin", "below min_s"),
        ("origin: {probability: 0.5, distribution: uniform, mean_s: 60}", "origin", "mean_s does not apply"),
        ("origin: {probability: 0.5, distribution: empirical, samples_s: []}", "origin", "non-empty"),
        ("origin: {probability: 0.5, distribution: empirical, samples_s: [10, -5]}", "origin", ">= 0"),
        ("origin: {probability: 0.5, distribution: gamma, mean_s: 60}", "origin.distribution", "exponential"),
        ("dwell: {probability: 0.2, mean_s: -3}", "dwell.mean_s", "greater than 0"),
    ],
)
def test_bad_config_names_file_and_field(tmp_path, text, field, words):
    path = write(tmp_path / "d.yaml", text + "\n")
    with pytest.raises(InputError) as exc:
        load_delay_config(path)
    msg = str(exc.value)
    assert str(path) in msg and field in msg and words in msg, msg


def test_config_file_and_digest(tmp_path):
    path = write(tmp_path / "d.yaml", "description: heavy\norigin: {probability: 0.5, distribution: uniform, min_s: 0, max_s: 300}\n")
    cfg = load_delay_config(path)
    assert cfg.origin.distribution == "uniform" and cfg.dwell == DelayConfig().dwell  # unspecified part keeps its default
    assert config_digest(cfg) == config_digest(cfg.model_copy(update={"description": "renamed"}))
    assert config_digest(cfg) != config_digest(DelayConfig())
    assert config_digest(load_delay_config(write(tmp_path / "e.yaml", "{}\n"))) == config_digest(DelayConfig())


def test_draws_are_seeded_per_timetable_seed_and_train():
    trains = fake_trains(50, stops=3)
    cfg = DelayConfig()
    a = draw_delays(trains, cfg, 7, "abc")
    assert a == draw_delays(trains, cfg, 7, "abc")
    assert a != draw_delays(trains, cfg, 8, "abc")
    assert a != draw_delays(trains, cfg, 7, "abd")
    # a train's delays do not depend on the other trains or their order
    sub = draw_delays(list(reversed(trains[10:20])), cfg, 7, "abc")
    assert all(sub[k] == a[k] for k in sub)


def test_exponential_delays_have_the_configured_share_and_mean():
    trains = fake_trains(20000, stops=1)
    d = draw_delays(trains, DelayConfig(), 1, "x")
    origin = np.array([x.origin_s for x in d.values()])
    dwell = np.array([x.dwell_s[0] for x in d.values()])
    assert (origin > 0).mean() == pytest.approx(0.3, abs=0.015)
    assert origin[origin > 0].mean() == pytest.approx(120.0, rel=0.05)
    assert (dwell > 0).mean() == pytest.approx(0.1, abs=0.01)
    assert dwell[dwell > 0].mean() == pytest.approx(30.0, rel=0.08)


def test_uniform_empirical_none_and_cap():
    trains = fake_trains(2000)
    u = DelayConfig(origin=DelaySpec(probability=1.0, distribution="uniform", min_s=20, max_s=40), dwell=DelaySpec(distribution="none"))
    vals = np.array([x.origin_s for x in draw_delays(trains, u, 3, "x").values()])
    assert vals.min() >= 20 and vals.max() <= 40 and vals.mean() == pytest.approx(30, abs=1)
    e = DelayConfig(origin=DelaySpec(probability=1.0, distribution="empirical", samples_s=[5, 60, 600]))
    vals = {x.origin_s for x in draw_delays(trains, e, 3, "x").values()}
    assert vals == {5.0, 60.0, 600.0}
    assert all(x.total_s == 0 for x in draw_delays(trains, NO_DELAYS, 3, "x").values())
    cap = DelayConfig(origin=DelaySpec(probability=1.0, mean_s=600, cap_s=90))
    assert max(x.origin_s for x in draw_delays(trains, cap, 3, "x").values()) == 90.0


def test_larger_mean_or_probability_never_gives_a_train_less_delay():
    trains = fake_trains(500, stops=2)
    small = draw_delays(trains, DelayConfig(origin=DelaySpec(probability=0.2, mean_s=60)), 5, "x")
    big = draw_delays(trains, DelayConfig(origin=DelaySpec(probability=0.5, mean_s=240)), 5, "x")
    assert all(big[k].origin_s >= small[k].origin_s for k in small)
    assert sum(x.origin_s for x in big.values()) > 2 * sum(x.origin_s for x in small.values())
    assert {k for k in small if small[k].origin_s > 0} < {k for k in big if big[k].origin_s > 0}


def test_injection_shifts_departures_and_extends_dwells_only(line_factory):
    from vcsumo.topology import build_topology

    line = line_factory("hcmc_line1")
    tt, p = load_timetable("peak", line)
    planned = plan_trains(tt, p, line, build_topology(line))
    cfg = DelayConfig(origin=DelaySpec(probability=0.5, mean_s=120), dwell=DelaySpec(probability=0.5, mean_s=30))
    delayed, d = inject_delays(planned, cfg, 11, "digest")
    assert sum(x.origin_s > 0 for x in d.values()) > 0 and sum(sum(x.dwell_s) > 0 for x in d.values()) > 0
    for t0, t1 in zip(planned, delayed):
        dd = d[t0.id]
        assert len(dd.dwell_s) == len(t0.stops) == 12
        assert t1.depart_s == pytest.approx(t0.depart_s + dd.origin_s)
        assert [s.dwell_s for s in t1.stops] == pytest.approx([s.dwell_s + e for s, e in zip(t0.stops, dd.dwell_s)])
        assert t1.scheduled_arrival_s == t0.scheduled_arrival_s
        assert [(s.arrival_s, s.departure_s) for s in t1.stops] == [(s.arrival_s, s.departure_s) for s in t0.stops]
    assert all(s.dwell_s == 30.0 for t in planned for s in t.stops)  # the planned trains are not modified
    assert apply_delays(planned, draw_delays(planned, NO_DELAYS, 11, "digest")) == planned
