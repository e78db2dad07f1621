"""The stack that drives one VC follower: nominal controller → supervisor → separation guard → fault stage.

A :class:`FollowerStack` is what :func:`vcsumo.control.registry.build_follower_stack` returns and
what both closed loops step — the SUMO loop (:class:`vcsumo.sim.vc_driver.VCDriver`, which turns
the final force into a speed command) and the offline loop (:mod:`vcsumo.sim.offline`, which
applies it to a :class:`~vcsumo.plant.TrainPlant`).  Its one verb is the controller's,
``make_step(obs) -> Command``; the stages are

1. the **nominal controller** (MPC, consensus, Terlizzi's switched cruise controller, ...),
   optionally computed every ``control_period_s`` only (:class:`SampledController`, the ATO cycle);
2. an optional **supervisor** (the CBF of Terlizzi et al.), every step;
3. the **separation guard** (:class:`~vcsumo.control.guard.SeparationGuard`), every step, on every
   command the stage issues;
4. all inside the **fault stage** (:class:`~vcsumo.control.faults.FaultStage`): faults of any stage
   give the emergency brake, latched, with the events recorded.

The stack also carries what the loops and studies need to know about the controller: its name,
the minimum safe gap d_min, its own coupled spacing at a common speed v, and whether predecessors
must broadcast their predicted trajectories (``uses_plans``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from vcsumo.control.base import Command, Observation
from vcsumo.control.faults import FaultStage


class SampledController:
    """A nominal controller computed every ``period_s`` (the ATO cycle) inside a faster loop.

    Between two computations the command is held; the NMPC applies its planned input u_k of the
    step it is in (eq. 12, the plan's ``commands_n``) instead.  The safety supervisor downstream
    still checks every step.
    """

    def __init__(self, controller, period_s: float):
        self.controller = controller
        self.period_s = period_s
        self._held: Command | None = None
        self._next_s = -math.inf

    def make_step(self, obs: Observation) -> Command:
        if self._held is None or obs.time_s >= self._next_s - 1e-9:
            self._held = self.controller.make_step(obs)
            self._next_s = obs.time_s + self.period_s
            return self._held
        c = self._held
        sol = getattr(self.controller, "last_solution", None)
        if sol is not None and sol.ok and not c.infeasible and len(sol.commands_n) > 1:
            k = int(np.searchsorted(sol.times_s, obs.time_s + 1e-9, side="right")) - 1
            k = min(max(k, 0), len(sol.commands_n) - 1)
            return Command(force_n=float(sol.commands_n[k]), mode=c.mode, emergency=c.emergency, info=c.info)
        return c


@dataclass
class FollowerStack:
    """One follower's controller stack (see the module doc); ``make_step(obs) -> Command``."""

    name: str
    """Controller name as registered (``cbc``, ``cbf-mpc``, ...)."""
    nominal: object
    """The nominal controller (unwrapped: its stats and settings are here)."""
    supervisor: object | None
    guard: object | None
    stage: FaultStage
    d_min_m: float
    """Minimum safe front-to-rear gap, m (d_min of the parameter file; with a CBF its safety distance d)."""
    coupled_gap: Callable[..., float]
    """The controller's own front-to-rear spacing at a common speed v (m/s), m."""
    uses_plans: bool
    """Whether this controller reads its predecessor's predicted trajectory (the loops then send it)."""
    parameter_files: dict[str, str] = field(default_factory=dict)
    """Resolved parameter files by stage (``nominal``, ``supervisor``), for the record."""

    def make_step(self, obs: Observation) -> Command:
        return self.stage.make_step(obs)

    def coupled_gap_m(self, v_mps: float, position_m: float | None = None) -> float:
        """The spacing the stack keeps at a common speed (on the route at ``position_m`` where its gap
        reference follows the gradients), m."""
        return float(self.coupled_gap(v_mps) if position_m is None else self.coupled_gap(v_mps, position_m=position_m))

    @property
    def supervisor_interventions(self) -> int:
        return self.stage.supervisor_interventions

    @property
    def guard_interventions(self) -> int:
        return self.guard.interventions if self.guard is not None else 0

    @property
    def events(self) -> list:
        return self.stage.events


__all__ = ["FollowerStack", "SampledController"]
