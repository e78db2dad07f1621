"""Consensus-based control (survey eq. 4.1–4.5, 4.10–4.11) in closed loop with the offline convoy simulator.

Every claim is checked twice where possible: by the linear analysis of the closed loop
(eq. 4.2 with the delays of eq. 4.3) and by simulating the nonlinear plant (eq. 1 of the train
model with force lag, jerk limit and the speed-dependent traction/brake envelope).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from vcsumo.control.base import Message, Observation, TrainStateMsg
from vcsumo.control.channel import ChannelConfig
from vcsumo.control.consensus import (
    CbcParams,
    ConsensusController,
    acceleration_envelope,
    cbc_params_for,
    force_for_acceleration,
    load_cbc_params,
)
from vcsumo.control.consensus_stability import (
    closed_loop_poles,
    closed_loop_stable,
    delay_margin_s,
    leader_response,
    string_gain,
    string_gain_peak,
    string_gain_response,
    string_stability_delay_bound_s,
)
from vcsumo.sim.offline import SpeedProfile, flat_profile, gap_errors, simulate_convoy
from vcsumo.control.gap_reference import JerkLimitedTransition, SteadyGap
from vcsumo.control.topology_graph import TOPOLOGIES
from vcsumo.dynamics import acceleration, brake_force_limit, traction_limit
from vcsumo.errors import InputError
from vcsumo.rolling_stock import load_rolling_stock

ETR = load_rolling_stock("etr1000").params()
LAG_S = ETR.traction_lag_s  # 0.5 s: τ of the third-order model eq. 2.7
V0 = 40.0
BASE = load_cbc_params("cbc")  # d_min 50 m, h 1.5 s → eq. 3.1 steady gap 50 + 1.5·40 = 110 m
STEADY_GAP_M = BASE.gap.d_min_m + BASE.gap.headway_s * V0
INITIAL_GAPS_M = [STEADY_GAP_M + 40.0, STEADY_GAP_M - 10.0, STEADY_GAP_M + 90.0]
DT = 0.2


def run(prm: CbcParams, *, channel: ChannelConfig | None = None, gaps=INITIAL_GAPS_M, duration_s: float = 200.0, stocks=("etr1000",) * 4, leader=None, schedule=None, **kw) -> pd.DataFrame:
    leader = leader or SpeedProfile((0.0, 1e4), (V0, V0))
    df = simulate_convoy(list(stocks), lambda tid: ConsensusController(prm, schedule), leader, duration_s, DT, channel, list(gaps), **kw)
    return gap_errors(df)


def followers(df: pd.DataFrame, t0: float = -math.inf) -> pd.DataFrame:
    return df[(df.train != "T0") & (df.time_s >= t0)]


def max_abs_error(df: pd.DataFrame, t0: float, t1: float = math.inf) -> float:
    f = followers(df)
    return float(f[(f.time_s >= t0) & (f.time_s <= t1)].gap_error_m.abs().max())


# ---------------------------------------------------------------------------------------------
# Convergence to the eq. 3.1 reference, every topology, with and without T2T delay


@pytest.mark.parametrize("delay_s", [0.0, 1.0])
@pytest.mark.parametrize("topology", TOPOLOGIES)
def test_every_topology_converges_to_the_steady_reference(topology, delay_s):
    prm = cbc_params_for(topology, BASE)
    # theory: the delay-free loop decays like e^{-0.045..0.051 t}; the constant delay is below the margin
    rate = -closed_loop_poles(prm, 4, LAG_S).real.max()
    assert 0.04 < rate < 0.06
    assert delay_margin_s(prm, 4, LAG_S, max_delay_s=2.0) > delay_s
    channel = ChannelConfig(model="constant", delay_s=delay_s, period_s=DT) if delay_s else None
    df = run(prm, channel=channel)
    f = followers(df)
    late = followers(df, 180.0)
    assert late.gap_error_m.abs().max() < 0.1
    np.testing.assert_allclose(late.gap_ref_m, STEADY_GAP_M, atol=0.01)  # eq. 3.1 + h·v at 40 m/s
    np.testing.assert_allclose(late.gap_m, STEADY_GAP_M, atol=0.1)
    np.testing.assert_allclose(late.speed_mps, V0, atol=0.01)
    # settling time agrees with the slowest closed-loop pole: 90 m → 0.1 m in ln(900)/rate ≈ 136-145 s
    settle = f[f.gap_error_m.abs() > 0.1].time_s.max()
    predicted = math.log(90.0 / 0.1) / rate
    assert 0.8 * predicted < settle < 1.2 * predicted
    assert followers(df).gap_m.min() > BASE.gap.d_min_m  # never closer than D_safe on the way
    assert set(followers(df, 2.2)["mode"]) == {"cbc"}


@pytest.mark.parametrize(
    "stocks,speed_mps,topology",
    [
        (("terlizzi2024_leader", "terlizzi2024_follower", "etr1000", "terlizzi2024_follower"), 60.0, "PLF"),
        (("hcmc_l1",) * 4, 20.0, "PF"),
        (("felez2019",) * 4, 20.0, "TPF"),
    ],
)
def test_heterogeneous_and_metro_convoys_converge(stocks, speed_mps, topology):
    prm = cbc_params_for(topology, BASE)
    ref = BASE.gap.d_min_m + BASE.gap.headway_s * speed_mps
    df = run(prm, stocks=stocks, gaps=[ref + 30, ref - 10, ref + 60], leader=SpeedProfile((0, 1e4), (speed_mps, speed_mps)))
    late = followers(df, 180.0)
    assert late.gap_error_m.abs().max() < 0.5
    np.testing.assert_allclose(late.gap_m, ref, atol=0.5)


def test_leader_speed_changes_on_a_gradient():
    """Uphill 10 ‰: the force conversion u = M·ρ·a + R + M·g·i compensates; the CTH reference follows v."""
    prm = cbc_params_for("PLF", BASE)
    leader = SpeedProfile((0, 30, 80, 150, 190, 1e4), (V0, V0, 30.0, 30.0, 45.0, 45.0))
    df = run(prm, leader=leader, duration_s=380.0, gaps=[STEADY_GAP_M] * 3, profile=flat_profile(40000.0, gradient=0.01))
    late = followers(df, 360.0)
    assert late.gap_error_m.abs().max() < 0.5
    np.testing.assert_allclose(late.gap_m, 50.0 + 1.5 * 45.0, atol=0.5)
    assert max_abs_error(df, 0.0) < 10.0  # tracking during the manoeuvres


# ---------------------------------------------------------------------------------------------
# Delay: the bound and its demonstration


@pytest.mark.parametrize("topology", ["PF", "PLF", "TPF"])
def test_acyclic_topologies_are_stable_for_any_constant_delay(topology):
    """Q⁻¹P is nilpotent for backward-only information flow: det(I − e^{−sθ}Q⁻¹P) ≡ 1, no delay bound."""
    stiff = cbc_params_for(topology, BASE, k_pos_per_s2=0.2, k_vel_per_s=0.3, delay_compensation="sender")
    assert delay_margin_s(stiff, 5, LAG_S, max_delay_s=8.0) == math.inf


def test_bidirectional_delay_margin_predicts_simulated_stability():
    """BD with sender-speed compensation has a finite delay margin θ*; the simulation is stable below and unstable above it.

    Linearised loop per follower i: q_i(s)X_i = e^{−sθ}Σ_j p_ij(s)X_j with q = τs³ + (1+k_a)s² + k_v s + k_x and
    p = w_ij(k_a s² + (k_v + k_x θ)s + k_x) + c_ff w̄_ij s².  The margin is the smallest θ at which
    det(I − e^{−jωθ}Q⁻¹P(jω)) encircles the origin (generalised Nyquist).
    """
    prm = cbc_params_for(
        "BD", BASE, k_pos_per_s2=0.1, k_vel_per_s=0.3, delay_compensation="sender", gap={"d_min_m": 50.0, "headway_s": 0.0}, max_message_age_s=60.0
    )
    theta = delay_margin_s(prm, 4, LAG_S)
    assert 3.0 < theta < 5.0  # ≈ 3.99 s
    assert closed_loop_stable(prm, 4, LAG_S, 0.95 * theta) and not closed_loop_stable(prm, 4, LAG_S, 1.05 * theta)
    gaps = [55.0, 45.0, 55.0]
    below = run(prm, gaps=gaps, duration_s=450.0, channel=ChannelConfig(model="constant", delay_s=round(0.6 * theta / DT) * DT, period_s=DT))
    above = run(prm, gaps=gaps, duration_s=450.0, channel=ChannelConfig(model="constant", delay_s=round(1.3 * theta / DT) * DT, period_s=DT))
    # below: the 5 m initial errors die out
    assert max_abs_error(below, 400.0) < 0.1
    assert max_abs_error(below, 400.0) < max_abs_error(below, 100.0, 200.0)
    # above: the errors do not die out — the linearly unstable pair grows until the traction/jerk
    # limits of the plant bound it, leaving a sustained oscillation (a limit cycle of ~14 m here)
    assert max_abs_error(above, 400.0) > 2.0 * 5.0
    assert max_abs_error(above, 400.0) > 100.0 * max_abs_error(below, 400.0)
    assert max_abs_error(above, 400.0) > max_abs_error(above, 0.0, 50.0)


def test_string_stability_delay_bound_with_sender_compensation():
    """Extrapolating a delayed position with the sender's speed adds k_x·θ·s to p(s): sup|G| ≤ 1 only below ≈ 0.91 s."""
    sender = BASE.model_copy(update={"delay_compensation": "sender"})
    bound = string_stability_delay_bound_s(sender, LAG_S)
    assert 0.5 < bound < 1.5
    assert string_gain(sender, LAG_S, 0.5 * bound) <= 1.0 + 1e-6 < string_gain(sender, LAG_S, 2.0 * bound)
    # without extrapolation |G| does not depend on θ at all (but the gap is short by v·θ in steady state)
    none = BASE.model_copy(update={"delay_compensation": "none"})
    assert string_stability_delay_bound_s(none, LAG_S) == math.inf
    with pytest.raises(ValueError, match="cascade"):
        string_stability_delay_bound_s(BASE, LAG_S)


