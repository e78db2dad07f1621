"""Offline reproduction of Terlizzi, Liuzza & Glielmo (2024), §VII: scenarios OS1 and OS2.

Two trains (``terlizzi2024_leader`` / ``terlizzi2024_follower``, Table III with the power fix of
the rolling-stock files) run on the Firenze–Bologna gradient profile ("up" track, positions from
the Bologna end), each integrated by :class:`vcsumo.plant.TrainPlant` with parameters drawn inside
its eq. 7 box (the true plant differs from the nominal model; seeded).  The leader sends a packet
every 1 s over :class:`vcsumo.control.channel.Channel` (constant or exponential delay, loss
p_loss = 0.01 of Table II, degradations, outages) with its state and its robust planned trajectory
(its RLP, eq. 12, under the force plan of its own speed-tracking MPC on the nominal model).  The
follower runs the paper's architecture: Algorithm 1–3 in :class:`~vcsumo.control.cbf.CBFSupervisor`
around Algorithm 4–5 in :class:`~vcsumo.control.cruise.SwitchedCruiseController`.

The line speed is taken constant (V^line = V^max = 83 m/s) as in the paper (§VII); gradients are
those of the line file.

* **OS1** — L3 start 6,000 m apart (front-to-rear) at the same speed; the leader changes speed
  twice, the follower closes the gap and couples; then the leader brakes to a stop.  Run for two
  constant channel delays (3 s and 0.8 s).
* **OS2** — the trains start coupled at 50 m/s; the channel degrades from 500 s (growing delay and
  loss), is lost at 1,200 s and restored after an outage; run with and without the delay estimator.

With the rolling stock's power-limited brake (P_br ≈ 9.8 MW) and the robust box, the spacing the
barrier requires grows fast with speed (≈ 2 km at 35 m/s, 3–5 km at 50 m/s, > 10 km at 80 m/s on
the line's 1.15 % falls), so the paper's OS1 speeds (~80 m/s catch-up, 60 and 40 m/s) and timeline
(2,250 s, more than the 91.5 km of the line) are replaced by 55/45/35 m/s with changes at 500 and
900 s and the stop at 1,300 s.  All are parameters of :class:`OS1Spec` / :class:`OS2Spec`.

Run ``python -m vcsumo.reproduce.terlizzi2024 --out DIR`` to write ``summary.csv`` and one
trajectory CSV per run.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from vcsumo.config import load_model
from vcsumo.control.base import Command, Message, Observation, TrainStateMsg
from vcsumo.control.cbf import CBFConfig, CBFSupervisor
from vcsumo.control.channel import Channel, ChannelConfig, Degradation, Window
from vcsumo.control.cruise import CondensedMPC, CruiseConfig, PositionReferenceGenerator, SwitchedCruiseController, Weights
from vcsumo.control.params import resolve_params
from vcsumo.control.proxies import GradeWindow, RobustProxies, robust_plan, sample_params
from vcsumo.control.registry import StackContext, build_follower_stack
from vcsumo.line import load_line
from vcsumo.plant import PlantState
from vcsumo.sim.offline import OfflineStep, OfflineTrain, run_convoy
from vcsumo.rolling_stock import load_rolling_stock
from vcsumo.route_profile import RouteProfile
from vcsumo.topology import build_topology

LEADER = "leader"
FOLLOWER = "follower"


# -------------------------------------------------------------------------------------------
# Scenario specifications


@dataclass(frozen=True)
class OS1Spec:
    """OS1: L3 → VC transition, leader speed changes, then a leader stop."""

    duration_s: float = 1560.0
    dt_s: float = 0.1
    leader_start_m: float = 9500.0
    initial_gap_m: float = 6000.0
    """Front-to-rear gap at t = 0 (the paper's 6,000 m separation), m."""
    speed_schedule: tuple[tuple[float, float], ...] = ((0.0, 55.0), (500.0, 45.0), (900.0, 35.0))
    """(from time s, leader target speed m/s)."""
    brake_time_s: float = 1300.0
    """The leader brakes to a stop from here, s."""
    steady_window_s: float = 150.0
    """The coupled distance is the mean gap over [brake_time − window, brake_time), s."""


@dataclass(frozen=True)
class OS2Spec:
    """OS2: coupled at constant speed, channel degradation, loss, restoration."""

    duration_s: float = 1650.0
    dt_s: float = 0.1
    leader_start_m: float = 6500.0
    speed_mps: float = 50.0
    base_delay_s: float = 0.4
    base_mean_extra_s: float = 0.2
    degradations: tuple[tuple[float, float, float, float, float], ...] = (
        (500.0, 800.0, 1.0, 0.5, 0.02),
        (800.0, 1000.0, 2.0, 1.0, 0.05),
        (1000.0, 1200.0, 3.5, 1.5, 0.10),
    )
    """(start s, end s, extra delay s, mean extra exponential delay s, loss probability)."""
    outage: tuple[float, float] = (1200.0, 1260.0)
    fixed_delay_s: float = 0.6
    """τ̄ without the estimator (and its initial value with it): the healthy channel's mean delay, s."""
    steady_window: tuple[float, float] = (300.0, 500.0)
    degraded_window: tuple[float, float] = (1000.0, 1200.0)


# -------------------------------------------------------------------------------------------
# Set-up helpers


def load_configs(cbf_path: str | Path | None = None, cruise_path: str | Path | None = None) -> tuple[CBFConfig, CruiseConfig]:
    cbf = load_model(CBFConfig, resolve_params(cbf_path, "cbf_terlizzi2024", "cbf_path"))  # the paper's barrier (fixed d, service-box leader)
    cruise = load_model(CruiseConfig, resolve_params(cruise_path, "cruise_terlizzi2024", "cruise_path"))
    return cbf, cruise


def line_profile(direction: str = "up") -> RouteProfile:
    """The Firenze–Bologna main track as a route profile (positions from the Bologna end for "up")."""
    topo = build_topology(load_line("firenze_bologna"))
    edges = topo.track_for("main", direction).edges
    return RouteProfile.from_edges(topo, edges)


class SpeedSchedule:
    """Piecewise-constant leader target speed with an optional stop from a given time."""

    def __init__(self, steps: tuple[tuple[float, float], ...], stop_time_s: float | None = None):
        self.t = np.array([a for a, _ in steps], dtype=float)
        self.v = np.array([b for _, b in steps], dtype=float)
        self.stop_time_s = stop_time_s

    def __call__(self, t: float) -> float:
        return float(self.at(np.array([t]))[0])

    def at(self, t: np.ndarray) -> np.ndarray:
        i = np.maximum(np.searchsorted(self.t, t, side="right") - 1, 0)
        v = self.v[i]
        if self.stop_time_s is not None:
            v = np.where(t >= self.stop_time_s, 0.0, v)
        return v


class LeaderController:
    """The leader's own controller: a speed-tracking MPC on its nominal model (§VI-D: "any valid
    MPC embedded on the leader over its nominal model") solved once per packet period, plus the
    robust planned trajectory x̲^L(t_κ) = RLP under that force plan (eq. 12) sent with the packet."""

    def __init__(self, stock, cruise: CruiseConfig, profile: RouteProfile, schedule: SpeedSchedule, dt_s: float, leader_speed_weight: float = 10.0, leader_force_weight: float = 1e-4):
        self.nominal = stock.params()
        self.mpc = CondensedMPC(self.nominal, cruise.horizon_s, cruise.mpc_step_s, cruise.blocks)
        self.route = GradeWindow(profile)
        self.proxies = RobustProxies.from_stock(stock, profile)
        self.schedule = schedule
        self.weights = Weights(0.0, leader_speed_weight, leader_force_weight)
        self.dt = dt_s
        self.sol = None
        self.length_m = stock.length_m

    def plan(self, t: float, s: float, v: float) -> None:
        tk = t + self.mpc.dt * np.arange(1, self.mpc.N + 1)
        v_ref = self.schedule.at(tk)
        self.sol = self.mpc.solve(t, s, v, np.zeros(self.mpc.N), v_ref, self.weights, self.route, self.nominal.max_speed_ms, False)

    def force(self, t: float, v: float) -> float:
        if self.schedule(t) <= 0.0 and v < 0.5:
            return -self.nominal.mass_kg * self.nominal.service_brake_decel_mps2  # holding brake at a stop
        sol = self.sol
        k = min(int((t - sol.times_s[0]) / self.mpc.dt + 1e-9), len(sol.forces_n) - 1)
        return float(sol.forces_n[max(k, 0)])

    def broadcast_plan(self, t: float, s: float, v: float) -> tuple:
        """At every packet: plan with the MPC, and the robust planned trajectory sent with the packet
        (times, positions, speeds, forces) — the offline loop's ``plan`` hook."""
        self.plan(t, s, v)
        sol = self.sol
        n = int(round((sol.times_s[-1] - t) / self.dt))
        tt = t + self.dt * np.arange(n)
        idx = np.minimum(((tt - sol.times_s[0]) / self.mpc.dt + 1e-9).astype(int), len(sol.forces_n) - 1)
        forces = sol.forces_n[idx]
        pt, ps, pv = robust_plan(self.proxies, s, v, forces, self.dt, t, every=max(1, int(round(0.5 / self.dt))))
        return pt, ps, pv, np.interp(pt, sol.times_s[:-1], sol.forces_n)

    def message(self, t: float, s: float, v: float, a: float, f: float) -> Message:
        """The packet at time t: state and robust planned trajectory (plans first)."""
        pt, ps, pv, pf = self.broadcast_plan(t, s, v)
        return Message(sender=LEADER, sent_time_s=t, state=TrainStateMsg(time_s=t, position_m=s, speed_mps=v, accel_mps2=a, force_n=f),
                       length_m=self.length_m, plan_times_s=pt, plan_positions_m=ps, plan_speeds_mps=pv, plan_forces_n=pf)

    def make_step(self, obs: Observation) -> Command:
        """The leader's force (the Controller interface; the plan is made at each packet)."""
        return Command(self.force(obs.time_s, obs.ego.speed_mps), mode="leader")


@dataclass
class RunResult:
    summary: dict
    trajectories: pd.DataFrame
    supervisor: CBFSupervisor = field(repr=False)
    cruise: SwitchedCruiseController = field(repr=False)


def _simulate(
    *,
    profile: RouteProfile,
    cbf: CBFConfig,
    cruise_cfg: CruiseConfig,
    channel_cfg: ChannelConfig,
    schedule: SpeedSchedule,
    s_leader0: float,
    s_follower0: float,
    v0: float,
    duration_s: float,
    dt_s: float,
    seed: int,
    record_every: int = 5,
) -> RunResult:
    lead_stock = load_rolling_stock("terlizzi2024_leader")
    fol_stock = load_rolling_stock("terlizzi2024_follower")
    rng = np.random.default_rng(seed)
    p_lead_true = sample_params(lead_stock, rng)
    p_fol_true = sample_params(fol_stock, rng)
    channel = Channel(channel_cfg)
    leader = LeaderController(lead_stock, cruise_cfg, profile, schedule, dt_s)
    # the paper's architecture: Algorithm 1-3 around Algorithm 4-5, no separation guard
    stack = build_follower_stack("cbf-cruise", StackContext(ego=fol_stock, predecessor=lead_stock, step_s=dt_s, profile=profile, params=cruise_cfg,
                                                            supervisor_params=cbf, guard=False, ego_id=FOLLOWER, predecessor_id=LEADER))
    sup, cruise = stack.supervisor, stack.nominal
    timed = _Timed(stack)
    trains = [
        OfflineTrain(LEADER, p_lead_true, PlantState(s_leader0, v0), leader, nominal=lead_stock.params(), plan=leader.broadcast_plan),
        OfflineTrain(FOLLOWER, p_fol_true, PlantState(s_follower0, v0), timed, nominal=fol_stock.params(), sends=False),
    ]
    rows = []
    last_rx = -math.inf

    def record(step: OfflineStep) -> None:
        nonlocal last_rx
        xl, xf = step.states
        cmd = step.commands[1]
        nom = stack.stage.last_nominal
        msg = step.observations[1].received.get(LEADER)
        rx = msg is not None and msg.received_time_s > last_rx
        if rx:
            last_rx = msg.received_time_s
        if step.k % record_every == 0 or rx or cmd.emergency:
            rows.append(
                {
                    "time_s": step.time_s,
                    "leader_position_m": xl.s_m,
                    "leader_speed_mps": xl.v_mps,
                    "leader_force_n": xl.force_n,
                    "follower_position_m": xf.s_m,
                    "follower_speed_mps": xf.v_mps,
                    "follower_force_n": xf.force_n,
                    "gap_m": xl.s_m - L - xf.s_m,
                    "interdistance_m": xl.s_m - xf.s_m,
                    "mode": cmd.mode,
                    "nominal_mode": nom.mode,
                    "emergency": cmd.emergency,
                    "robust_barrier_m": cmd.info.get("cbf_barrier_m", math.nan),
                    "true_barrier_m": cmd.info.get("cbf_true_barrier_m", math.nan),
                    "info_age_s": cmd.info.get("cbf_info_age_s", math.nan),
                    "tau_bar_s": nom.info.get("tau_bar_s", math.nan),
                    "z_tau1_m": nom.info.get("z_tau1_m", math.nan),
                    "z_tau2_m": nom.info.get("z_tau2_m", math.nan),
                    "z_tau3_m": nom.info.get("z_tau3_m", math.nan),
                    "packet_received": rx,
                    "packet_delay_s": (msg.received_time_s - msg.sent_time_s) if rx else math.nan,
                }
            )

    L = lead_stock.length_m
    n = int(round(duration_s / dt_s))
    # the paper's plant has one brake (K_E^F demands the strongest brake of the box, eq. 4)
    run_convoy(trains, profile, dt_s, n * dt_s, channel=channel, record_every=0, emergency_brake=False, on_step=record)
    cpu_ctrl = timed.seconds
    df = pd.DataFrame(rows)
    cpu = np.array(cpu_ctrl) * 1e3
    st = sup.stats
    hist = sup.history_frame()
    em = hist.emergency.to_numpy(dtype=bool)
    on_t = hist.time_s.to_numpy()[np.flatnonzero(em & ~np.concatenate(([False], em[:-1])))]
    off_t = hist.time_s.to_numpy()[np.flatnonzero(~em & np.concatenate(([False], em[:-1])))]
    episodes = 0
    for t_on in on_t:  # activations more than 10 s after the previous release start a new episode
        prev_off = off_t[off_t <= t_on]
        if episodes == 0 or len(prev_off) == 0 or t_on - prev_off[-1] > 10.0:
            episodes += 1
    summary = {
        "emergency_activations": st.emergency_activations,
        "emergency_episodes": episodes,
        "tmax_activations": st.tmax_activations,
        "emergency_steps": st.interventions,
        "emergency_time_s": round(st.emergency_time_s, 3),
        "min_gap_m": float(df["gap_m"].min()),
        "true_barrier_max": float(np.nanmax(sup.history.true_barrier_m)),
        "robust_barrier_max": float(np.nanmax(sup.history.robust_barrier_m)),
        "packets_sent": channel.sent,
        "packets_delivered": channel.delivered,
        "packets_lost": channel.lost,
        "qp_solves": cruise.solves,
        "qp_failures": cruise.failed_solves,
        "follower_step_mean_ms": float(cpu.mean()),
        "follower_step_p99_ms": float(np.percentile(cpu, 99)),
        "seed": seed,
    }
    for m, c in cruise.mode_counts.items():
        summary[f"share_{m}"] = round(c / max(1, sum(cruise.mode_counts.values())), 4)
    return RunResult(summary, df, sup, cruise)


class _Timed:
    """The follower's stack with the CPU time of each step (``seconds``)."""

    def __init__(self, stack):
        self.stack = stack
        self.seconds: list[float] = []

    def make_step(self, obs: Observation) -> Command:
        c0 = time.perf_counter()
        cmd = self.stack.make_step(obs)
        self.seconds.append(time.perf_counter() - c0)
        return cmd

    @property
    def events(self) -> list:
        return self.stack.events


# -------------------------------------------------------------------------------------------
# OS1 and OS2


def run_os1(delay_s: float, seed: int = 1, spec: OS1Spec | None = None, cbf: CBFConfig | None = None, cruise: CruiseConfig | None = None, profile: RouteProfile | None = None, full: bool = False):
    """OS1 for a constant channel delay; returns (summary_row, trajectories_df) (or the RunResult if ``full``)."""
    spec = spec or OS1Spec()
    cbf0, cruise0 = load_configs()
    cbf, cruise = cbf or cbf0, cruise or cruise0
    cruise = cruise.model_copy(update={"line_speed_limits": False, "fixed_delay_s": delay_s})
    profile = profile or line_profile()
    L = load_rolling_stock("terlizzi2024_leader").length_m
    v0 = spec.speed_schedule[0][1]
    ch = ChannelConfig(model="constant", period_s=1.0, delay_s=delay_s, loss_probability=cbf.packet_loss_probability, seed=seed)
    res = _simulate(
        profile=profile, cbf=cbf, cruise_cfg=cruise, channel_cfg=ch,
        schedule=SpeedSchedule(spec.speed_schedule, spec.brake_time_s),
        s_leader0=spec.leader_start_m, s_follower0=spec.leader_start_m - L - spec.initial_gap_m, v0=v0,
        duration_s=spec.duration_s, dt_s=spec.dt_s, seed=seed,
    )
    df = res.trajectories
    w = df[(df.time_s >= spec.brake_time_s - spec.steady_window_s) & (df.time_s < spec.brake_time_s)]
    end = df.iloc[-1]
    stopped = end.leader_speed_mps < 0.1 and end.follower_speed_mps < 0.1
    first_cruise2 = df[(df["nominal_mode"] == "cruise-2") & (df.time_s > 0)]
    row = {
        "scenario": "OS1",
        "delay_s": delay_s,
        "delay_estimator": cruise.delay_estimator,
        "coupled_distance_m": float(w.gap_m.mean()),
        "coupled_interdistance_m": float(w.interdistance_m.mean()),
        "reference_gap_m": float((w.leader_position_m - L - w.z_tau2_m).mean()),
        "coupled_speed_mps": float(w.leader_speed_mps.mean()),
        "tau_bar_s": float(w.tau_bar_s.mean()),
        "first_k2_time_s": float(first_cruise2.time_s.iloc[0]) if len(first_cruise2) else math.nan,
        **res.summary,
        "both_stopped": bool(stopped),
        "both_stopped_gap_m": float(end.gap_m) if stopped else math.nan,
        "safety_distance_m": cbf.safety_distance_m,
    }
    return res if full else (row, df)


def os2_channel(spec: OS2Spec, loss: float, seed: int) -> ChannelConfig:
    return ChannelConfig(
        model="exponential", period_s=1.0, delay_s=spec.base_delay_s, mean_extra_s=spec.base_mean_extra_s,
        loss_probability=loss,
        degradations=[Degradation(start_s=a, end_s=b, delay_s=d, mean_extra_s=m, loss_probability=p) for a, b, d, m, p in spec.degradations],
        outages=[Window(start_s=spec.outage[0], end_s=spec.outage[1])],
        seed=seed,
    )


def coupled_start_gap(profile: RouteProfile, cbf: CBFConfig, cruise: CruiseConfig, s_leader: float, v: float, tau_bar_s: float) -> float:
    """Front-to-rear gap at which the follower sits on z_τ2 behind a leader cruising at v (eq. 27)."""
    lead_stock = load_rolling_stock("terlizzi2024_leader")
    fol_stock = load_rolling_stock("terlizzi2024_follower")
    ctl = SwitchedCruiseController(lead_stock, fol_stock, cruise, cbf)
    model, _ = ctl._model(profile)
    msg = Message(sender=LEADER, sent_time_s=0.0, state=TrainStateMsg(0.0, s_leader, v), length_m=lead_stock.length_m)
    s_f = s_leader - lead_stock.length_m - cbf.safety_distance_m
    for _ in range(4):  # the reference depends weakly on the follower's own position (its window)
        ref = PositionReferenceGenerator(model, cruise, 0.1).compute(msg, tau_bar_s, s_f, v, 0.0)
        s_f = float(ref.at(0.0)[1])
    return s_leader - lead_stock.length_m - s_f


def run_os2(delay_estimator: bool, seed: int = 2, spec: OS2Spec | None = None, cbf: CBFConfig | None = None, cruise: CruiseConfig | None = None, profile: RouteProfile | None = None, full: bool = False):
    """OS2 with or without the delay estimator; returns (summary_row, trajectories_df)."""
    spec = spec or OS2Spec()
    cbf0, cruise0 = load_configs()
    cbf, cruise = cbf or cbf0, cruise or cruise0
    cruise = cruise.model_copy(update={"line_speed_limits": False, "delay_estimator": delay_estimator, "fixed_delay_s": spec.fixed_delay_s})
    profile = profile or line_profile()
    L = load_rolling_stock("terlizzi2024_leader").length_m
    gap0 = coupled_start_gap(profile, cbf, cruise, spec.leader_start_m, spec.speed_mps, cruise.fixed_delay_s)
    res = _simulate(
        profile=profile, cbf=cbf, cruise_cfg=cruise, channel_cfg=os2_channel(spec, cbf.packet_loss_probability, seed),
        schedule=SpeedSchedule(((0.0, spec.speed_mps),)),
        s_leader0=spec.leader_start_m, s_follower0=spec.leader_start_m - L - gap0, v0=spec.speed_mps,
        duration_s=spec.duration_s, dt_s=spec.dt_s, seed=seed,
    )
    df = res.trajectories
    w = df[(df.time_s >= spec.steady_window[0]) & (df.time_s < spec.steady_window[1])]
    wd = df[(df.time_s >= spec.degraded_window[0]) & (df.time_s < spec.degraded_window[1])]
    hist = res.supervisor.history_frame()
    on = hist.emergency.astype(int).diff().fillna(hist.emergency.astype(int)) > 0
    act_t = hist.time_s[on]
    row = {
        "scenario": "OS2",
        "delay_s": math.nan,
        "delay_estimator": delay_estimator,
        "coupled_distance_m": float(w.gap_m.mean()),
        "coupled_interdistance_m": float(w.interdistance_m.mean()),
        "reference_gap_m": float((w.leader_position_m - L - w.z_tau2_m).mean()),
        "degraded_distance_m": float(wd.gap_m.mean()),
        "coupled_speed_mps": float(w.leader_speed_mps.mean()),
        "tau_bar_s": float(w.tau_bar_s.mean()),
        "tau_bar_degraded_s": float(wd.tau_bar_s.mean()),
        "initial_gap_m": gap0,
        **res.summary,
        "activations_before_outage": int(((act_t >= spec.degradations[0][0]) & (act_t < spec.outage[0])).sum()),
        "activations_after_outage": int((act_t >= spec.outage[1]).sum()),
        "both_stopped_gap_m": math.nan,
        "safety_distance_m": cbf.safety_distance_m,
    }
    return res if full else (row, df)


def run_all(out: Path | None = None, seed_os1: int = 1, seed_os2: int = 2) -> pd.DataFrame:
    """OS1 (3 s, 0.8 s) and OS2 (with, without estimator); writes CSVs to ``out`` if given."""
    rows, trajs = [], {}
    for d in (3.0, 0.8):
        r, df = run_os1(d, seed=seed_os1)
        rows.append(r)
        trajs[f"os1_delay_{d:g}s"] = df
    for est in (True, False):
        r, df = run_os2(est, seed=seed_os2)
        rows.append(r)
        trajs[f"os2_estimator_{'on' if est else 'off'}"] = df
    summary = pd.DataFrame(rows)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        summary.to_csv(out / "summary.csv", index=False)
        for name, df in trajs.items():
            df.to_csv(out / f"{name}.csv", index=False)
    return summary


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Reproduce Terlizzi et al. (2024) OS1/OS2 offline")
    ap.add_argument("--out", type=Path, default=Path("results") / "terlizzi2024")
    args = ap.parse_args(argv)
    summary = run_all(args.out)
    with pd.option_context("display.max_columns", None, "display.width", 200):
        print(summary.T)


if __name__ == "__main__":
    main()
