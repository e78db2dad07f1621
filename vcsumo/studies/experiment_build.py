"""From an experiment file's model to the offline loop's inputs: track, trains, stacks, channel.

Everything is built from the validated :class:`~vcsumo.studies.experiment_model.Experiment`; paths
are relative to the file's folder (``base_dir``).  Problems the model cannot see (an unknown
stock, a parameter override its controller rejects, a km range outside the line) are one
:class:`~vcsumo.errors.InputError` naming the experiment file and the field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ValidationError

from vcsumo.config import parse_model, read_yaml, validation_error
from vcsumo.control.base import Message, TrainStateMsg
from vcsumo.control.cbf import BarrierModel, CBFConfig
from vcsumo.control.channel import ChannelConfig, Degradation, Window
from vcsumo.control.consensus import CbcParams
from vcsumo.control.cruise import CruiseConfig, PositionReferenceGenerator
from vcsumo.control.route_lookup import route_profile_from_arrays
from vcsumo.control.mpc import MPCSettings
from vcsumo.control.params import is_path_spec, resolve_params
from vcsumo.control.proxies import BoxBounds, sample_params
from vcsumo.control.registry import CONTROLLERS, SUPERVISORS, StackContext, build_follower_stack, controller_spec
from vcsumo.control.stack import FollowerStack
from vcsumo.dynamics import TrainParams
from vcsumo.errors import InfeasibleBraking, InputError
from vcsumo.line import load_line
from vcsumo.plant import PlantState
from vcsumo.rolling_stock import Interval, RollingStock, UncertaintyBox, load_rolling_stock
from vcsumo.signalling.separation import RelativeBraking
from vcsumo.route_profile import RouteProfile
from vcsumo.running_time import stall_problem
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.train_braking import guaranteed_decel
from vcsumo.sim.offline import OfflineTrain, steady_force
from vcsumo.studies.experiment_leaders import LeaderEvents, Schedule, SpeedMPCLeader, SpeedTracker, felez_leader
from vcsumo.studies.experiment_model import ChannelSpec, Experiment, StockSpec, TrackSpec
from vcsumo.topology import build_topology

PARAM_MODELS: dict[str, type[BaseModel]] = {"mpc": MPCSettings, "cbc": CbcParams, "cruise": CruiseConfig}
"""The parameter model of each registered family whose parameters an experiment may override."""
SUPERVISOR_MODELS: dict[str, type[BaseModel]] = {"cbf": CBFConfig}


# -------------------------------------------------------------------------------------------
# Track


def _rel(spec: str, base_dir: Path | None) -> str | Path:
    """A path spec taken relative to the experiment file's folder; a shipped name as it is."""
    if is_path_spec(spec) and not Path(spec).is_absolute() and base_dir is not None:
        return Path(base_dir) / spec
    return spec


def cut_profile(profile: RouteProfile, s0: float, s1: float) -> RouteProfile:
    """The stretch [s0, s1] of a route profile, positions from s0 (turnout limits kept)."""
    i0, i1 = profile.index_at(s0), profile.index_at(max(s0, s1 - 1e-6))
    idx = range(i0, i1 + 1)
    starts = np.array([max(profile.starts_m[i], s0) - s0 for i in idx])
    ends = np.array([min(profile.starts_m[i] + profile.lengths_m[i], s1) - s0 for i in idx])

    def km(i: int, s: float) -> float:
        frac = (s - profile.starts_m[i]) / profile.lengths_m[i] if profile.lengths_m[i] > 0 else 0.0
        return float(profile.km_from[i] + frac * (profile.km_to[i] - profile.km_from[i]))

    return RouteProfile(
        edges=[profile.edges[i] for i in idx], starts_m=starts, lengths_m=ends - starts, speeds_ms=np.array([profile.speeds_ms[i] for i in idx]),
        gradients=np.array([profile.gradients[i] for i in idx]), tunnel_factors=np.array([profile.tunnel_factors[i] for i in idx]),
        sections=[profile.sections[i] for i in idx], km_from=np.array([km(i, s0 + a) for i, a in zip(idx, starts)]),
        km_to=np.array([km(i, s0 + b) for i, b in zip(idx, ends)]), point_limits=[(p - s0, v) for p, v in profile.point_limits if s0 <= p <= s1],
    )


