"""The regime interface and what the analytic headways share: the supervised braking distance."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd

from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.separation import RouteBraking, SeparationModel

SUPERVISION_REACTION_STEPS = 1.5
"""The supervisor's curves add 1.5 simulation steps to the dead time (semi-implicit Euler), as
:mod:`vcsumo.sim.supervision` does."""


@dataclass(frozen=True)
class SupervisedBraking:
    """Braking distance of a train under the absolute rule, along its route, m.

    D(v, s): after the dead time T + 1.5·Δt, guaranteed service braking integrated over the
    gradient profile (:class:`vcsumo.signalling.separation.RouteBraking`) — the rule the supervisor
    enforces: trains approach their end of authority on the service brake whatever brake the set
    certifies the separation with (``absolute_braking``), so the headways do not depend on it.
    """

    model: SeparationModel
    stock: RollingStock
    profile: RouteProfile
    step_s: float

    @property
    def dead_time_s(self) -> float:
        return self.model.dead_time_s + SUPERVISION_REACTION_STEPS * self.step_s

    def distance(self, v, s=None):
        """D(v, s) on the route (s None: at the route's start), m (arrays accepted)."""
        br = RouteBraking(self.model, self.stock, self.profile, "service")
        v_arr = np.atleast_1d(np.asarray(v, dtype=float))
        s_arr = np.zeros_like(v_arr) if s is None else np.broadcast_to(np.atleast_1d(np.asarray(s, dtype=float)), v_arr.shape)
        out = np.array([br.stopping_distance(float(sk), float(vk), self.dead_time_s) for vk, sk in zip(v_arr, s_arr)])
        return float(out[0]) if np.ndim(v) == 0 else out


@dataclass(frozen=True)
class HeadwayInputs:
    """What an analytic headway needs: one unit's leader running alone on its route."""

    model: SeparationModel
    stock: RollingStock
    profile: RouteProfile
    run: pd.DataFrame
    """The leader's unhindered run (``time_s, s_m, speed_mps``) from the release point."""
    signals_m: list[float]
    """Route positions of the signals (FBS)."""
    step_s: float
    s_check_m: float
    """The headway is the largest blocking time met between the release point and here."""
    route_end_m: float | None = None
    """Where the trains leave the route (None: the end of ``profile``)."""
    coupled_gap: Callable[[float], float] | None = None
    """VC: the front-to-rear gap a convoy's followers keep at a common speed v, m — the spacing
    their stack certifies (e.g. :meth:`vcsumo.control.stack.FollowerStack.coupled_gap_m`: the
    model's relative braking gap with the guard's brake build-up and the controller's buffer);
    None: the separation model's own coupled gap ``vc_gap(v)``."""
    coupled_gap_at: Callable[[float, float], float] | None = None
    """VC on a route: ``(v, s) ->`` that spacing with the follower's front at route position s of
    ``profile`` (the relative-braking rule over the grades ahead), m; when given, every follower of
    the convoy runs at the spacing where it is (``coupled_gap`` is then only the level-track
    figure)."""

    @property
    def end_m(self) -> float:
        return self.profile.length_m if self.route_end_m is None else self.route_end_m

    def braking(self) -> SupervisedBraking:
        return SupervisedBraking(self.model, self.stock, self.profile, self.step_s)


@dataclass(frozen=True)
class AnalyticHeadway:
    """A regime's minimum headway between two units, from the separation model."""

    headway_s: float
    critical_m: float
    """Route position of the critical block or point."""
    blocks: pd.DataFrame | None = None
    """FBS: every block's blocking time (for the blocking-time stairs)."""
    coupled_gap_m: float | None = None
    """VC: the coupled front-to-rear gap at the release speed, m — on the route where the first
    follower is at the release (with ``HeadwayInputs.coupled_gap_at``), else on level track."""
    coupled_gap_level_m: float | None = None
    """VC: the same spacing on level track at the release speed, m (a paper check)."""
    reservation: pd.DataFrame | None = None
    """MB / VC: the track reserved ahead of the unit's leader along its run, ``s_m`` (front) →
    ``reserved_to_m`` (front + supervised braking distance + margin and position errors), the rule
    the headway is computed with (for the time–distance bands)."""
    rear_lag: Callable[[np.ndarray], np.ndarray] | None = None
    """VC convoys: time between the convoy's leader and its last train passing a route position, s
    (:func:`vcsumo.signalling.regimes.vc.convoy_rear_lag`); None: a single train."""


class Regime:
    """A signalling regime (see :mod:`vcsumo.signalling.regimes`)."""

    name: str = ""
    title: str = ""
    moving_block: bool = False
    supervision: str = "mb"
    couples: bool = False
    default_step_s: float = 0.5

    def analytic_headway(self, inp: HeadwayInputs, convoy_size: int = 1) -> AnalyticHeadway:
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"<regime {self.name}>"
