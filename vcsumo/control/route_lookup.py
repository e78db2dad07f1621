"""Vectorised look-ups along a route for one train length (v_lim(s), mean gradient, tunnel factor),
used by the DP speed profile (:mod:`vcsumo.control.dp_profile`), the NMPC's terminal set and its
prediction model; and plain-array test tracks as :class:`~vcsumo.route_profile.RouteProfile`.
"""

from __future__ import annotations

import math

import numpy as np

from vcsumo.route_profile import RouteProfile


def straight_route_profile(length_m: float, speed_limit_mps: float, gradient: float = 0.0, tunnel_factor: float = 1.0, edge_length_m: float | None = None) -> RouteProfile:
    """A straight level (or constant-gradient) test track as a :class:`RouteProfile` built from plain arrays.

    One edge (or equal edges of ``edge_length_m``), uniform speed limit, gradient and tunnel
    factor; used by the Felez et al. §IV-A test track and the unit tests.
    """
    if edge_length_m is None or edge_length_m >= length_m:
        lengths = np.array([float(length_m)])
    else:
        n = int(math.ceil(length_m / edge_length_m))
        lengths = np.full(n, float(length_m) / n)
    n = len(lengths)
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    return RouteProfile(
        edges=[f"e{i}" for i in range(n)], starts_m=starts, lengths_m=lengths, speeds_ms=np.full(n, float(speed_limit_mps)),
        gradients=np.full(n, float(gradient)), tunnel_factors=np.full(n, float(tunnel_factor)), sections=["test"] * n,
        km_from=starts / 1000.0, km_to=(starts + lengths) / 1000.0, point_limits=[],
    )


def route_profile_from_arrays(starts_m, speeds_mps, gradients=None, tunnel_factors=None, length_m: float | None = None) -> RouteProfile:
    """A :class:`RouteProfile` from piecewise-constant arrays (segment starts, limits, gradients)."""
    starts = np.asarray(starts_m, dtype=float)
    if length_m is None:
        raise ValueError("length_m is required")
    ends = np.append(starts[1:], float(length_m))
    lengths = ends - starts
    n = len(starts)
    grads = np.zeros(n) if gradients is None else np.asarray(gradients, dtype=float)
    tfs = np.ones(n) if tunnel_factors is None else np.asarray(tunnel_factors, dtype=float)
    return RouteProfile(
        edges=[f"e{i}" for i in range(n)], starts_m=starts, lengths_m=lengths, speeds_ms=np.asarray(speeds_mps, dtype=float),
        gradients=grads, tunnel_factors=tfs, sections=["arrays"] * n, km_from=starts / 1000.0, km_to=ends / 1000.0, point_limits=[],
    )


class RouteLookup:
    """Vectorised v_lim(s), mean gradient and tunnel factor of a route for one train length.

    * ``speed_limit(s)`` — the lowest limit over the train [s − L, s] including turnout limits
      (the same rule as :meth:`RouteProfile.speed_limit_train`), piecewise constant;
    * ``gradient(s)`` — equivalent gradient averaged over the train (as
      :meth:`RouteProfile.mean_gradient`), exact via the cumulative integral of the gradient;
    * ``tunnel_factor(s)`` — at the train front.

    Beyond the route end the last values are kept (the DP/terminal set ends the route anyway).
    """

    def __init__(self, profile: RouteProfile, train_length_m: float):
        self.profile = profile
        self.length_m = float(train_length_m)
        starts = np.asarray(profile.starts_m, dtype=float)
        lengths = np.asarray(profile.lengths_m, dtype=float)
        self.route_length_m = float(starts[-1] + lengths[-1])
        self._starts = starts
        self._tf = np.asarray(profile.tunnel_factors, dtype=float)
        # cumulative gradient integral at knots (edge starts + route end)
        grads = np.asarray(profile.gradients, dtype=float)
        self._g_knots = np.append(starts, self.route_length_m)
        self._g_cum = np.concatenate([[0.0], np.cumsum(grads * lengths)])
        self._g_first = float(grads[0])
        self._g_last = float(grads[-1])
        # train-length speed limit: piecewise constant between breakpoints
        L = self.length_m
        bps = set(starts.tolist()) | set((starts + L).tolist()) | {self.route_length_m, self.route_length_m + L}
        for ps, _ in profile.point_limits:
            bps |= {float(ps), float(ps) + L}
        bp = np.array(sorted(b for b in bps if b >= 0.0))
        if bp[0] > 0.0:
            bp = np.concatenate([[0.0], bp])
        mids = np.append(0.5 * (bp[:-1] + bp[1:]), bp[-1] + 1.0)
        vals = np.array([self._limit_scalar(m) for m in mids])
        self._lim_bp = bp
        self._lim_val = vals
        self._lim_ext = np.concatenate((vals[:1], vals))
        self.uniform = bool(np.all(grads == grads[0]) and np.all(self._tf == self._tf[0]))
        """Gradient and tunnel factor are the same everywhere (look-ups can be skipped)."""
        self.gradient0 = float(grads[0])
        self.tunnel0 = float(self._tf[0])

    def _limit_scalar(self, s: float) -> float:
        p = self.profile
        v = p.speed_limit_train(min(s, self.route_length_m - 1e-9), self.length_m)
        return float(v)

    # ---------------------------------------------------------------------------------------
    def speed_limit(self, s) -> np.ndarray:
        """Train-length speed limit v_lim(s), m/s (vectorised)."""
        # index i + 1 of the piece holding s into [v_0, v_0, v_1, …] (i = −1 before the first breakpoint)
        return self._lim_ext[np.searchsorted(self._lim_bp, np.asarray(s, dtype=float), side="right")]

    def _g_int(self, x: np.ndarray) -> np.ndarray:
        out = np.interp(x, self._g_knots, self._g_cum)
        out = np.where(x < 0.0, self._g_first * x, out)
        return np.where(x > self.route_length_m, self._g_cum[-1] + self._g_last * (x - self.route_length_m), out)

    def gradient(self, s) -> np.ndarray:
        """Equivalent gradient averaged over the train [s − L, s] (rise/run, vectorised)."""
        s = np.asarray(s, dtype=float)
        if self.length_m <= 0:
            return self._g_int(s + 1e-6) - self._g_int(s)
        return (self._g_int(s) - self._g_int(s - self.length_m)) / self.length_m

    def tunnel_factor(self, s) -> np.ndarray:
        """Tunnel factor at the train front (vectorised)."""
        s = np.asarray(s, dtype=float)
        i = np.searchsorted(self._starts, s, side="right") - 1
        return self._tf[np.clip(i, 0, len(self._tf) - 1)]

    def restriction_points(self) -> list[tuple[float, float]]:
        """(position, new limit) wherever the train-length limit drops, sorted."""
        out = []
        for j in range(1, len(self._lim_val)):
            if self._lim_val[j] < self._lim_val[j - 1] - 1e-9:
                out.append((float(self._lim_bp[j]), float(self._lim_val[j])))
        return out