@pytest.mark.parametrize("delay_s", [0.5, 1.0])
def test_eq43_reference_compensation_keeps_errors_below_the_first_followers(delay_s):
    """With the eq. 4.3 τ·v_0 term every follower also hears the leader; on an 8-train PF string the worst-case
    gap error per unit leader speed, sup_ω|E_i/V_0|, stays below the first follower's, as with the
    sender-speed extrapolation (the string is not a pure cascade, so |G| alone does not decide)."""
    w = np.logspace(-4, 1.5, 3000)
    ref = np.abs(leader_response(BASE, 8, LAG_S, w, delay_s)[1] / (1j * w)).max(axis=1)
    snd = np.abs(leader_response(BASE.model_copy(update={"delay_compensation": "sender"}), 8, LAG_S, w, delay_s)[1] / (1j * w)).max(axis=1)
    assert np.all(ref[1:] < ref[0])
    assert np.all(snd[1:] < snd[0])


def test_lossy_periodic_channel_still_converges():
    """Terlizzi-like channel: 1 s sending period, 0.1 s + Exp(0.3 s) delay, 20 % loss (seeded)."""
    ch = ChannelConfig(model="exponential", period_s=1.0, delay_s=0.1, mean_extra_s=0.3, loss_probability=0.2, seed=3)
    df = run(cbc_params_for("TPF", BASE), channel=ch)
    assert max_abs_error(df, 180.0) < 0.5