def _s_at_km(profile: RouteProfile, km: float, field_name: str, path) -> float:
    for i in range(len(profile.starts_m)):
        a, b = profile.km_from[i], profile.km_to[i]
        if min(a, b) - 1e-9 <= km <= max(a, b) + 1e-9:
            frac = 0.0 if b == a else (km - a) / (b - a)
            return float(profile.starts_m[i] + frac * profile.lengths_m[i])
    lo, hi = float(min(profile.km_from.min(), profile.km_to.min())), float(max(profile.km_from.max(), profile.km_to.max()))
    raise InputError(path, field_name, f"km {km:g} is not on the track (km {lo:g}–{hi:g})")


def build_profile(track: TrackSpec, base_dir: Path | None = None, path=None) -> RouteProfile:
    """The route of the experiment: a straight with its grade profile, or a line's track over a km range."""
    if track.straight is not None:
        st = track.straight
        pts = sorted((g.from_m, g.permille) for g in st.grades if g.from_m < st.length_m)
        if not pts or pts[0][0] > 0.0:
            pts = [(0.0, 0.0)] + pts
        starts = [p[0] for p in pts]
        if any(b <= a for a, b in zip(starts, starts[1:])):
            raise InputError(path, "track.straight.grades", "from_m must increase")
        return route_profile_from_arrays(starts, [st.speed_limit_mps] * len(pts), [p[1] / 1000.0 for p in pts], None, st.length_m)
    ln = track.line
    try:
        line = load_line(_rel(ln.line, base_dir))
    except InputError as exc:
        # a name looked up ("unknown line") is about this field: its message without the '--line: ' an
        # option would carry (before: "track.line.line: --line: unknown line 'x'"); a problem inside
        # the line file names that file already
        raise InputError(path, "track.line.line", exc.message if exc.path is None else str(exc)) from None
    topo = build_topology(line)
    try:
        edges = topo.track_for(ln.track, ln.direction).edges
    except (KeyError, ValueError) as exc:
        raise InputError(path, "track.line.track", f"no track '{ln.track}' ({ln.direction}) on this line: {exc}") from None
    prof = RouteProfile.from_edges(topo, edges)
    s0 = 0.0 if ln.km_from is None else _s_at_km(prof, ln.km_from, "track.line.km_from", path)
    s1 = prof.length_m if ln.km_to is None else _s_at_km(prof, ln.km_to, "track.line.km_to", path)
    if s1 - s0 < 100.0:
        raise InputError(path, "track.line.km_to", f"the stretch is {s1 - s0:.0f} m long in the direction of travel (at least 100 m)")
    return cut_profile(prof, s0, s1)


# -------------------------------------------------------------------------------------------
# Rolling stock and plants


def build_stock(spec: str | StockSpec, base_dir: Path | None, field_name: str, path=None) -> RollingStock:
    """A shipped or own rolling stock, with the file's overrides and ± box applied."""
    base = spec if isinstance(spec, str) else spec.base
    try:
        stock = load_rolling_stock(_rel(base, base_dir))
    except InputError as exc:
        raise InputError(path, field_name, exc.message if exc.path is None else str(exc)) from None
    if isinstance(spec, str):
        return stock
    data = stock.model_dump()
    data.update({k: v for k, v in spec.model_dump(exclude={"base", "uncertainty_pct"}).items() if v is not None})
    pct = spec.uncertainty_pct
    if pct is not None:
        f = pct / 100.0

        def box(v: float) -> dict:
            return {"low": v * (1.0 - f), "high": v * (1.0 + f)}

        def point(v: float) -> dict:
            return {"low": v, "high": v}

        data["uncertainty"] = {
            "mass_kg": box(data["mass_kg"]), "davis_a_n": box(data["davis_a_n"]), "davis_b_n_per_mps": box(data["davis_b_n_per_mps"]),
            "davis_c_n_per_mps2": box(data["davis_c_n_per_mps2"]), "max_accel_mps2": point(data["max_traction_n"] / data["mass_kg"]),
            "service_brake_decel_mps2": point(data["service_brake_decel_mps2"]), "max_power_w": point(data["max_power_w"]),
            "max_brake_power_w": None if data.get("max_brake_power_w") is None else point(data["max_brake_power_w"]),
        }
    try:
        return RollingStock.model_validate(data)
    except ValidationError as exc:
        err = validation_error(exc, None, RollingStock)
        raise InputError(path, f"{field_name}.{err.field}" if err.field else field_name, err.message) from None


