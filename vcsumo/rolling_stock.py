"""Rolling stock: one definition per train type, feeding both SUMO and vcsumo's own model.

A rolling-stock file (``networks/rolling_stock/<name>.yaml``) holds the physical parameters of a
train in SI units.  From it come

* :meth:`RollingStock.vtype_xml` — the SUMO vType (``carFollowModel="Rail"``,
  ``trainType="custom"``): mass, rotating-mass factor, power, traction, Davis resistance,
  service and emergency deceleration;
* :meth:`RollingStock.params` — the :class:`~vcsumo.dynamics.TrainParams` of the train-dynamics
  model (Felez et al. eq. 1–5; Terlizzi et al. eq. 5–6) used by the controllers, the safety
  supervisor and the offline running-time calculation;
* :meth:`RollingStock.uncertainty_box` — the parameter intervals of Terlizzi et al. eq. 7 used by
  the robust proxies.

so the plant and the prediction model cannot drift apart silently.
"""

from __future__ import annotations

import math
from pathlib import Path

from pydantic import Field, model_validator

from vcsumo.config import FieldProblem, StrictModel, is_file, load_model
from vcsumo.dynamics import TrainParams
from vcsumo.errors import InputError
from vcsumo.line import project_root
from vcsumo.units import kmh_to_ms


MAX_ACCEL_MPS2 = 3.0
"""Largest starting acceleration F_max/M accepted, m/s² (metros reach 1.3; adhesion caps it near 3)."""
MIN_POWER_W_PER_KG = 0.2
"""Smallest traction power per mass accepted, W/kg (= kW/t): heavy-haul ore trains run at ≈ 0.4 kW/t;
below 0.2 a train crawls (a power given in kW instead of W is 1,000 times too small)."""


class Interval(StrictModel):
    """A closed interval [low, high]."""

    low: float
    high: float

    @model_validator(mode="after")
    def _ordered(self) -> "Interval":
        if self.high < self.low:
            raise ValueError(f"interval high ({self.high}) is below low ({self.low})")
        return self


class UncertaintyBox(StrictModel):
    """Parameter intervals (Terlizzi et al. eq. 7).  Each must contain the nominal value."""

    mass_kg: Interval
    davis_a_n: Interval
    davis_b_n_per_mps: Interval
    davis_c_n_per_mps2: Interval
    max_accel_mps2: Interval = Field(description="a_dr interval, m/s² (traction force limit / mass)")
    service_brake_decel_mps2: Interval = Field(description="a_br interval, m/s²")
    max_power_w: Interval = Field(description="P_dr interval, W")
    max_brake_power_w: Interval | None = Field(default=None, description="P_br interval, W")

    @model_validator(mode="after")
    def _physical(self) -> "UncertaintyBox":
        """Every corner of the box is a train: positive mass, traction, braking and power, resistance not negative."""
        for key in ("mass_kg", "max_accel_mps2", "service_brake_decel_mps2", "max_power_w", "max_brake_power_w"):
            iv = getattr(self, key)
            if iv is not None and not (iv.low > 0 and math.isfinite(iv.high)):
                raise FieldProblem(f"{key}.low", f"the interval [{iv.low}, {iv.high}] must be positive and finite")
        for key in ("davis_a_n", "davis_b_n_per_mps", "davis_c_n_per_mps2"):
            iv = getattr(self, key)
            if not (iv.low >= 0 and math.isfinite(iv.high)):
                raise FieldProblem(f"{key}.low", f"the interval [{iv.low}, {iv.high}] must be finite and not negative")
        return self