def test_without_messages_the_fallback_uses_the_sensed_gap():
    df = run(BASE, channel=ChannelConfig(loss_probability=1.0, period_s=DT))
    assert set(followers(df)["mode"]) == {"cbc-fallback"}
    assert max_abs_error(df, 180.0) < 0.5


def test_stale_messages_are_ignored():
    obs = _obs(gap_m=500.0, age_s=BASE.max_message_age_s + 1.0)
    cmd = ConsensusController(BASE).make_step(obs)
    assert cmd.mode == "cbc-fallback"


# ---------------------------------------------------------------------------------------------
# Input saturation (eq. 4.4)


@pytest.mark.parametrize("link_bound", [None, 0.2])
def test_saturation_respected_at_every_step(link_bound):
    prm = cbc_params_for("PF", BASE, link_bound_mps2=link_bound)
    df = run(prm, gaps=[STEADY_GAP_M + 500.0, STEADY_GAP_M - 70.0, STEADY_GAP_M + 200.0], duration_s=300.0)
    f = followers(df)
    upper = np.array([traction_limit(ETR, v) for v in f.speed_mps])
    lower = -np.array([brake_force_limit(ETR, v) for v in f.speed_mps])
    assert np.all(f.force_cmd_n <= upper + 1e-6) and np.all(f.force_cmd_n >= lower - 1e-6)
    # (the plant's applied force lags the command by τ, so it is not checked against today's envelope)
    at_limit = (np.isclose(f.force_cmd_n, upper, rtol=1e-9) | np.isclose(f.force_cmd_n, lower, rtol=1e-9)).sum()
    if link_bound is None:
        assert at_limit > 50  # the scenario really drives the train into its envelope
    else:
        # eq. 4.4: each link term is bounded by Δ and the feed-forward c_ff·a_{i−1} too, so |u_i| ≤ Δ/(1 − c_ff)
        assert f.accel_mps2.abs().max() <= link_bound / (1 - prm.accel_feedforward) + 0.01
    assert f.gap_m.min() > 0.0
    assert max_abs_error(df, 260.0) < 0.5  # and it still converges (no integrator: no wind-up)