def hardest_start(stock: RollingStock, kind: str) -> TrainParams:
    """The plant of this kind that starts hardest on a grade: the nominal train, or the corner of its
    uncertainty box with the least traction per mass and the most rolling resistance per mass (any
    seed may draw a plant near it)."""
    nom = stock.params()
    if kind == "nominal":
        return nom
    box = stock.uncertainty_box()
    m = box.mass_kg.low
    return nom.with_(mass_kg=m, davis_a_n=box.davis_a_n.high, max_traction_n=m * box.max_accel_mps2.low)


def plant_params(stock: RollingStock, kind: str, rng: np.random.Generator) -> TrainParams:
    """The plant's true parameters: nominal, drawn in the box, or at a corner of it."""
    if kind == "nominal":
        return stock.params()
    return sample_params(stock, rng, corner=kind == "corner")


# -------------------------------------------------------------------------------------------
# Controller parameters with overrides


def _with_overrides(model: type[BaseModel], spec: str | None, default: str, overrides: dict[str, Any], base_dir, field_name: str, path,
                    spec_field: str | None = None) -> BaseModel:
    """Load a parameter file and replace fields, validated like the file (errors name ``field_name``;
    a parameter file that is not found names ``spec_field``, the field that gave it)."""
    try:
        file = resolve_params(spec, default, spec_field or field_name, base_dir)
    except InputError as exc:
        raise InputError(path, exc.field, exc.message) from None
    raw = read_yaml(file)
    if not isinstance(raw, dict):
        return parse_model(model, raw, file)
    raw.update(overrides)
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        err = validation_error(exc, None, model)
        raise InputError(path, f"{field_name}.{err.field}" if err.field else field_name, err.message) from None


@dataclass
class FollowerSetup:
    """A follower's stack and the parameter objects it was built from."""

    stack: FollowerStack
    nominal_params: Any
    supervisor_params: Any
    files: list[Path] = field(default_factory=list)


def _resolve(spec: str, default: str, field_name: str, base_dir, path) -> Path:
    """A parameter file named in the experiment file at ``path`` (a missing one names the file and field)."""
    try:
        return resolve_params(spec, default, field_name, base_dir)
    except InputError as exc:
        raise InputError(path, exc.field, exc.message) from None


def build_follower(exp: Experiment, k: int, stocks: list[RollingStock], profile: RouteProfile, base_dir, path) -> FollowerSetup:
    """Follower k's registry stack (nominal → supervisor → guard → fault stage) with the file's parameters."""
    tr = exp.trains[k]
    fld = f"trains[{k}]"
    try:
        cs = controller_spec(tr.controller, f"{fld}.controller")
    except InputError as exc:
        raise InputError(path, exc.field, exc.message) from None
    entry = CONTROLLERS[cs.family]
    nominal: Any = None
    files: list[Path] = []
    spec = tr.params or cs.params
    if tr.overrides or tr.horizon_steps is not None:
        model = PARAM_MODELS.get(cs.family)
        if model is None:
            raise InputError(path, f"{fld}.overrides", f"parameters of controller family '{cs.family}' cannot be overridden here (only {', '.join(PARAM_MODELS)})")
        over = dict(tr.overrides)
        nominal = _with_overrides(model, spec, entry.default_params, over, base_dir, f"{fld}.overrides", path,
                                  f"{fld}.params" if tr.params else f"{fld}.controller")
        if tr.horizon_steps is not None:
            if isinstance(nominal, CruiseConfig):
                nominal = nominal.model_copy(update={"horizon_s": tr.horizon_steps * nominal.mpc_step_s})
            elif isinstance(nominal, MPCSettings):
                nominal = nominal.model_copy(update={"horizon_steps": tr.horizon_steps})
            else:
                raise InputError(path, f"{fld}.horizon_steps", f"controller family '{cs.family}' has no horizon")
    elif spec is not None:
        nominal = _resolve(spec, entry.default_params or "", f"{fld}.params" if tr.params else f"{fld}.controller", base_dir, path)
        files.append(nominal)
    sup: Any = None
    if cs.supervisor is None and cs.family != "cruise":
        for key in ("supervisor_params", "supervisor_overrides"):
            if getattr(tr, key):
                raise InputError(path, f"{fld}.{key}", f"controller '{tr.controller}' has no supervisor to take it (cbf-{cs.family} has the CBF)")
    if cs.supervisor is not None or cs.family == "cruise":
        sup_name = cs.supervisor or "cbf"
        if tr.supervisor_overrides:
            sup = _with_overrides(SUPERVISOR_MODELS[sup_name], tr.supervisor_params, SUPERVISORS[sup_name].default_params, tr.supervisor_overrides, base_dir,
                                  f"{fld}.supervisor_overrides", path, f"{fld}.supervisor_params")
        elif tr.supervisor_params is not None:
            sup = _resolve(tr.supervisor_params, SUPERVISORS[sup_name].default_params, f"{fld}.supervisor_params", base_dir, path)
            files.append(sup)
    ctx = StackContext(ego=stocks[k], predecessor=stocks[k - 1], step_s=exp.step_s, profile=profile, params=nominal, supervisor_params=sup,
                       guard=tr.guard, base_dir=base_dir, field=f"{fld}.controller", ego_id=tr.id, predecessor_id=exp.trains[k - 1].id,
                       control_period_s=tr.control_period_s, message_age_s=channel_config(exp.channel, exp.step_s, 0).age_budget_s())
    try:
        stack = build_follower_stack(tr.controller, ctx)
    except InputError as exc:
        raise InputError(path, exc.field, exc.message) from None
    return FollowerSetup(stack, nominal, sup, files)


