"""Braking of real trains in the worst case: the brake range of a train under an assumption set, the
deceleration it is guaranteed to reach (the train behind) and the hardest it may show (the train
ahead), with resistance and grade (``../shared/notes/safe-separation.md``; the separation model,
:mod:`vcsumo.signalling.separation`, builds its rules on them).

:func:`guaranteed_decel` and :func:`strongest_decel` take numpy arrays as well as floats; the
``*_of_floats`` twins are the per-step case of plain floats, the same operations in the same order
(the same numbers, ``tests/test_decel_scalar.py``), with each train's constants computed once."""

from __future__ import annotations

import numpy as np

from vcsumo.dynamics import running_resistance
from vcsumo.errors import InfeasibleBraking
from vcsumo.rolling_stock import RollingStock
from vcsumo.signalling.assumptions import AssumptionSet
from vcsumo.units import G


def brake_range(stock: RollingStock, assumptions: AssumptionSet, kind: str) -> tuple[float, float]:
    """(guaranteed, strongest) brake deceleration of a train's brake ``kind``, m/s² (brake force per
    mass, before resistance and grade): nominal ∓ the set's uncertainty, or the rolling stock's own
    box where it is wider (service brake)."""
    u = assumptions.braking_uncertainty
    if kind == "emergency":
        a = stock.emergency_brake_decel_mps2
        return a * (1.0 - u), a * (1.0 + u)
    if kind != "service":
        raise ValueError(f"brake kind '{kind}' (service or emergency)")
    a = stock.service_brake_decel_mps2
    low, high = a * (1.0 - u), a * (1.0 + u)
    if stock.uncertainty is not None:
        box = stock.uncertainty.service_brake_decel_mps2
        low, high = min(low, box.low), max(high, box.high)
    return low, high


def guaranteed_decel(stock: RollingStock, assumptions: AssumptionSet, kind: str, v_mps: float, grade_low: float = 0.0):
    """Deceleration the train is certain to reach, m/s² (numpy arrays of v and grade accepted).

    Brake at the bottom of the box (the service brake limited by the brake power, if the train has a
    limit, at the speed v: braking from v the limit only eases; the emergency brake is not), Davis A at the bottom of its box as the only
    resistance, the steepest descent where it brakes (``grade_low`` < 0, rise/run; an up-grade is not
    counted), all over M·ρ.
    """
    low, _ = brake_range(stock, assumptions, kind)
    m_high = stock.mass_kg if stock.uncertainty is None else stock.uncertainty.mass_kg.high
    a_res = stock.davis_a_n if stock.uncertainty is None else stock.uncertainty.davis_a_n.low
    brake = np.asarray(low, dtype=float)
    if stock.max_brake_power_w is not None and kind == "service":  # the emergency brake (friction) is not power-limited
        p_low = stock.max_brake_power_w if stock.uncertainty is None or stock.uncertainty.max_brake_power_w is None else stock.uncertainty.max_brake_power_w.low
        brake = np.minimum(brake, p_low / (m_high * np.maximum(v_mps, 0.1)))
    a = (brake + a_res / m_high + G * np.minimum(grade_low, 0.0)) / stock.rotating_mass_factor
    if np.any(a <= 0.0):
        raise InfeasibleBraking(f"{stock.name}: no guaranteed braking on a {1000 * float(np.min(grade_low)):.1f} ‰ descent")
    return float(a) if np.ndim(a) == 0 else a


def strongest_decel(stock: RollingStock, assumptions: AssumptionSet, kind: str, v_mps: float, grade_high: float = 0.0, tunnel_factor: float = 1.5):
    """The hardest deceleration the train may show, m/s² (numpy arrays of v and grade accepted).

    Brake at the top of the box (no power limit), its whole running resistance at v with the Davis
    coefficients at the top of their box and the largest tunnel factor, the steepest up-grade where it
    brakes (``grade_high`` > 0), over M alone (no rotating-mass factor).
    """
    _, high = brake_range(stock, assumptions, kind)
    p = stock.params()
    box = stock.uncertainty
    if box is not None:
        p = p.with_(davis_a_n=box.davis_a_n.high, davis_b_n_per_mps=box.davis_b_n_per_mps.high, davis_c_n_per_mps2=box.davis_c_n_per_mps2.high)
    m_low = stock.mass_kg if box is None else box.mass_kg.low
    a = high + running_resistance(p, np.asarray(v_mps, dtype=float), tunnel_factor) / m_low + G * np.maximum(grade_high, 0.0)
    return float(a) if np.ndim(a) == 0 else a


_TERMS: dict[tuple[int, int, str], tuple] = {}
"""(stock, assumption set, brake kind) -> the constants of :func:`guaranteed_decel` and
:func:`strongest_decel` for plain-float arguments (kept with the objects they are of, so an id is
never reused while its entry lives)."""


def _decel_terms(stock: RollingStock, assumptions: AssumptionSet, kind: str) -> tuple:
    key = (id(stock), id(assumptions), kind)
    hit = _TERMS.get(key)
    if hit is not None and hit[0] is stock and hit[1] is assumptions:
        return hit
    low, high = brake_range(stock, assumptions, kind)
    box = stock.uncertainty
    m_high = stock.mass_kg if box is None else box.mass_kg.high
    a_res = stock.davis_a_n if box is None else box.davis_a_n.low
    p_low = None
    if stock.max_brake_power_w is not None and kind == "service":
        p_low = stock.max_brake_power_w if box is None or box.max_brake_power_w is None else box.max_brake_power_w.low
    p = stock.params()
    if box is not None:
        p = p.with_(davis_a_n=box.davis_a_n.high, davis_b_n_per_mps=box.davis_b_n_per_mps.high, davis_c_n_per_mps2=box.davis_c_n_per_mps2.high)
    m_low = stock.mass_kg if box is None else box.mass_kg.low
    hit = _TERMS[key] = (stock, assumptions, float(low), m_high, a_res, p_low, stock.rotating_mass_factor, float(high),
                         p.davis_a_n, p.davis_b_n_per_mps, p.davis_c_n_per_mps2, m_low)
    return hit


def guaranteed_decel_of_floats(stock: RollingStock, assumptions: AssumptionSet, kind: str, v_mps: float, grade_low: float) -> float:
    """:func:`guaranteed_decel` of plain floats: the same operations in the same order, without numpy."""
    _, _, low, m_high, a_res, p_low, rho, *_ = _decel_terms(stock, assumptions, kind)
    brake = low
    if p_low is not None:
        brake = min(brake, p_low / (m_high * max(v_mps, 0.1)))
    a = (brake + a_res / m_high + G * min(grade_low, 0.0)) / rho
    if a <= 0.0:
        raise InfeasibleBraking(f"{stock.name}: no guaranteed braking on a {1000 * grade_low:.1f} ‰ descent")
    return a


def strongest_decel_of_floats(stock: RollingStock, assumptions: AssumptionSet, kind: str, v_mps: float, grade_high: float, tunnel_factor: float) -> float:
    """:func:`strongest_decel` of plain floats: the same operations in the same order, without numpy."""
    *_, high, d_a, d_b, d_c, m_low = _decel_terms(stock, assumptions, kind)
    return high + (d_a + d_b * v_mps + tunnel_factor * d_c * v_mps * v_mps) / m_low + G * max(grade_high, 0.0)