def test_command_is_the_speed_dependent_envelope():
    """Huge errors: the command is exactly min(M·a_dr, P/v) in traction and −min(M·a_br, P_br/v) in braking."""
    ctrl = ConsensusController(BASE)
    for v in (10.0, 40.0, 80.0):  # 80 m/s is in the power-limited region (Fig. 2(a))
        far = ctrl.make_step(_obs(gap_m=5000.0, speed_mps=v))
        near = ctrl.make_step(_obs(gap_m=STEADY_GAP_M - 100.0, speed_mps=v, leader_speed_mps=v - 20.0))
        assert far.force_n == pytest.approx(float(traction_limit(ETR, v)))
        assert near.force_n == pytest.approx(-float(brake_force_limit(ETR, v)))
        assert far.info["saturated"] and near.info["saturated"]
        lo, hi = acceleration_envelope(ETR, v)
        assert far.info["u_sat_mps2"] == pytest.approx(hi) and near.info["u_sat_mps2"] == pytest.approx(lo)
    assert float(traction_limit(ETR, 80.0)) < float(traction_limit(ETR, 10.0))


def test_eq44_link_bound():
    prm = BASE.model_copy(update={"link_bound_mps2": 0.1, "accel_feedforward": 0.0})
    cmd = ConsensusController(prm).make_step(_obs(gap_m=5000.0))
    assert cmd.info["u_mps2"] == pytest.approx(0.1)
    assert not cmd.info["saturated"]


def test_relative_braking_term_of_eq31_uses_the_predecessor_speed():
    prm = BASE.model_copy(update={"gap": SteadyGap(d_min_m=50.0, headway_s=1.5, rbd_brake_decel_mps2=0.65)})
    cmd = ConsensusController(prm).make_step(_obs(gap_m=300.0, speed_mps=40.0, leader_speed_mps=35.0))
    assert cmd.info["gap_ref_m"] == pytest.approx(50.0 + 1.5 * 40.0 + (40.0**2 - 35.0**2) / (2 * 0.65))


