"""Named assumption sets of the separation model: every number a safety case rests on, in a file.

An assumption set (``vcsumo/data/assumptions/<name>.yaml``, or any path) states how the worst case
of :mod:`vcsumo.signalling.separation` is built, the same for every regime (FBS, MB, VC) and every
safety layer (VC guard, CBF distance, run-health monitor, analytic headways):

* how uncertain braking is (the follower brakes at the bottom of the box, the leader at the top);
* how late the follower reacts (detection and reaction, brake build-up, the age of the newest
  train-to-train message it may rely on, the period of the position reports);
* how uncertain positions are (odometry error of each train) and the margin kept behind the
  leader's rear; the overlap beyond a fixed-block signal; ETCS fixed times;
* which brake the safe separation of the absolute-braking rules (FBS, MB) is certified with: the
  service brake, or the emergency brake as the reserve behind the service-brake approach.  Trains
  are driven on the service brake either way (ETCS: the service-brake curves lie before the
  emergency-brake intervention), so this brake changes the certified margin, not the running or
  the headways.

Every results folder records the set it ran under (its name and its full content in ``meta.json``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field

from vcsumo.config import StrictModel, is_file, load_model
from vcsumo.errors import InputError
from vcsumo.line import project_root

DEFAULT_ASSUMPTIONS = "etcs_typical"


class AssumptionSet(StrictModel):
    """The worst case every separation rule must survive (see ``notes`` in each shipped file)."""

    name: str = Field(pattern=r"^[a-z0-9_]+$", description="Identifier (the file name without .yaml)")
    title: str = Field(default="", description="Human-readable name")
    notes: str = Field(default="", description="Where the numbers come from and what they leave out")
    sources: dict[str, str] = Field(default_factory=dict, description="Source key -> citation")
    braking_uncertainty: float = Field(
        ge=0.0, le=0.5,
        description="Relative half-width of every brake deceleration, - (0.10 = ±10 %): the follower is guaranteed "
                    "(1 − u)·a, the leader may reach (1 + u)·a; a rolling-stock box that is wider wins",
    )
    reaction_time_s: float = Field(ge=0.0, le=10.0, description="Detection and reaction of the follower's protection (ATP/ATO), s")
    brake_build_up_s: float = Field(
        ge=0.0, le=20.0,
        description="Time for the brake to build up to full force, s; counted as an equivalent dead time of half of it",
    )
    t2t_delay_bound_s: float = Field(
        ge=0.0, le=30.0,
        description="VC: age of the newest train-to-train message the relative-braking rule relies on (T^max), s; "
                    "the guard uses the true age of what it holds, this bound sets the analytic spacing",
    )
    position_report_period_s: float = Field(
        ge=0.0, le=60.0,
        description="MB: period of the leader's position reports, s; the movement authority ends at the rear as "
                    "of the last report",
    )
    position_error_m: float = Field(ge=0.0, le=500.0, description="Odometry error of each train, m (both trains: counted twice)")
    safety_margin_m: float = Field(ge=0.0, le=2000.0, description="Margin kept behind the leader's (confirmed) rear end, m")
    overlap_m: float = Field(ge=0.0, le=2000.0, description="FBS: length beyond a signal that must be clear before the signal behind it clears, m")
    fixed_time_s: float = Field(default=0.0, ge=0.0, le=120.0, description="ETCS fixed times (route setting, MA transmission, reaction), s; lengthen every headway")
    absolute_braking: Literal["service", "emergency"] = Field(
        default="service",
        description="Brake the safe separation of the absolute-braking rules (FBS, MB) is certified with: the run-health "
                    "check of every FBS/MB train and VC convoy leader needs, behind the true rear ahead, the margin, both "
                    "position errors and its guaranteed stopping distance on this brake after the dead time. Trains are "
                    "driven on the guaranteed service brake whatever this says (the approach to the end of authority and of "
                    "the track, stops, speed restrictions, and so the analytic headways): 'emergency' counts the emergency "
                    "brake as the reserve behind that approach; it changes no running and no headway",
    )
    relative_braking: Literal["emergency", "service"] = Field(
        default="emergency",
        description="Brake of both trains in the VC relative-braking rule (the leader's strongest, the follower's guaranteed)",
    )
    speed_tolerance_kmh: float = Field(default=2.0, ge=0.0, le=20.0, description="Overspeed counted above the permitted speed plus this, km/h")

    @property
    def dead_time_s(self) -> float:
        """Equivalent dead time of the follower before full braking: reaction + half the build-up, s."""
        return self.reaction_time_s + 0.5 * self.brake_build_up_s

    @property
    def position_uncertainty_m(self) -> float:
        """Position error of both trains, m."""
        return 2.0 * self.position_error_m

    def record(self) -> dict:
        """The set as recorded in a results folder's meta.json."""
        return self.model_dump(mode="json")


def assumptions_dir() -> Path:
    return project_root() / "assumptions"


def shipped_assumptions() -> list[str]:
    return sorted(p.stem for p in assumptions_dir().glob("*.yaml"))


def load_assumptions(spec: str | Path | None = None, field: str = "--assumptions") -> AssumptionSet:
    """An assumption set by shipped name (default ``etcs_typical``) or by path to a YAML file."""
    spec = spec or DEFAULT_ASSUMPTIONS
    path = Path(spec)
    if path.suffix not in (".yaml", ".yml"):
        path = assumptions_dir() / f"{spec}.yaml"
        if not is_file(path):
            raise InputError(None, field, f"unknown assumption set '{spec}' (shipped: {', '.join(shipped_assumptions())}; or a path to a .yaml file)")
    elif not is_file(path):
        raise InputError(None, field, f"assumption file '{spec}' not found")
    return load_model(AssumptionSet, path)
