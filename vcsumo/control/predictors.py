"""Preceding-train predictors of Felez, Kim & Borrelli (2019), §III-F, eq. 16–18.

A follower's NMPC (eq. 12) needs the predicted leader positions s̄^l_{k|t} and speeds v̄^l_{k|t},
k = t … t+N_p.  Three strategies:

* **SH** (short horizon, eq. 16): the leader communicates its plan; the follower propagates the
  leader model from the measured state with the leader's previous optimal inputs, shifted by one
  step, the last one repeated (:func:`predict_sh`), or — when it only receives the planned
  trajectory (:class:`~vcsumo.control.base.Message` ``plan_*``) — resamples that trajectory on its
  own horizon (:func:`predict_sh_from_plan`);
* **NP** (no prediction, eq. 17): communication lost; from the measured state the leader is
  assumed to brake at a^l until it stops (:func:`predict_np`);
* **MB** (moving block, eq. 18): the leader stands still at its last known position
  (:func:`predict_mb`).

All functions are pure numpy.  :func:`model_step` is the discrete train model shared with the
NMPC (eq. 6b with the force lag 1c), written so that it also accepts CasADi symbols.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vcsumo.dynamics import TrainParams, acceleration

STRATEGIES = ("SH", "NP", "MB")


# -------------------------------------------------------------------------------------------
# Discrete model shared with the NMPC


def lag_alpha(params: TrainParams, dt: float) -> float:
    """α = min(1, Δt/τ): explicit-Euler factor of the force lag dF/dt = (u − F)/τ (eq. 1c)."""
    if params.traction_lag_s <= 0:
        return 1.0
    return min(1.0, dt / params.traction_lag_s)


def smooth_positive(x, eps: float):
    """½·(x + √(x² + ε²)): a smooth max(x, 0) (error ε/2 at 0, ε²/(4|x|) far from 0).

    Works on floats, numpy arrays and CasADi symbols (only +, *, ** are used).
    """
    return 0.5 * (x + (x * x + eps * eps) ** 0.5)


def model_step(params: TrainParams, s, v, F, u, dt: float, gradient=0.0, tunnel_factor=1.0, eps_mps: float = 0.01):
    """One step of the discrete model x(k+1) = f(x(k), u(k)) (eq. 6b, 7) with the lag of eq. 1c.

    F_{k+1} = F_k + α·(u_k − F_k);  v_{k+1} = max⁺(v_k + Δt·a(v_k, F_{k+1}));  s_{k+1} = s_k + Δt·v_k

    The force acting during the step is the lagged force at its end and speed cannot go
    negative (trains do not reverse) — both exactly as :class:`vcsumo.plant.TrainPlant`
    integrates eq. 1, so the prediction model and the offline plant coincide; max⁺ is smoothed
    (:func:`smooth_positive`, ε = ``eps_mps``) so that the NMPC has derivatives at standstill.
    Accepts floats, numpy arrays and CasADi symbols.
    """
    F_next = F + lag_alpha(params, dt) * (u - F)
    a = acceleration(params, v, F_next, gradient, tunnel_factor)
    v_next = smooth_positive(v + dt * a, eps_mps) if eps_mps > 0 else np.maximum(v + dt * a, 0.0)
    s_next = s + dt * v
    return s_next, v_next, F_next


# -------------------------------------------------------------------------------------------
# Predictions


@dataclass(frozen=True)
class LeaderPrediction:
    """Predicted leader trajectory on the follower's horizon, k = 0 … N (front positions)."""

    times_s: np.ndarray
    positions_m: np.ndarray
    speeds_mps: np.ndarray
    length_m: float
    strategy: str

    @property
    def rear_m(self) -> np.ndarray:
        """Predicted leader rear s̄^l − L (the follower's gap is rear − own front, eq. 8/12n)."""
        return self.positions_m - self.length_m

    @property
    def horizon(self) -> int:
        return len(self.positions_m) - 1


