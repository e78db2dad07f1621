"""Tier 1 — blocking-time theory on hand-computable running profiles (no SUMO)."""

import numpy as np
import pandas as pd
import pytest

from vcsumo.signalling.blocking_time import (
    BrakingRule,
    fbs_blocking_times,
    fbs_headway_at,
    mb_headway_at,
    mb_headway_profile,
    uniform_fbs_headway,
    uniform_mb_headway,
    vc_headway,
)


def constant_speed_run(v: float, length_m: float, dt: float = 0.5) -> pd.DataFrame:
    t = np.arange(0.0, length_m / v + dt, dt)
    return pd.DataFrame({"time_s": t, "s_m": v * t, "speed_mps": np.full_like(t, v), "accel_mps2": 0.0})


def test_fbs_uniform_section_is_braking_distance_plus_block_plus_length_over_speed():
    v, block, L = 83.33, 1350.0, 202.0
    rule = BrakingRule(0.65, 0.25)
    run = constant_speed_run(v, 60000)
    signals = [10000 + k * block for k in range(20)]
    blocks = fbs_blocking_times(run, signals, 60000, L, rule)
    inner = blocks.iloc[5:15]
    expected = (v * v / 1.3 + 0.25 * v + block + L) / v
    assert np.allclose(inner.blocking_time_s, expected, rtol=1e-3)
    assert uniform_fbs_headway(v, block, L, rule) == pytest.approx(expected)
    h, crit = fbs_headway_at(blocks, 30000)
    assert h == pytest.approx(expected, rel=1e-3)


def test_mb_uniform_section():
    v, L = 83.33, 202.0
    rule = BrakingRule(0.65, 0.25)
    run = constant_speed_run(v, 40000)
    prof = mb_headway_profile(run, L, rule, margin_m=50.0)
    expected = (v * v / 1.3 + 0.25 * v + 50 + L) / v
    h, _ = mb_headway_at(prof, 20000)
    assert h == pytest.approx(expected, rel=1e-3)
    assert uniform_mb_headway(v, L, rule) == pytest.approx(expected)


def test_ordering_fbs_mb_vc_at_300_kmh():
    rule = BrakingRule(0.65, 0.0)
    v, L = 83.33, 202.0
    fbs = uniform_fbs_headway(v, 1350, L, rule)
    mb = uniform_mb_headway(v, L, rule)
    vc = vc_headway(v, 50.0, L)
    # DATASHEET §5 / notes: MB ~ 67 s + margins, VC ~ 3 s at a 50 m gap
    assert vc < 5.0 < mb < fbs
    assert fbs - mb == pytest.approx((1350 - 50) / v)


def test_headway_at_point_takes_the_largest_block_approached_before_it():
    # two speeds: 40 m/s then 80 m/s after 20 km -> the faster section has the larger blocking time
    v1, v2, L = 40.0, 80.0, 200.0
    t1 = 20000 / v1
    t = np.arange(0, t1 + 40000 / v2, 0.5)
    s = np.where(t <= t1, v1 * t, 20000 + v2 * (t - t1))
    v = np.where(t <= t1, v1, v2)
    run = pd.DataFrame({"time_s": t, "s_m": s, "speed_mps": v, "accel_mps2": 0.0})
    rule = BrakingRule(0.65, 0.0)
    blocks = fbs_blocking_times(run, [k * 1000.0 for k in range(1, 60)], 60000, L, rule)
    h_early, _ = fbs_headway_at(blocks, 8000)
    h_late, _ = fbs_headway_at(blocks, 50000)
    assert h_early == pytest.approx(uniform_fbs_headway(v1, 1000, L, rule), rel=0.02)
    assert h_late == pytest.approx(uniform_fbs_headway(v2, 1000, L, rule), rel=0.02)


def test_mb_headway_is_continuous_in_the_margin_a_50_m_margin_is_not_sumos():
    # a set with a 30 m margin and 10 m position errors has a 50 m margin at every speed: before, exactly 50 m
    # was taken for SUMO's own margin and dropped to 5 m below 30 km/h (3.4 s off at a departure)
    t = np.arange(0.0, 200.0, 0.5)
    v = np.minimum(0.5 * t, 40.0)
    run = pd.DataFrame({"time_s": t, "s_m": np.cumsum(v) * 0.5, "speed_mps": v})
    rule = BrakingRule(0.6, 2.0)
    h = [mb_headway_profile(run, 150.0, rule, m).headway_s.iloc[0] for m in (49.999, 50.0, 50.001)]
    assert h[1] == pytest.approx(h[0], abs=0.01) and h[1] == pytest.approx(h[2], abs=0.01)
    # SUMO's own margin (None): 5 m below 30 km/h
    assert mb_headway_profile(run, 150.0, rule).headway_s.iloc[0] < h[1] - 1.0