class RollingStock(StrictModel):
    """A train type.  All fields SI; the unit is in every field name."""

    name: str = Field(pattern=r"^[a-z0-9_]+$", description="Identifier (file name without .yaml)")
    title: str = Field(default="", description="Human-readable name")
    notes: str = Field(default="", description="Assumptions and caveats")
    sources: dict[str, str] = Field(default_factory=dict, description="Source key -> citation")
    length_m: float = Field(ge=10, le=1500, description="Train length L, m (10–1,500: no vehicle is shorter than 10 m; 1,500 m is the longest freight train run in Europe)")
    mass_kg: float = Field(gt=0, le=5e7, description="Mass M, kg (up to 50,000 t, beyond the heaviest heavy-haul trains in service)")
    rotating_mass_factor: float = Field(default=1.0, ge=1.0, le=1.5, description="Rotating-mass (inertia) factor, -")
    max_speed_kmh: float = Field(ge=10, le=600, description="Maximum speed of the train, km/h (10–600: 600 km/h is above any wheel-rail record)")
    max_traction_n: float = Field(gt=0, le=1e7, description="Maximum tractive effort F_max = M·a_dr, N (eq. 4a); F_max/M at most 3 m/s² (see MAX_ACCEL_MPS2)")
    max_power_w: float = Field(gt=0, le=1e8, description="Maximum traction power P_dr, W (eq. 4b); up to 100 MW, five times the most powerful trainsets")
    davis_a_n: float = Field(ge=0, le=1e6, description="Davis A (rolling + bearing resistance), N (0–1 MN)")
    davis_b_n_per_mps: float = Field(ge=0, le=1e5, description="Davis B, N/(m/s) (0–100 kN/(m/s))")
    davis_c_n_per_mps2: float = Field(ge=0, le=1e3, description="Davis C (aerodynamic, open air), N/(m/s)² (0–1,000; long high-speed trains are near 10)")
    service_brake_decel_mps2: float = Field(gt=0, le=3, description="Service braking deceleration a_br, m/s²: braking-force limit M·a_br and the planning deceleration of SUMO and of blocking-time theory (0 < a ≤ 3 m/s²: adhesion limits service braking)")
    emergency_brake_decel_mps2: float = Field(gt=0, le=5, description="Emergency braking deceleration, m/s² (0 < a ≤ 5 m/s²: beyond wheel-rail adhesion even with track brakes)")
    max_brake_power_w: float | None = Field(default=None, gt=0, le=1e8, description="Maximum braking power P_br, W (eq. 4b), up to 100 MW; none = not limited")
    max_jerk_mps3: float | None = Field(default=None, gt=0, le=20, description="Maximum jerk j_max, m/s³ (eq. 4c), up to 20; none = not limited")
    traction_lag_s: float = Field(default=0.0, ge=0, le=5, description="First-order lag τ of the traction/brake force, s (eq. 1c)")
    uncertainty: UncertaintyBox | None = Field(default=None, description="Parameter intervals (Terlizzi eq. 7)")

    @model_validator(mode="after")
    def _consistent(self) -> "RollingStock":
        if self.max_traction_n / self.mass_kg > MAX_ACCEL_MPS2:
            raise FieldProblem("max_traction_n", f"max_traction_n / mass_kg = {self.max_traction_n / self.mass_kg:.3g} m/s² exceeds {MAX_ACCEL_MPS2:g} m/s² (no train accelerates faster)")
        if self.max_power_w / self.mass_kg < MIN_POWER_W_PER_KG:
            raise FieldProblem("max_power_w", f"max_power_w / mass_kg = {self.max_power_w / self.mass_kg:.3g} W/kg is below {MIN_POWER_W_PER_KG:g} W/kg "
                                              f"(the heaviest heavy-haul trains have about 0.4): the power is in W, not kW")
        if self.emergency_brake_decel_mps2 < self.service_brake_decel_mps2:
            raise FieldProblem("emergency_brake_decel_mps2", f"{self.emergency_brake_decel_mps2} m/s² must not be below service_brake_decel_mps2 ({self.service_brake_decel_mps2} m/s²)")
        box = self.uncertainty
        if box is not None:
            nominal = {
                "mass_kg": self.mass_kg,
                "davis_a_n": self.davis_a_n,
                "davis_b_n_per_mps": self.davis_b_n_per_mps,
                "davis_c_n_per_mps2": self.davis_c_n_per_mps2,
                "max_accel_mps2": self.max_traction_n / self.mass_kg,
                "service_brake_decel_mps2": self.service_brake_decel_mps2,
                "max_power_w": self.max_power_w,
            }
            for key, value in nominal.items():
                iv: Interval = getattr(box, key)
                if not iv.low - 1e-9 * max(1.0, abs(value)) <= value <= iv.high + 1e-9 * max(1.0, abs(value)):
                    raise FieldProblem(f"uncertainty.{key}", f"[{iv.low}, {iv.high}] does not contain the nominal value {value:g}")
        return self

    # ---------------------------------------------------------------------------------------
    @property
    def max_speed_ms(self) -> float:
        return kmh_to_ms(self.max_speed_kmh)

    def params(self) -> TrainParams:
        """The nominal parameters of the train-dynamics model (SI)."""
        return TrainParams(
            length_m=self.length_m,
            mass_kg=self.mass_kg,
            rotating_mass_factor=self.rotating_mass_factor,
            max_speed_ms=self.max_speed_ms,
            max_traction_n=self.max_traction_n,
            max_power_w=self.max_power_w,
            davis_a_n=self.davis_a_n,
            davis_b_n_per_mps=self.davis_b_n_per_mps,
            davis_c_n_per_mps2=self.davis_c_n_per_mps2,
            service_brake_decel_mps2=self.service_brake_decel_mps2,
            emergency_brake_decel_mps2=self.emergency_brake_decel_mps2,
            max_brake_power_w=self.max_brake_power_w if self.max_brake_power_w is not None else math.inf,
            max_jerk_mps3=self.max_jerk_mps3 if self.max_jerk_mps3 is not None else math.inf,
            traction_lag_s=self.traction_lag_s,
        )

    def uncertainty_box(self) -> UncertaintyBox:
        """The eq. 7 intervals; a train without them is treated as exactly known."""
        if self.uncertainty is not None:
            return self.uncertainty

        def point(v: float) -> Interval:
            return Interval(low=v, high=v)

        return UncertaintyBox(
            mass_kg=point(self.mass_kg),
            davis_a_n=point(self.davis_a_n),
            davis_b_n_per_mps=point(self.davis_b_n_per_mps),
            davis_c_n_per_mps2=point(self.davis_c_n_per_mps2),
            max_accel_mps2=point(self.max_traction_n / self.mass_kg),
            service_brake_decel_mps2=point(self.service_brake_decel_mps2),
            max_power_w=point(self.max_power_w),
            max_brake_power_w=None if self.max_brake_power_w is None else point(self.max_brake_power_w),
        )

    @property
    def sumo_emergency_decel_mps2(self) -> float:
        """The vType's ``emergencyDecel``, m/s²: SUMO warns of 'emergency braking' above it.  vcsumo
        drives a train at most with its emergency brake plus its running resistance (VC followers
        under speed mode 26), so the threshold is the hardest braking the train can physically show —
        its emergency brake + 20 % plus its resistance at top speed in a tunnel over its lightest mass
        — and a warning means braking no brake can give."""
        box = self.uncertainty
        m_low = self.mass_kg if box is None else box.mass_kg.low
        v = self.max_speed_ms
        r = self.davis_a_n + self.davis_b_n_per_mps * v + 1.5 * self.davis_c_n_per_mps2 * v * v
        return 1.2 * self.emergency_brake_decel_mps2 + r / m_low

    def vtype_id(self, tunnel_factor: float = 1.0) -> str:
        """SUMO vType id; tunnels use a variant with the aerodynamic term scaled (see vtype_xml)."""
        return self.name if abs(tunnel_factor - 1.0) < 1e-9 else f"{self.name}@tf{tunnel_factor:.2f}"

    def vtype_xml(self, tunnel_factor: float = 1.0, vclass: str = "rail", min_gap_m: float = 5.0) -> str:
        """The SUMO vType element (Rail model, custom train type).

        SUMO's units: maxPower kW, maxTraction kN, resCoef_* kN, kN/(m/s), kN/(m/s)²; mass kg.
        SUMO plans braking with ``decel`` and may brake up to ``decel + R(v)/(M·mf)``; see the
        README (physics) for the gaps between SUMO's Rail model and eq. 1–5.  ``min_gap_m``: the gap
        SUMO leaves behind a standing train (a convoy follower berths that far behind its leader in
        a shared platform; the runs set it to the separation model's margin and position errors).
        """
        return (
            f'<vType id="{self.vtype_id(tunnel_factor)}" vClass="{vclass}" carFollowModel="Rail" trainType="custom" '
            f'length="{self.length_m:.3f}" minGap="{min_gap_m:.3f}" maxSpeed="{self.max_speed_ms:.4f}" '
            f'mass="{self.mass_kg:.1f}" massFactor="{self.rotating_mass_factor:.4f}" '
            f'maxPower="{self.max_power_w / 1000:.4f}" maxTraction="{self.max_traction_n / 1000:.4f}" '
            f'resCoef_constant="{self.davis_a_n / 1000:.6f}" resCoef_linear="{self.davis_b_n_per_mps / 1000:.8f}" '
            f'resCoef_quadratic="{tunnel_factor * self.davis_c_n_per_mps2 / 1000:.8f}" '
            f'decel="{self.service_brake_decel_mps2:.4f}" emergencyDecel="{self.sumo_emergency_decel_mps2:.4f}" '
            f'speedFactor="1" speedDev="0"/>'
        )


    def vtype_variant(self, tag: str, true_params: TrainParams, max_speed_ms: float | None = None) -> "RollingStock":
        """This train with a SUMO vType of its own that carries drawn ("true") parameters.

        The copy is named ``<name>_<tag>`` (so each variant gets its own vType ids in a route file)
        and its model — every field vcsumo's controllers, supervisors, braking curves and run-health
        monitor read — stays this train's nominal one; only :meth:`vtype_xml` writes ``true_params``
        (mass, resistance, traction, power, service and emergency deceleration): SUMO then runs the
        train as it really is while everything on board plans with the nominal model and its box.
        ``max_speed_ms``: the vType's maxSpeed, the speed SUMO drives it at most (a train told to
        cruise below its top speed; None: its top speed).
        """
        if not tag or not all(c.isalnum() or c == "_" for c in tag) or tag.lower() != tag:
            raise ValueError(f"vType variant tag '{tag}' must be lower-case letters, digits and _")
        true = self.model_copy(update={
            "name": f"{self.name}_{tag}", "mass_kg": true_params.mass_kg, "davis_a_n": true_params.davis_a_n,
            "davis_b_n_per_mps": true_params.davis_b_n_per_mps, "davis_c_n_per_mps2": true_params.davis_c_n_per_mps2,
            "max_traction_n": true_params.max_traction_n, "max_power_w": true_params.max_power_w,
            "service_brake_decel_mps2": true_params.service_brake_decel_mps2,
            "emergency_brake_decel_mps2": max(true_params.emergency_brake_decel_mps2, true_params.service_brake_decel_mps2),
            **({} if max_speed_ms is None else {"max_speed_kmh": 3.6 * min(max_speed_ms, self.max_speed_ms)}),
        })
        return _VTypeVariant(**{**self.__dict__, "name": true.name}, true_stock=true)