def coupled_gap_m(setup: FollowerSetup, lead: RollingStock, ego: RollingStock, profile: RouteProfile, s_leader: float, v: float, step_s: float) -> float:
    """Front-to-rear gap at which a follower sits on its own reference behind a leader cruising at v.

    Cruise family: on z_τ2 (eq. 27) with τ̄ = its fixed (initial) delay; others: the stack's coupled spacing,
    and under a supervisor (``cbf-*``) at least where its barrier on these states is −1 m, with the
    separation guard 1 m outside the safe separation it keeps (the run-health monitor's rule): the
    controller sits where its safety layers let it (a ``cbf-mpc`` follower at the NMPC's own spacing
    starts inside the CBF's unsafe set, an ``mpc`` one inside the relative-braking rule)."""
    ctrl = setup.stack.nominal
    cruise = getattr(ctrl, "cfg", None)
    if not isinstance(cruise, CruiseConfig):
        sup, guard = setup.stack.supervisor, setup.stack.guard
        gap = float(setup.stack.coupled_gap_m(v))
        for _ in range(4):  # on the route: the spacing follows the gradients under the follower, whose place depends on the gap
            s_f = s_leader - lead.length_m - gap
            gap = float(setup.stack.coupled_gap_m(v, position_m=s_f))
            if sup is not None and hasattr(sup, "required_gap_m"):
                f_hold = steady_force(ego.params(), v, profile, s_f) if v > 0 else 0.0  # the force it starts with (build_setup)
                gap = max(gap, float(sup.required_gap_m(profile, s_leader, v, s_f, v, f_hold)) + 1.0)
            if guard is not None:  # and outside the safe separation its guard keeps (the run-health monitor's rule)
                gap = max(gap, RelativeBraking(guard.model, ego, lead, profile).required_gap(s_f, v, s_leader, v, guard.model.dead_time_s) + 1.0)
        return gap
    model = BarrierModel(BoxBounds.from_stock(lead), BoxBounds.from_stock(ego), ctrl.cbf, profile)
    msg = Message(sender="leader", sent_time_s=0.0, state=TrainStateMsg(0.0, s_leader, v), length_m=lead.length_m)
    s_f = s_leader - lead.length_m - ctrl.cbf.safety_distance_m
    for _ in range(4):  # the reference depends weakly on the follower's own position (its window)
        ref = PositionReferenceGenerator(model, cruise, step_s).compute(msg, cruise.fixed_delay_s, s_f, v, 0.0)
        s_f = float(ref.at(0.0)[1])
    return s_leader - lead.length_m - s_f


# -------------------------------------------------------------------------------------------
# Channel