def test_force_conversion_inverts_the_train_model():
    for v, a, grad, tf in [(0.0, 0.3, 0.0, 1.0), (40.0, -0.4, 0.012, 1.0), (70.0, 0.1, -0.008, 1.3)]:
        u = force_for_acceleration(ETR, v, a, grad, tf)
        assert float(acceleration(ETR, v, u, grad, tf)) == pytest.approx(a, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# String stability (PF, constant time headway)


@pytest.mark.parametrize(
    "headway_s,compensation,delay_s,stable",
    [(1.5, "reference", 0.0, True), (0.0, "reference", 0.0, False), (1.5, "sender", 0.5, True), (1.5, "sender", 2.0, False)],
)
def test_string_stability_pf(headway_s, compensation, delay_s, stable):
    """Gap-error amplitudes along the string follow |G(jω)| of the linear analysis.

    The leader's speed oscillates at the frequency where the constant-spacing string is least stable;
    each follower's gap-error amplitude is |G(jω)| times its predecessor's.  With h = 1.5 s ≥ 2τ
    (and sender-speed extrapolation of a 0.5 s delay, below the 0.91 s bound) sup|G| ≤ 1: not
    amplified.  Constant spacing (h = 0) and a 2 s delay give |G| > 1: amplified.
    """
    prm = cbc_params_for("PF", BASE, delay_compensation=compensation, gap={"d_min_m": 50.0, "headway_s": headway_s})
    _, omega = string_gain_peak(cbc_params_for("PF", BASE, gap={"d_min_m": 50.0, "headway_s": 0.0}), LAG_S)
    g_pred = float(string_gain_response(prm, LAG_S, np.array([omega]), delay_s)[0])
    assert (string_gain(prm, LAG_S, delay_s) <= 1.0 + 1e-6) is stable
    assert (g_pred <= 1.0) is stable
    period = 2 * math.pi / omega
    ref = 50.0 + headway_s * V0
    channel = ChannelConfig(model="constant", delay_s=delay_s, period_s=DT) if delay_s else None
    df = simulate_convoy(
        ["etr1000"] * 5, lambda tid: ConsensusController(prm), lambda t: V0 + 0.5 * math.sin(omega * t), 300.0, DT, channel, [ref] * 4
    )
    df = gap_errors(df)
    late = df[(df.time_s > 300.0 - 3 * period) & (df.train != "T0")]
    amp = late.groupby("train").gap_error_m.agg(lambda s: (s.max() - s.min()) / 2)
    ratios = (amp / amp.shift(1)).dropna().to_numpy()
    np.testing.assert_allclose(ratios, g_pred, rtol=0.01)  # Euler at Δt = 0.2 s: within 0.4 %
    if stable:
        assert np.all(np.diff(amp.to_numpy()) <= 0)  # not amplified along the string
    else:
        assert np.all(np.diff(amp.to_numpy()) > 0)


# ---------------------------------------------------------------------------------------------
# Merge / split with transitional references (eq. 3.2–3.6)


@pytest.mark.parametrize("topology", ["PF", "TPF"])
@pytest.mark.parametrize("manoeuvre", ["merge", "split"])
def test_merge_and_split_track_the_jerk_limited_reference(topology, manoeuvre):
    steady_end = BASE.gap if manoeuvre == "merge" else SteadyGap(d_min_m=500.0, headway_s=1.5)
    d0 = 800.0 if manoeuvre == "merge" else STEADY_GAP_M
    tr = JerkLimitedTransition.design(10.0, d0, steady_end, V0, jerk_mps3=0.1, max_accel_mps2=0.15, idle_s=25.0)
    schedule = {"T3": tr}  # one mapping shared by every controller (multi-hop offsets agree)
    df = run(cbc_params_for(topology, BASE), gaps=[STEADY_GAP_M, STEADY_GAP_M, d0], duration_s=tr.end_time_s + 120.0, schedule=schedule)
    t3 = df[df.train == "T3"]
    assert t3.gap_error_m.abs().max() < 8.0
    assert t3.gap_m.iloc[-1] == pytest.approx(steady_end.gap_m(V0), abs=0.5)
    assert t3.accel_mps2.abs().max() < 0.15 + 0.03  # the profile's a_max, not the train's 0.7 m/s²
    assert df[df.train.isin(["T1", "T2"])].gap_error_m.abs().max() < 0.5  # the others are undisturbed


# ---------------------------------------------------------------------------------------------
# Variants eq. 4.10 and 4.11


def test_eq410_liu_converges_with_and_without_delay():
    prm = load_cbc_params("cbc_liu")
    for ch in (None, ChannelConfig(model="constant", delay_s=1.0, period_s=DT)):
        df = run(prm, channel=ch)
        assert max_abs_error(df, 180.0) < 0.5
        assert set(followers(df, 2.2)["mode"]) == {"cbc-liu_tanh"}


def test_eq411_zhou_converges_to_the_predicted_bias():
    """The speed-limit barrier k3·v/(v − v_max) is balanced by k1·tanh(e/ℓ): e = ℓ·atanh(k3 v/((v_max − v) k1))."""
    prm = load_cbc_params("cbc_zhou")
    df = run(prm)
    z = prm.zhou
    v_max = min(100.0, ETR.max_speed_ms)  # flat test line limit vs the train's maximum
    bias = z.spacing_scale_m * math.atanh(z.k3_mps2 * V0 / ((v_max - V0) * z.k1_mps2))
    late = followers(df, 180.0)
    np.testing.assert_allclose(late.gap_error_m, bias, atol=0.02)
    assert 0.0 < bias < 0.1


def test_variants_need_pf():
    with pytest.raises(ValueError, match="predecessor-follower"):
        CbcParams(law="zhou_tanh", topology="BD")


# ---------------------------------------------------------------------------------------------
# Configuration and single steps


def test_shipped_yaml_files_load():
    for name, topo in [("cbc", "PF"), ("cbc_plf", "PLF"), ("cbc_bd", "BD"), ("cbc_bdl", "BDL"), ("cbc_tpf", "TPF")]:
        p = load_cbc_params(name)
        assert p.topology == topo and p.law == "consensus"
        assert p.model_dump(exclude={"topology"}) == BASE.model_dump(exclude={"topology"})
    with pytest.raises(InputError, match="unknown controller settings"):
        load_cbc_params("nope")


def test_unknown_key_is_rejected(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("topology: PF\nk_pos: 1\n")
    with pytest.raises(InputError, match="k_pos"):
        load_cbc_params(bad)


def test_controller_drives_a_convoy_leader_to_its_target_speed():
    ctrl = ConsensusController(BASE)
    obs = _obs(gap_m=STEADY_GAP_M)
    lead = Observation(
        time_s=obs.time_s, step_s=DT, ego_id="T0", ego=TrainStateMsg(obs.time_s, 10000.0, 30.0), params=ETR, profile=obs.profile,
        convoy=obs.convoy, target_speed_mps=40.0,
    )
    cmd = ctrl.make_step(lead)
    assert cmd.mode == "cbc-leader" and cmd.force_n > 0
    assert cmd.info["target_speed_mps"] == 40.0


def _obs(gap_m: float, speed_mps: float = V0, leader_speed_mps: float | None = None, age_s: float = 0.0) -> Observation:
    """Follower T1 behind leader T0 (PF), one message from the leader of age ``age_s``."""
    t = 100.0
    x1 = 5000.0
    x0 = x1 + gap_m + ETR.length_m
    v0 = speed_mps if leader_speed_mps is None else leader_speed_mps
    msg = Message("T0", t - age_s, TrainStateMsg(t - age_s, x0 - v0 * age_s, v0), ETR.length_m)
    return Observation(
        time_s=t, step_s=DT, ego_id="T1", ego=TrainStateMsg(t, x1, speed_mps), params=ETR, profile=flat_profile(1e6, 100.0),
        received={"T0": msg}, predecessor="T0", convoy=("T0", "T1"),
    )