class _VTypeVariant(RollingStock):
    """A rolling stock whose SUMO vType is another's (:meth:`RollingStock.vtype_variant`)."""

    true_stock: RollingStock = Field(description="The train as SUMO runs it (its vType)")

    def vtype_xml(self, tunnel_factor: float = 1.0, vclass: str = "rail", min_gap_m: float = 5.0) -> str:
        return self.true_stock.vtype_xml(tunnel_factor, vclass, min_gap_m)


def rolling_stock_dir() -> Path:
    return project_root() / "networks" / "rolling_stock"


def shipped_rolling_stock() -> list[str]:
    return sorted(p.stem for p in rolling_stock_dir().glob("*.yaml"))


def rolling_stock_path(spec: str | Path) -> Path:
    """The file of a train type named by shipped name (``etr1000``) or path; an unknown name or a
    missing file is an InputError without a file (the one who named it is to blame: the caller adds
    its file and field)."""
    path = Path(spec)
    if path.suffix not in (".yaml", ".yml"):
        path = rolling_stock_dir() / f"{spec}.yaml"
        if not is_file(path):
            raise InputError(None, "train", f"unknown train '{spec}' (shipped: {', '.join(shipped_rolling_stock())}; or give a path to a .yaml file)")
    elif not is_file(path):
        raise InputError(None, "train", f"train file '{spec}' not found")
    return path


def load_rolling_stock(spec: str | Path) -> RollingStock:
    """Load a train type by shipped name (``etr1000``) or by path to a YAML file."""
    path = rolling_stock_path(spec)
    stock = load_model(RollingStock, path)
    if path.parent.resolve() == rolling_stock_dir().resolve() and stock.name != path.stem:
        raise InputError(path, "name", f"name '{stock.name}' must match the file name '{path.stem}'")
    return stock