def predict_sh(params: TrainParams, s_meas_m: float, v_meas_mps: float, force_pred_n: float, u_prev_plan_n, dt: float, horizon: int,
               gradient_fn=None, tunnel_fn=None, eps_mps: float = 0.01) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 16: propagate the leader model from (s_t, v_t, F_{t|t−1}) with the previous plan's inputs.

    ``u_prev_plan_n`` is the leader's optimal input sequence computed at t−1,
    [u_{t−1|t−1}, u_{t|t−1}, …, u_{t+N−2|t−1}] (length ≥ 2).  The inputs used at t are
    ū_{k|t} = u_{k|t−1} for k = t … t+N−2 (16c) and ū_{t+N−1|t} = u_{t+N−2|t−1} (16d).  With no
    previous plan (t = 0) the inputs are zero.  ``gradient_fn``/``tunnel_fn`` map positions to the
    leader's gradient and tunnel factor (level open track if None).  Returns (s̄, v̄, F̄), k = 0 … N.
    """
    u_prev = np.zeros(horizon + 1) if u_prev_plan_n is None else np.asarray(u_prev_plan_n, dtype=float)
    ubar = np.empty(horizon)
    shifted = u_prev[1:horizon + 1] if len(u_prev) > 1 else np.zeros(0)
    ubar[: len(shifted)] = shifted  # (16c)
    if len(shifted) < horizon:
        ubar[len(shifted):] = shifted[-1] if len(shifted) else 0.0  # (16d): repeat the last input
    s = np.empty(horizon + 1)
    v = np.empty(horizon + 1)
    F = np.empty(horizon + 1)
    s[0], v[0], F[0] = s_meas_m, v_meas_mps, force_pred_n  # (16a)
    for k in range(horizon):  # (16b)
        g = 0.0 if gradient_fn is None else float(gradient_fn(s[k]))
        tf = 1.0 if tunnel_fn is None else float(tunnel_fn(s[k]))
        s[k + 1], v[k + 1], F[k + 1] = model_step(params, s[k], v[k], F[k], ubar[k], dt, g, tf, eps_mps)
    return s, v, F


def predict_sh_from_plan(plan_times_s, plan_positions_m, plan_speeds_mps, t0_s: float, dt: float, horizon: int,
                         measured: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 16 from a communicated trajectory: the leader's plan resampled at t0 + k·Δt.

    Under the nominal model the leader's plan computed at t−1 is exactly the propagation of
    eq. 16 (same inputs, same model), so resampling it is eq. 16.  Beyond the end of the plan the
    last planned acceleration is continued (16d repeats the last input), speed ≥ 0.  If a
    ``measured`` (position, speed) of the leader at t0 is given, it replaces k = 0 (16a) and the
    predicted positions are shifted by the measured position error.
    """
    T = np.asarray(plan_times_s, dtype=float)
    P = np.asarray(plan_positions_m, dtype=float)
    V = np.asarray(plan_speeds_mps, dtype=float)
    t = t0_s + dt * np.arange(horizon + 1)
    s = np.interp(t, T, P)
    v = np.interp(t, T, V)
    t_end, v_end = float(T[-1]), float(V[-1])
    if t[-1] > t_end + 1e-9:  # t increases: the times beyond the plan are a suffix, from j
        j = int(np.searchsorted(t, t_end + 1e-9, side="right"))
        acc = (v_end - float(V[-2])) / max(t_end - float(T[-2]), 1e-9) if len(T) >= 2 else 0.0
        tt = t[j:] - t_end
        if acc < 0:
            tt = np.minimum(tt, v_end / -acc if v_end > 0 else 0.0)
        v[j:] = np.maximum(v_end + acc * tt, 0.0)
        s[j:] = float(P[-1]) + v_end * tt + 0.5 * acc * tt * tt
    if measured is not None:  # s and v are new arrays (np.interp)
        s += measured[0] - s[0]
        v[0] = measured[1]
    return s, v


def predict_np(s_meas_m: float, v_meas_mps: float, a_leader_mps2: float, dt: float, horizon: int, literal: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 17: from the measured state the leader brakes at a^l (its maximum braking) until it stops.

    s̄_k = s̄_{k−1} + v̄_{k−1}·Δt − ½·a^l·Δt²,  v̄_k = max(v̄_{k−1} − a^l·Δt, 0)        (17b)

    Taken literally, 17b keeps subtracting ½·a^l·Δt² once v̄ = 0, i.e. a stopped leader would be
    predicted to roll backwards (0.6 cm per step for a^l = 1.25, Δt = 0.1).  By default the
    position update of the step in which the leader stops is the exact v̄²/(2a^l) and a stopped
    leader stays put; ``literal=True`` gives eq. 17b verbatim.
    """
    s = np.empty(horizon + 1)
    v = np.empty(horizon + 1)
    s[0], v[0] = s_meas_m, max(v_meas_mps, 0.0)  # (17a)
    a, h = float(a_leader_mps2), dt
    for k in range(1, horizon + 1):
        if literal or v[k - 1] >= a * h:
            s[k] = s[k - 1] + v[k - 1] * h - 0.5 * a * h * h
        else:
            s[k] = s[k - 1] + v[k - 1] * v[k - 1] / (2.0 * a)
        v[k] = max(v[k - 1] - a * h, 0.0)
    return s, v


def predict_mb(s_meas_m: float, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 18: the leader stands at its last known position for the whole horizon (moving block)."""
    return np.full(horizon + 1, float(s_meas_m)), np.zeros(horizon + 1)


def np_state_now(s_m: float, v_mps: float, a_leader_mps2: float, elapsed_s: float) -> tuple[float, float]:
    """Worst-case (eq. 17 continuous form) leader state ``elapsed_s`` after a report (s, v).

    Used when the NP predictor only has a time-stamped message instead of a fresh measurement.
    """
    if elapsed_s <= 0:
        return s_m, v_mps
    t_stop = v_mps / a_leader_mps2 if a_leader_mps2 > 0 else np.inf
    t = min(elapsed_s, t_stop)
    return s_m + v_mps * t - 0.5 * a_leader_mps2 * t * t, max(v_mps - a_leader_mps2 * t, 0.0)