def channel_config(spec: ChannelSpec | None, step_s: float, seed: int) -> ChannelConfig:
    """The :class:`~vcsumo.control.channel.ChannelConfig` of the file's channel (none: ideal, every step)."""
    if spec is None:
        return ChannelConfig(period_s=max(step_s, 0.01), seed=seed)
    exponential = spec.exp_rate_per_s is not None or any(w.exp_rate_per_s is not None for w in spec.degradations)
    degs = [Degradation(start_s=w.start_s, end_s=w.end_s, delay_s=w.extra_delay_s, mean_extra_s=w.extra_mean_s,
                        loss_probability=spec.loss_probability if w.loss_probability is None else w.loss_probability,
                        exponential_mean_s=None if w.exp_rate_per_s is None else 1.0 / w.exp_rate_per_s) for w in spec.degradations]
    return ChannelConfig(model="exponential" if exponential else "constant", period_s=spec.period_s, delay_s=spec.delay_s,
                         mean_extra_s=1.0 / spec.exp_rate_per_s if spec.exp_rate_per_s else 0.0, loss_probability=spec.loss_probability,
                         degradations=degs, outages=[Window(start_s=w.start_s, end_s=w.end_s) for w in spec.outages], seed=seed)


# -------------------------------------------------------------------------------------------
# The whole set-up


@dataclass
class Setup:
    """What :func:`vcsumo.sim.offline.run_convoy` needs, and the parts the measurements read."""

    profile: RouteProfile
    stocks: list[RollingStock]
    trains: list[OfflineTrain]
    followers: list[FollowerSetup]
    channel: ChannelConfig
    leader_driver: Any
    input_files: dict[str, Path]


def leader_driver(exp: Experiment, stock: RollingStock, profile: RouteProfile, base_dir, path) -> tuple[Any, Any, TrainParams | None, float | None]:
    """(driver, plan hook, plant override, objective speed) of the leader."""
    spec = exp.leader
    schedule = Schedule.from_spec(spec)
    plan, plant, objective = None, None, None
    if spec.driver == "speed_tracker":
        driver: Any = SpeedTracker(schedule, spec.gain_per_s)
    elif spec.driver == "speed_mpc":
        m = spec.mpc
        driver = SpeedMPCLeader(stock, profile, schedule, exp.step_s, m.horizon_steps, m.step_s, m.blocks, m.speed_weight_per_mps2, m.force_weight_per_kn2,
                                m.replan_period_s, m.robust_plan)
        plan = driver.broadcast_plan
    else:
        objective = exp.trains[0].target_speed_mps or (float(max(schedule.v)) if spec.schedule else None)
        if objective is None:
            raise InputError(path, "trains[0].target_speed_mps", "the felez_mpc leader needs its objective speed (target_speed_mps)")
        try:
            driver, plant = felez_leader(spec, stock, profile, objective, base_dir, exp.step_s)
        except InputError as exc:
            raise InputError(path, exc.field, exc.message) from None
    at_s = [e.at_s for e in spec.events if e.action == "emergency_brake" and e.at_s is not None]
    at_m = [e.at_m for e in spec.events if e.action == "emergency_brake" and e.at_m is not None]
    for k, e in enumerate(spec.events):
        if e.at_m is not None and e.at_m > profile.length_m:
            raise InputError(path, f"leader.events[{k}].at_m", f"{e.at_m:g} m is beyond the end of the track ({profile.length_m:.0f} m)")
    at_m += [_s_at_km(profile, e.at_km, f"leader.events[{k}].at_km", path) for k, e in enumerate(spec.events) if e.action == "emergency_brake" and e.at_km is not None]
    if at_s or at_m:
        driver = LeaderEvents(driver, at_s, at_m, plan)
        plan = driver.plan if plan is not None else None
    return driver, plan, plant, objective


