"""The route as the robust proxies see it (Terlizzi, Liuzza & Glielmo 2024, eq. 12–13): worst-case
gradient and tunnel factor over a window ahead (σ_sup, σ_inf, ρ_inf, ρ_sup), and the exact
worst-case stopping points on the route's train-averaged gradient.

* :class:`RouteBounds` — the extrema over a window;
* :class:`GradeWindow` — their look-up along a :class:`~vcsumo.route_profile.RouteProfile`;
* :class:`StopIntegral` — stopping points by the energy balance on the train-averaged gradient.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from vcsumo.route_profile import RouteProfile
from vcsumo.units import G

# -------------------------------------------------------------------------------------------
# The route (σ_sup, σ_inf, ρ_inf, ρ_sup of eq. 12–13)


@dataclass(frozen=True)
class RouteBounds:
    """Worst-case route data over a window: equivalent gradient (rise/run) and tunnel factor."""

    grade_min: float
    grade_max: float
    tunnel_min: float
    tunnel_max: float


_LEVEL = RouteBounds(0.0, 0.0, 1.0, 1.0)


class GradeWindow:
    """Extrema of the route's equivalent gradient and tunnel factor over [s_from, s_to].

    Equivalent gradient = gradient + curve resistance as a gradient, so g·σ is the paper's
    F_e = g·σ + γ/ρ (eq. 5).  Positions outside the route take the first/last edge's values, as
    :class:`vcsumo.route_profile.RouteProfile` and the plant do.  ``profile=None`` is level open
    track.
    """

    def __init__(self, profile: RouteProfile | None):
        self.profile = profile
        if profile is not None:
            self._starts = np.asarray(profile.starts_m, dtype=float)
            self._grades = np.asarray(profile.gradients, dtype=float)
            self._tunnels = np.asarray(profile.tunnel_factors, dtype=float)
            self._starts_l = self._starts.tolist()
            self._grades_l = self._grades.tolist()
            self._tunnels_l = self._tunnels.tolist()
            self.global_bounds = RouteBounds(float(self._grades.min()), float(self._grades.max()), float(self._tunnels.min()), float(self._tunnels.max()))
        else:
            self.global_bounds = _LEVEL

    def bounds(self, s_from: float, s_to: float) -> RouteBounds:
        if self.profile is None:
            return _LEVEL
        n = len(self._starts_l)
        i0 = min(max(bisect_right(self._starts_l, s_from) - 1, 0), n - 1)
        i1 = min(max(bisect_right(self._starts_l, s_to) - 1, 0), n - 1)
        if i1 < i0:
            i0, i1 = i1, i0
        g = self._grades_l[i0 : i1 + 1]
        t = self._tunnels_l[i0 : i1 + 1]
        return RouteBounds(min(g), max(g), min(t), max(t))

    def lower_bounds(self, s_from: float, s_to: float) -> tuple[float, float]:
        """(grade_min, tunnel_min) of :meth:`bounds` without building a :class:`RouteBounds`."""
        if self.profile is None:
            return _LEVEL.grade_min, _LEVEL.tunnel_min
        starts = self._starts_l
        n = len(starts)
        i0 = min(max(bisect_right(starts, s_from) - 1, 0), n - 1)
        i1 = min(max(bisect_right(starts, s_to) - 1, 0), n - 1)
        if i1 < i0:
            i0, i1 = i1, i0
        return min(self._grades_l[i0 : i1 + 1]), min(self._tunnels_l[i0 : i1 + 1])

    def grades_at(self, s: np.ndarray) -> np.ndarray:
        """Point equivalent gradient at each position (vectorised; for prediction models)."""
        if self.profile is None:
            return np.zeros_like(np.asarray(s, dtype=float))
        idx = np.clip(np.searchsorted(self._starts, s, side="right") - 1, 0, len(self._starts) - 1)
        return self._grades[idx]

    def speed_limits_at(self, s: np.ndarray) -> np.ndarray:
        """Line speed limit at each position, m/s (vectorised)."""
        if self.profile is None:
            return np.full_like(np.asarray(s, dtype=float), np.inf)
        idx = np.clip(np.searchsorted(self._starts, s, side="right") - 1, 0, len(self._starts) - 1)
        return np.asarray(self.profile.speeds_ms, dtype=float)[idx]


class StopIntegral:
    """Worst-case stopping points on the route's train-averaged gradient (energy balance).

    A train of length L feels the gradient averaged over its length, G(x) = (1/L)∫_{x−L}^{x} σ
    (:meth:`RouteProfile.mean_gradient`, SUMO's slope), a continuous piecewise-linear function of
    the front position x.  If the train's deceleration from brake and resistance is bounded by a
    constant a (from below for a follower, from above for a leader), the energy balance
    d(v²/2)/dx = −(a + g·G(x)) bounds its speed along the track, and the stopping point is the
    first S ≥ x with

        a·(S − x) + g·(I(S) − I(x)) = v²/2,        I(x) = ∫ G.

    On a constant grade σ this is S = x + v²/(2(a + g·σ)) — exactly the v²/(2e) terms of eq. 15 —
    but it is continuous and increasing in (x, v) on any profile, unlike the worst grade over a
    window ahead (σ_sup/σ_inf of eq. 12–13), which jumps whenever a new grade enters the window.
    I is integrated exactly (G is linear between the breakpoints of σ and σ shifted by L).
    """

    def __init__(self, profile: RouteProfile | None, length_m: float):
        L = max(float(length_m), 1.0)
        self.length_m = L
        if profile is None:
            self.x = np.array([0.0])
            self.G = np.array([0.0])
            self.I = np.array([0.0])
            self._x_list = [0.0]
            self._G_list = [0.0]
            self._I_list = [0.0]
            self._n = 1
            return
        starts = np.asarray(profile.starts_m, dtype=float)
        sig = np.asarray(profile.gradients, dtype=float)
        # P(y) = ∫_0^y σ, σ = σ_0 before the route and σ_last after it (as RouteProfile/plant)
        ends = starts + np.asarray(profile.lengths_m, dtype=float)

        def P(y: np.ndarray) -> np.ndarray:
            y = np.asarray(y, dtype=float)
            out = np.zeros_like(y)
            before = y < starts[0]
            out[before] = sig[0] * (y[before] - starts[0])
            cum = np.concatenate(([0.0], np.cumsum(sig * (ends - starts))))
            idx = np.clip(np.searchsorted(starts, y, side="right") - 1, 0, len(starts) - 1)
            inside = ~before
            out[inside] = cum[idx[inside]] + sig[idx[inside]] * (y[inside] - starts[idx[inside]])
            return out

        bps = np.unique(np.concatenate((starts, starts + L, [starts[0] - L, ends[-1], ends[-1] + L])))
        G = (P(bps) - P(bps - L)) / L
        I = np.concatenate(([0.0], np.cumsum(0.5 * (G[1:] + G[:-1]) * np.diff(bps))))
        self.x, self.G, self.I = bps, G, I
        # plain lists: the per-step look-ups are scalar (bisect and float arithmetic)
        self._x_list = bps.tolist()
        self._G_list = G.tolist()
        self._I_list = I.tolist()
        self._n = len(self._x_list)

    def _seg(self, x: float) -> int:
        return min(max(bisect_right(self._x_list, x) - 1, 0), self._n - 1)

    def grade_at(self, x: float) -> float:
        """G(x), the train-averaged equivalent gradient at front position x."""
        xs, Gs = self._x_list, self._G_list
        n = self._n
        if n == 1 or x <= xs[0]:
            return Gs[0]
        k = bisect_right(xs, x) - 1  # ≥ 0 since x > xs[0]
        if k >= n - 1:
            return Gs[-1]
        return Gs[k] + (x - xs[k]) / (xs[k + 1] - xs[k]) * (Gs[k + 1] - Gs[k])

    def integral_at(self, x: float) -> float:
        """I(x) = ∫_{x_0}^{x} G (exact: G is linear between breakpoints)."""
        xs, Gs, Is = self._x_list, self._G_list, self._I_list
        if self._n == 1 or x <= xs[0]:
            return Gs[0] * (x - xs[0])
        k = bisect_right(xs, x) - 1
        h = x - xs[k]
        if k >= self._n - 1:
            return Is[-1] + Gs[-1] * h
        slope = (Gs[k + 1] - Gs[k]) / (xs[k + 1] - xs[k])
        return Is[k] + Gs[k] * h + 0.5 * slope * h * h

    def stop_point(self, x: float, v: float, a: float) -> float:
        """First S ≥ x with a·(S − x) + g·(I(S) − I(x)) ≥ v²/2; +inf if never reached."""
        if v <= 0.0:
            return x
        target = 0.5 * v * v
        xs, Gs = self._x_list, self._G_list
        n = self._n
        # G(x) (as grade_at) and the first breakpoint after x, with one bisection
        if x <= xs[0]:
            Ga = Gs[0]
            j = 0
        else:
            k = bisect_right(xs, x) - 1
            if k >= n - 1:
                k = n - 1
                Ga = Gs[-1]
            else:
                Ga = Gs[k] + (x - xs[k]) / (xs[k + 1] - xs[k]) * (Gs[k + 1] - Gs[k])
            j = k + 1
        # walk the linear pieces of G from x: on [xa, xb], a + g·G is linear, F is quadratic
        # (the decelerations a + g·G at the breakpoints are computed once and carried along)
        xa = x
        Fa = 0.0
        ra = a + G * Ga
        while True:
            if j >= n:  # beyond the last breakpoint: constant grade
                if ra <= 0:
                    return math.inf
                return xa + (target - Fa) / ra
            xb = xs[j]
            rb_ = a + G * Gs[j]
            if ra <= 0 or rb_ <= 0:  # energy balance not monotone here: careful scan
                return self._first_crossing(x, a, target, self.integral_at(x))
            h_seg = xb - xa
            Fb = Fa + 0.5 * (ra + rb_) * h_seg
            if Fb >= target:
                c2 = 0.5 * (rb_ - ra) / h_seg if h_seg > 0 else 0.0
                rhs = target - Fa
                if abs(c2) < 1e-15:
                    h = rhs / ra
                else:
                    h = (2.0 * rhs) / (ra + math.sqrt(max(ra * ra + 4.0 * c2 * rhs, 0.0)))
                return xa + min(max(h, 0.0), h_seg)
            xa, ra, Fa = xb, rb_, Fb
            j += 1

    def _first_crossing(self, x: float, a: float, target: float, Ix: float) -> float:
        pts = [x] + [float(p) for p in self.x if p > x]
        for xa, xb in zip(pts[:-1], pts[1:]):
            for h in np.linspace(0.0, xb - xa, 65)[1:]:
                S = xa + h
                if a * (S - x) + G * (self.integral_at(S) - Ix) >= target:
                    lo, hi = xa + h - (xb - xa) / 64.0, S
                    for _ in range(60):
                        mid = 0.5 * (lo + hi)
                        if a * (mid - x) + G * (self.integral_at(mid) - Ix) >= target:
                            hi = mid
                        else:
                            lo = mid
                    return hi
        r = a + G * float(self.G[-1])
        if r <= 0:
            return math.inf
        xl = pts[-1]
        Fl = a * (xl - x) + G * (self.integral_at(xl) - Ix)
        return xl + max(0.0, (target - Fl) / r)


