"""The offline convoy experiment file (``vcsumo experiment FILE.yaml``): its strict model and loader.

An experiment file describes one offline closed-loop run of a convoy (:func:`vcsumo.sim.offline.run_convoy`):
the trains (rolling stock, possibly with inline overrides, initial state, the plant's parameters),
the track, the leader's driver (speed schedule, events), each follower's controller stack by
registry name and parameter files, the train-to-train channel, step, duration, seeds and what to
measure.  ``variants`` name changes of the file (dotted paths, e.g. ``trains.1.overrides.delay_estimator``)
that are run beside it.  Every path inside the file is relative to the file's folder.  Every
problem is one :class:`~vcsumo.errors.InputError` naming the file and the field.

Shipped files: ``vcsumo/data/studies/experiments/*.yaml`` (the paper reproductions).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, model_validator

from vcsumo.config import FieldProblem, StrictModel, is_file, parse_model, read_yaml, validation_error
from vcsumo.errors import InputError
from vcsumo.line import project_root

NAME = r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,59}$"


class StockSpec(StrictModel):
    """A rolling stock with inline overrides (e.g. the authors' 490 t / 540 t trains)."""

    base: str = Field(description="Shipped rolling-stock name or path to its YAML file (relative to the experiment file)")
    length_m: float | None = Field(default=None, ge=10, le=1500, description="Train length, m (10–1,500)")
    mass_kg: float | None = Field(default=None, gt=0, le=5e7, description="Mass, kg")
    davis_a_n: float | None = Field(default=None, ge=0, le=1e6, description="Davis A, N")
    davis_b_n_per_mps: float | None = Field(default=None, ge=0, le=1e5, description="Davis B, N/(m/s)")
    davis_c_n_per_mps2: float | None = Field(default=None, ge=0, le=1e3, description="Davis C, N/(m/s)²")
    max_traction_n: float | None = Field(default=None, gt=0, le=1e7, description="Largest traction force, N")
    max_power_w: float | None = Field(default=None, gt=0, le=1e8, description="Largest traction power, W")
    service_brake_decel_mps2: float | None = Field(default=None, gt=0, le=3, description="Service braking deceleration (force limit / mass), m/s²")
    emergency_brake_decel_mps2: float | None = Field(default=None, gt=0, le=5, description="Emergency braking deceleration, m/s²")
    max_speed_kmh: float | None = Field(default=None, ge=10, le=600, description="Largest speed, km/h")
    uncertainty_pct: float | None = Field(default=None, ge=0, le=50, description="Replace the uncertainty box by ±this % on mass and Davis A, B, C (the other parameters exact), % (0–50)")


class TrainSpec(StrictModel):
    """One train of the convoy (the first is the leader)."""

    id: str = Field(pattern=NAME, description="Train id (1–60 letters, digits, _ . -)")
    stock: str | StockSpec = Field(description="Rolling stock: a shipped name, a path, or a base with overrides")
    position_m: float | None = Field(default=None, ge=0, le=2e6, description="Front position on the track at t = 0, m")
    gap_m: float | Literal["coupled"] | None = Field(default=None, description="Front-to-rear gap to the train ahead at t = 0, m (0–100 km), or 'coupled': on the follower's own reference (cruise: z_τ2 of eq. 27; other controllers: their coupled spacing, never inside their CBF's barrier or their guard's safe separation)")
    speed_mps: float = Field(default=0.0, ge=0, le=170, description="Speed at t = 0, m/s (0–170)")
    plant: Literal["nominal", "sampled", "corner"] = Field(default="nominal", description="The plant's true parameters: the nominal ones, drawn uniformly in the uncertainty box, or at a random corner of it (seeded)")
    controller: str | None = Field(default=None, description="Followers: registered controller stack NAME[:PARAMS] (e.g. cbf-cruise, mpc:mpc_felez2019)")
    params: str | None = Field(default=None, description="The nominal controller's parameter file (shipped name or path)")
    supervisor_params: str | None = Field(default=None, description="The supervisor's parameter file (shipped name or path)")
    overrides: dict[str, Any] = Field(default_factory=dict, description="Fields of the nominal controller's parameters that replace the file's (validated like the file)")
    supervisor_overrides: dict[str, Any] = Field(default_factory=dict, description="Fields of the supervisor's parameters that replace the file's")
    horizon_steps: int | None = Field(default=None, ge=1, le=2000, description="Prediction horizon N of the nominal controller, steps of its own step (cruise: H = N·ΔT^mpc; mpc: N_p)")
    guard: bool = Field(default=True, description="Wrap the follower in the separation guard (false: the paper's own architecture only)")
    control_period_s: float | None = Field(default=None, gt=0, le=60, description="Period of the nominal controller, s (none: every step)")
    target_speed_mps: float | None = Field(default=None, gt=0, le=170, description="Objective speed the train's controller sees, m/s")

    @model_validator(mode="after")
    def _gap_range(self) -> "TrainSpec":
        if isinstance(self.gap_m, float) and not 0.0 <= self.gap_m <= 1e5:
            raise FieldProblem("gap_m", f"{self.gap_m} m is outside 0–100,000 m")
        if self.position_m is not None and self.gap_m is not None:
            raise FieldProblem("gap_m", "give position_m or gap_m, not both")
        return self


class GradePoint(StrictModel):
    """A constant gradient from a position on (until the next point)."""

    from_m: float = Field(ge=0, le=2e6, description="Start of the gradient, m from the start of the track")
    permille: float = Field(ge=-60, le=60, description="Gradient, ‰ (positive rising in the direction of travel; −60 to 60)")


class StraightTrack(StrictModel):
    """A straight track of one's own."""

    length_m: float = Field(ge=100, le=2e6, description="Length, m (100 m–2,000 km)")
    speed_limit_mps: float = Field(ge=1, le=170, description="Line speed limit, m/s (1–170)")
    grades: list[GradePoint] = Field(default_factory=list, description="Gradient profile (level where none is given)")

    @model_validator(mode="after")
    def _grades_on_track(self) -> "StraightTrack":
        for k, g in enumerate(self.grades):
            if g.from_m >= self.length_m:
                raise FieldProblem(f"grades.{k}.from_m", f"{g.from_m:g} m is beyond the end of the track ({self.length_m:g} m)")
        return self


class LineTrack(StrictModel):
    """A shipped (or own) line's main track over a km range."""

    line: str = Field(description="Line name or path to its line.yaml (relative to the experiment file)")
    track: str = Field(default="main", description="Track of the line")
    direction: Literal["up", "down"] = Field(default="up", description="Direction of travel (up: increasing km)")
    km_from: float | None = Field(default=None, description="Start of the stretch, km of the line (none: the track's start)")
    km_to: float | None = Field(default=None, description="End of the stretch, km (none: the track's end)")


class TrackSpec(StrictModel):
    """The track: exactly one of ``straight`` and ``line``."""

    straight: StraightTrack | None = None
    line: LineTrack | None = None
    why: str = Field(default="", description="Why this track (e.g. long enough for the paper's schedule)")

    @model_validator(mode="after")
    def _one(self) -> "TrackSpec":
        if (self.straight is None) == (self.line is None):
            raise ValueError("give exactly one of straight and line")
        return self


class LeaderEvent(StrictModel):
    """Something the leader does: a full emergency brake (at a time or a position) or a new target speed."""

    action: Literal["emergency_brake", "speed"] = Field(description="emergency_brake (held to the end) or speed (a new target speed)")
    at_s: float | None = Field(default=None, ge=0, le=864000, description="Time of the event, s")
    at_m: float | None = Field(default=None, ge=0, le=2e6, description="Emergency brake once the leader's front reaches this position on the track, m")
    at_km: float | None = Field(default=None, ge=-1e5, le=1e5, description="Emergency brake once the leader's front reaches this km (of the line; of the straight from its start), km")
    speed_mps: float | None = Field(default=None, ge=0, le=170, description="The new target speed (action speed), m/s")

    @model_validator(mode="after")
    def _consistent(self) -> "LeaderEvent":
        if sum(x is not None for x in (self.at_s, self.at_m, self.at_km)) != 1:
            raise ValueError("give exactly one of at_s, at_m and at_km")
        if self.action == "speed" and (self.speed_mps is None or self.at_s is None):
            raise ValueError("a speed event needs at_s and speed_mps")
        if self.action == "emergency_brake" and self.speed_mps is not None:
            raise FieldProblem("speed_mps", "an emergency brake has no speed")
        return self


class LeaderMPCSpec(StrictModel):
    """The leader's speed-tracking MPC on its nominal model (Terlizzi §VI-D: "any valid MPC")."""

    horizon_steps: int = Field(default=50, ge=2, le=2000, description="Horizon N, steps")
    step_s: float = Field(default=0.24, ge=0.01, le=5, description="Step of its prediction, s")
    blocks: int = Field(default=12, ge=1, le=200, description="Piecewise-constant input moves over the horizon")
    speed_weight_per_mps2: float = Field(default=10.0, ge=0, description="Weight of the speed error, 1/(m/s)²")
    force_weight_per_kn2: float = Field(default=1e-4, ge=0, description="Weight of the force, 1/kN²")
    replan_period_s: float = Field(default=1.0, gt=0, le=60, description="Re-plan at every packet it sends and at least this often, s")
    robust_plan: bool = Field(default=True, description="Send its robust planned trajectory (RLP under the force plan, eq. 12) with each packet")


class FelezLeaderSpec(StrictModel):
    """The leader NMPC of Felez et al. (2019), eq. 11, with its DP terminal set ending at a stop."""

    params: str = Field(default="mpc_felez2019", description="MPC parameter file (shipped name or path)")
    horizon_steps: int | None = Field(default=None, ge=2, le=2000, description="Its horizon N_p, steps (none: the parameter file's)")
    stop_at_m: float | None = Field(default=None, ge=0, le=2e6, description="Where the leader stops (end of its movement authority), m (none: the track's end)")
    braking: Literal["planned-emergency", "service", "unannounced-emergency"] = Field(
        default="planned-emergency", description="planned-emergency: its NMPC plans the stop with the emergency brake (a^l in total, no power limit) and sends it; "
        "service: the same with the service brake; unannounced-emergency: it brakes at a^l from the point it must, without having announced it")


class LeaderSpec(StrictModel):
    """The leader's driver."""

    driver: Literal["speed_tracker", "speed_mpc", "felez_mpc"] = Field(default="speed_tracker", description="speed_tracker (P law on the schedule), speed_mpc (its own MPC on the schedule), felez_mpc (Felez eq. 11)")
    schedule: list[tuple[float, float]] = Field(default_factory=list, description="Target speed: (time s, speed m/s) points")
    schedule_kind: Literal["steps", "linear"] = Field(default="steps", description="steps: each speed holds from its time on; linear: interpolated")
    gain_per_s: float = Field(default=0.5, gt=0, le=20, description="Gain of the P speed tracker, 1/s")
    mpc: LeaderMPCSpec = Field(default_factory=LeaderMPCSpec)
    felez: FelezLeaderSpec = Field(default_factory=FelezLeaderSpec)
    events: list[LeaderEvent] = Field(default_factory=list)

    @model_validator(mode="after")
    def _schedule(self) -> "LeaderSpec":
        ts = [t for t, _ in self.schedule]
        if any(b <= a for a, b in zip(ts, ts[1:])):
            raise FieldProblem("schedule", "times must increase")
        if any(not (0 <= t <= 864000 and 0 <= v <= 170) for t, v in self.schedule):
            raise FieldProblem("schedule", "times 0–864,000 s and speeds 0–170 m/s")
        if self.driver != "felez_mpc" and not self.schedule and not any(e.action == "speed" for e in self.events):
            raise FieldProblem("schedule", f"the {self.driver} driver needs a speed schedule")
        return self


class TimeWindow(StrictModel):
    start_s: float = Field(ge=0, le=864000, description="Start, s")
    end_s: float = Field(ge=0, le=864000, description="End, s")

    @model_validator(mode="after")
    def _ordered(self) -> "TimeWindow":
        if self.end_s <= self.start_s:
            raise FieldProblem("end_s", "must be after start_s")
        return self


class ChannelWindow(TimeWindow):
    """A degradation: in the window, messages sent see another delay or loss."""

    exp_rate_per_s: float | None = Field(default=None, gt=0, le=1e4, description="Rate of the exponential delay in place of the channel's, 1/s")
    extra_delay_s: float = Field(default=0.0, ge=0, le=3600, description="Extra constant delay, s")
    extra_mean_s: float = Field(default=0.0, ge=0, le=3600, description="Mean of an extra exponential delay, s")
    loss_probability: float | None = Field(default=None, ge=0, le=1, description="Loss probability in place of the channel's (none: the channel's)")


class ChannelSpec(StrictModel):
    """The train-to-train channel: every train sends every period; delay = constant + Exp(rate)."""

    period_s: float = Field(ge=0.01, le=60, description="Sending period, s")
    delay_s: float = Field(default=0.0, ge=0, le=3600, description="Constant (minimum) delay, s")
    exp_rate_per_s: float | None = Field(default=None, gt=0, le=1e4, description="Rate λ of the exponential part of the delay (mean 1/λ), 1/s (none: constant delay)")
    loss_probability: float = Field(default=0.0, ge=0, le=1, description="Independent loss probability per message")
    degradations: list[ChannelWindow] = Field(default_factory=list)
    outages: list[TimeWindow] = Field(default_factory=list, description="Windows in which nothing sent or due is delivered")


class GapWindow(StrictModel):
    """Where the gaps are measured: a time window, optionally where both trains run at a speed."""

    name: str = Field(pattern=NAME, description="Name of the window in the measurements table")
    from_s: float = Field(default=0.0, ge=0, description="Start, s")
    to_s: float | None = Field(default=None, ge=0, description="End, s (none: the end of the run)")
    speed_mps: float | None = Field(default=None, ge=0, le=170, description="Only where the leader and the follower are within tolerance_mps of this speed, m/s")
    tolerance_mps: float = Field(default=0.5, gt=0, le=20, description="Speed tolerance, m/s")
    min_hold_s: float = Field(default=0.0, ge=0, description="Only stretches at that speed lasting at least this long, s")

    @model_validator(mode="after")
    def _ordered(self) -> "GapWindow":
        if self.to_s is not None and self.to_s <= self.from_s:
            raise FieldProblem("to_s", f"{self.to_s:g} s must be after from_s ({self.from_s:g} s)")
        return self


class StopSpec(StrictModel):
    """Measure the leader's stop: brake onset, stop delays, gaps at the onset and at rest."""

    onset_speed_mps: float | None = Field(default=None, gt=0, le=170, description="Brake onset: the last time the leader ran at ≥ this − 0.05 m/s (none: its emergency brake, else the last time it was not braking)")


class MeasurementSpec(StrictModel):
    gap_windows: list[GapWindow] = Field(default_factory=list)
    stop: StopSpec | None = Field(default=None, description="Measure the leader's stop (none: not)")


class PlantSpec(StrictModel):
    lag: bool = Field(default=True, description="Apply the rolling stock's force lag")
    jerk: bool = Field(default=True, description="Apply the rolling stock's jerk limit")
    emergency_brake: bool = Field(default=True, description="An emergency command brakes with the emergency brake (false: the service envelope only, as the papers' own simulations)")


class VariantSpec(StrictModel):
    name: str = Field(pattern=NAME)
    notes: str = ""
    set: dict[str, Any] = Field(description="Dotted paths into this file (list items by index) and their new values")


class Experiment(StrictModel):
    """An offline convoy experiment (the module doc)."""

    name: str = Field(pattern=NAME, description="Name of the experiment")
    title: str = ""
    notes: str = ""
    sources: dict[str, str] = Field(default_factory=dict)
    label: str = Field(default="default", pattern=NAME, description="Name of the run this file describes (beside its variants)")
    step_s: float = Field(ge=0.001, le=10, description="Integration and control step, s")
    duration_s: float = Field(gt=0, le=864000, description="Simulated time, s")
    seeds: list[Annotated[int, Field(ge=0, le=2**32 - 1)]] = Field(default_factory=lambda: [1], min_length=1, max_length=1000,
                                                                  description="One run per seed, 0–2³²−1 (plants drawn in the box and the channel)")
    record_every: int = Field(default=1, ge=1, le=100000, description="Record every k-th step in trajectories.csv (plus every packet and emergency step)")
    stop_when_at_rest_s: float | None = Field(default=None, gt=0, le=86400, description="End the run once every train has been at rest this long after moving, s")
    known_at_start: bool = Field(default=False, description="Followers know their predecessor's state at t = 0")
    plant: PlantSpec = Field(default_factory=PlantSpec)
    track: TrackSpec
    trains: list[TrainSpec] = Field(min_length=1, max_length=50)
    leader: LeaderSpec
    channel: ChannelSpec | None = Field(default=None, description="Train-to-train channel (none: ideal, every step)")
    measurements: MeasurementSpec = Field(default_factory=MeasurementSpec)
    variants: list[VariantSpec] = Field(default_factory=list)

    @model_validator(mode="after")
    def _trains(self) -> "Experiment":
        ids = [t.id for t in self.trains]
        for k, tid in enumerate(ids):
            if tid in ids[:k]:
                raise FieldProblem(f"trains.{k}.id", f"duplicate train id '{tid}'")
        lead = self.trains[0]
        if self.leader.driver == "felez_mpc" and lead.plant != "nominal":
            raise FieldProblem("trains.0.plant", "the felez_mpc leader's plant is its stock with the brake of leader.felez.braking: nominal only")
        if lead.controller is not None or lead.gap_m is not None:
            raise FieldProblem("trains.0", "the first train is the leader: it has no controller or gap_m (see leader)")
        for k, t in enumerate(self.trains[1:], start=1):
            if t.controller is None:
                raise FieldProblem(f"trains.{k}.controller", "a follower needs a controller stack")
            if t.position_m is None and t.gap_m is None:
                raise FieldProblem(f"trains.{k}", "give position_m or gap_m")
        for k, w in enumerate(self.measurements.gap_windows):
            if w.from_s >= self.duration_s:
                raise FieldProblem(f"measurements.gap_windows.{k}.from_s", f"{w.from_s:g} s is not within the run (duration_s {self.duration_s:g} s)")
        for k, e in enumerate(self.leader.events):
            if e.at_s is not None and e.at_s >= self.duration_s:
                raise FieldProblem(f"leader.events.{k}.at_s", f"{e.at_s:g} s is not within the run (duration_s {self.duration_s:g} s)")
        names = [v.name for v in self.variants]
        for k, n in enumerate(names):
            if n in names[:k] or n == self.label:
                raise FieldProblem(f"variants.{k}.name", f"duplicate run name '{n}'")
        return self


def experiments_dir() -> Path:
    """The shipped experiment files (``project_root()/studies/experiments``)."""
    return project_root() / "studies" / "experiments"


def shipped_experiments() -> list[str]:
    return sorted(p.stem for p in experiments_dir().glob("*.yaml"))


def resolve_experiment(spec: str | Path) -> Path:
    """An experiment file by path, or a shipped experiment by name."""
    p = Path(spec)
    if p.suffix in (".yaml", ".yml") or is_file(p):
        if not is_file(p):
            raise InputError(p, None, "file not found")
        return p
    cand = experiments_dir() / f"{spec}.yaml"
    if not is_file(cand):
        raise InputError(None, "FILE", f"unknown experiment '{spec}' (shipped: {', '.join(shipped_experiments())}; or a path to a .yaml file)")
    return cand


def set_path(data: dict, dotted: str, value: Any) -> None:
    """Set ``value`` at a dotted path of nested mappings/lists (list items by index); ValueError if it does not exist."""
    parts = dotted.split(".")
    node: Any = data
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise ValueError(f"'{'.'.join(parts[:i + 1])}': no list item {part}")
            key: Any = int(part)
        elif isinstance(node, dict):
            key = part
            if not last and key not in node:
                node[key] = {}
        else:
            raise ValueError(f"'{'.'.join(parts[:i])}' is not a mapping or a list")
        if last:
            node[key] = copy.deepcopy(value)
        else:
            node = node[key]


def runs_of(data: dict, path: str | Path | None) -> list[tuple[str, Experiment]]:
    """(run name, experiment) for the file's own run and every variant, each validated."""
    base = parse_model(Experiment, data, path)
    runs = [(base.label, base)]
    for k, v in enumerate(base.variants):
        raw = copy.deepcopy(data)
        raw.pop("variants", None)
        for key, value in v.set.items():
            try:
                set_path(raw, key, value)
            except ValueError as exc:
                raise InputError(path, f"variants[{k}].set.{key}", str(exc)) from None
        raw["label"] = v.name
        try:
            runs.append((v.name, Experiment.model_validate(raw)))
        except ValidationError as exc:
            err = validation_error(exc, None, Experiment)
            raise InputError(path, f"variants[{k}] ({v.name}): {err.field}" if err.field else f"variants[{k}] ({v.name})", err.message) from None
    return runs


def load_experiment(spec: str | Path) -> tuple[Path, dict, list[tuple[str, Experiment]]]:
    """Read an experiment file (path or shipped name): (its path, the raw mapping, its runs)."""
    path = resolve_experiment(spec)
    data = read_yaml(path)
    runs = runs_of(data, path)
    return path, data, runs


__all__ = [
    "StockSpec", "TrainSpec", "GradePoint", "StraightTrack", "LineTrack", "TrackSpec", "LeaderEvent", "LeaderMPCSpec", "FelezLeaderSpec", "LeaderSpec",
    "TimeWindow", "ChannelWindow", "ChannelSpec", "GapWindow", "StopSpec", "MeasurementSpec", "PlantSpec", "VariantSpec", "Experiment",
    "experiments_dir", "shipped_experiments", "resolve_experiment", "set_path", "runs_of", "load_experiment",
]