def build_setup(exp: Experiment, seed: int, base_dir: Path | None = None, path=None, profile: RouteProfile | None = None) -> Setup:
    """Track, trains (plants, initial states, drivers), follower stacks and channel of one run."""
    base_dir = Path(base_dir).resolve() if base_dir is not None else None  # paths handed on stay valid whatever the working directory
    profile = profile or build_profile(exp.track, base_dir, path)
    stocks = [build_stock(t.stock, base_dir, f"trains[{k}].stock", path) for k, t in enumerate(exp.trains)]
    rng = np.random.default_rng(seed)
    plants = [plant_params(s, t.plant, rng) for s, t in zip(stocks, exp.trains)]
    driver, plan, lead_plant, objective = leader_driver(exp, stocks[0], profile, base_dir, path)
    if lead_plant is not None:
        plants[0] = lead_plant
    followers = [build_follower(exp, k, stocks, profile, base_dir, path) for k in range(1, len(exp.trains))]
    lead = exp.trains[0]
    room = sum(s.length_m for s in stocks[:-1]) + sum(t.gap_m if isinstance(t.gap_m, float) else 5000.0 for t in exp.trains[1:]) + stocks[-1].length_m
    positions = [lead.position_m if lead.position_m is not None else room + 10.0]
    for k, t in enumerate(exp.trains[1:], start=1):
        if t.position_m is not None:
            positions.append(t.position_m)
            continue
        gap = t.gap_m
        if gap == "coupled":
            gap = coupled_gap_m(followers[k - 1], stocks[k - 1], stocks[k], profile, positions[k - 1], t.speed_mps, exp.step_s)
        positions.append(positions[k - 1] - stocks[k - 1].length_m - float(gap))
    for k, s in enumerate(positions):
        if not stocks[k].length_m <= s <= profile.length_m:
            raise InputError(path, f"trains[{k}]", f"starts at {s:.1f} m, outside the track (its rear must be on it: {stocks[k].length_m:.0f}–{profile.length_m:.0f} m)")
        if k and s > positions[k - 1] - stocks[k - 1].length_m:
            raise InputError(path, f"trains[{k}]", f"starts at {s:.1f} m, overlapping the train ahead (its rear at {positions[k - 1] - stocks[k - 1].length_m:.1f} m)")
    for k, t in enumerate(exp.trains):  # a train that cannot start on a grade it can reach would stand there (as a timetable's, refused)
        weakest = plants[0] if k == 0 and lead_plant is not None else hardest_start(stocks[k], t.plant)
        reach = min(profile.length_m, positions[k] + max(weakest.max_speed_ms, t.speed_mps) * exp.duration_s)
        place = (lambda s: f"{s:.0f} m of the straight") if exp.track.straight is not None else None
        if stall := stall_problem(weakest, profile, positions[k], reach, place):
            plant = f" (the weakest {t.plant} plant of its uncertainty box)" if t.plant != "nominal" else ""
            raise InputError(path, f"trains[{k}].stock", f"infeasible: train {t.id}{plant} {stall} (within the run it can reach {reach:.0f} m of the track)")
        if k:  # a follower's separation is judged on its guaranteed brake (the run-health rule): it must hold it on every descent it can reach
            g_low = min(profile.gradient_range(positions[k] - stocks[k].length_m, reach)[0], 0.0)
            set_ = load_assumptions()
            try:
                guaranteed_decel(stocks[k], set_, "service", stocks[k].max_speed_kmh / 3.6, g_low)
            except InfeasibleBraking as exc:
                raise InputError(path, f"trains[{k}].stock", f"infeasible: train {t.id}: {exc} within its reach (to {reach:.0f} m) under the assumption set "
                                                            f"'{set_.name}'") from None
    stop_at = exp.leader.felez.stop_at_m if exp.leader.driver == "felez_mpc" and exp.leader.felez is not None else None
    if stop_at is not None and not positions[0] < stop_at <= profile.length_m:
        raise InputError(path, "leader.felez.stop_at_m", f"{stop_at:g} m is not ahead of the leader on the track (the leader starts at {positions[0]:.1f} m, "
                         f"the track ends at {profile.length_m:.1f} m)")
    trains = []
    n = len(exp.trains)
    for k, t in enumerate(exp.trains):
        v0 = t.speed_mps
        f0 = steady_force(plants[k], v0, profile, positions[k]) if v0 > 0 else 0.0
        target = t.target_speed_mps if t.target_speed_mps is not None else objective
        trains.append(OfflineTrain(t.id, plants[k], PlantState(positions[k], v0, f0, 0.0), driver if k == 0 else followers[k - 1].stack,
                                   nominal=stocks[k].params(), sends=k < n - 1, plan=plan if k == 0 else None, target_speed_mps=target))
    files = {f"param_{k}_{j}": p for k, f in enumerate(followers, start=1) for j, p in enumerate(f.files)}
    for k, t in enumerate(exp.trains):
        base = t.stock if isinstance(t.stock, str) else t.stock.base
        if is_path_spec(base):
            files[f"stock_{k}"] = Path(_rel(base, base_dir))
    return Setup(profile, stocks, trains, followers, channel_config(exp.channel, exp.step_s, seed), driver, files)


__all__ = ["PARAM_MODELS", "SUPERVISOR_MODELS", "cut_profile", "build_profile", "build_stock", "hardest_start", "plant_params", "FollowerSetup", "build_follower",
           "coupled_gap_m", "channel_config", "Setup", "leader_driver", "build_setup"]
