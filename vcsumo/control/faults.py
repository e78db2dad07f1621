"""Faults in the control loop: one stage between the observation and the train, for every controller.

:class:`FaultStage` wraps a controller (and optionally its safety supervisor, e.g. the CBF of
Terlizzi et al.) and has the one verb of every controller, ``make_step(obs) -> Command``.  It is
used by the SUMO loop (:class:`vcsumo.sim.vc_driver.VCDriver`) and by the offline simulator
(:func:`vcsumo.sim.offline.simulate_convoy`).  Each step it

1. checks the observation: the ego state (time, position, speed, applied force), the sensed gap and
   speed of the predecessor and every received message (time stamp, position, speed and, when sent,
   the predicted trajectory) must be finite — otherwise ``non_finite_state`` and the controller is
   not called (its output from a NaN input would be meaningless, and stateful controllers — the
   NMPC's warm start, consensus integrators — would be corrupted);
2. asks the controller for a command — an exception is ``controller_exception``; a non-finite force
   is ``non_finite_command``; a command flagged ``infeasible`` (the nominal problem had no solution,
   :class:`~vcsumo.control.base.Command`) is ``solver_failure``;
3. passes the command through the supervisor, if any (an exception or a non-finite force there is
   recorded the same way);
4. passes every command it issues (its own emergency brake included) through the separation
   guard, if any (:class:`~vcsumo.control.guard.SeparationGuard`; a guard that raises or returns a
   non-finite force is a fault of the same kinds).  Stacks are built with it by
   :func:`vcsumo.control.registry.build_follower_stack`.

Actions.  On a fault the follower gets the **emergency brake** for that step: the force
:func:`emergency_brake_force_n` (−max(M·a_eb, min(M·a_br, P_br/v)), eq. 4a/4b with the emergency
deceleration of the train model; with a CBF supervisor at least its K_E^F demand
:func:`vcsumo.control.cbf.emergency_force_n`, Terlizzi et al. Definition 11), ``mode`` =
``fault-emergency``, ``emergency`` = True.  The one exception is a ``solver_failure`` that comes
with a *usable fallback*: the controller reports ``infeasible`` but its command is a finite brake
(force ≤ 0) and its plan, if it sends one, is finite — the NMPC's documented fallback, the full
service brake −min(M·a_br, P_br/v) (:mod:`vcsumo.control.mpc`).  That command is passed on (the
event is recorded with action ``controller_fallback``); the separation guard downstream still
limits it.  The emergency brake command is flagged ``emergency``: the SUMO loop applies the force
(bounded by −M·a_eb), the offline plant its full emergency brake (:mod:`vcsumo.plant`).

Latch.  After an emergency-brake fault the follower keeps braking until the observation has been
valid *and* the controller (and supervisor) has returned a valid, feasible command for
``recovery_s`` consecutive seconds (at least one step); only the step after that gets the
controller's command.  So a follower never resumes traction the step after a NaN or an exception,
and a controller that fails every other step keeps the train braking.  During the latch the
controller is still stepped on valid observations (so its internal state follows the train) but its
commands are not applied.

Recording.  Consecutive faulty steps of the same kind form one :class:`FaultEvent` (time of the
first step, train, kind, action, message, number of steps, time of the last step); the stage keeps
them in ``events``, counts ``emergency_steps`` (steps it commanded the emergency brake, latch
included) and the supervisor's interventions.  :func:`faults_frame` turns events into the
``faults.csv`` table (columns :data:`FAULT_COLUMNS`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Iterable

import numpy as np
import pandas as pd

from vcsumo.control.base import Command, Observation
from vcsumo.dynamics import TrainParams, brake_force_limit

CONTROLLER_EXCEPTION = "controller_exception"
NON_FINITE_COMMAND = "non_finite_command"
NON_FINITE_STATE = "non_finite_state"
SOLVER_FAILURE = "solver_failure"
FAULT_KINDS = (CONTROLLER_EXCEPTION, NON_FINITE_COMMAND, NON_FINITE_STATE, SOLVER_FAILURE)

EMERGENCY_BRAKE = "emergency_brake"
CONTROLLER_FALLBACK = "controller_fallback"
FAULT_MODE = "fault-emergency"
"""``Command.mode`` of a command issued by the fault stage."""

FAULT_COLUMNS = ["time_s", "train", "kind", "action", "message", "steps", "end_time_s"]
"""Columns of ``faults.csv``: time_s (first faulty step, s), train, kind (one of
:data:`FAULT_KINDS`), action (``emergency_brake`` or ``controller_fallback``), message, steps
(consecutive faulty steps of this event, -), end_time_s (last faulty step, s)."""


@dataclass
class FaultEvent:
    """Consecutive faulty steps of one kind for one train."""

    time_s: float
    """Simulation time of the first faulty step, s."""
    train: str
    kind: str
    action: str
    message: str
    steps: int = 1
    end_time_s: float = math.nan
    """Simulation time of the last faulty step, s."""


def emergency_brake_force_n(p: TrainParams, v_mps: float) -> float:
    """The emergency brake demand, N (negative): −max(M·a_eb, min(M·a_br, P_br/v)).

    M·a_eb is the train model's emergency braking force (the deceleration the SUMO loop lets a
    follower reach, eq. 1b); the service envelope of eq. 4a/4b is the floor for a train whose
    emergency deceleration is given below its service one.  A non-finite speed counts as standstill
    (the largest service-envelope force)."""
    v = float(v_mps) if math.isfinite(v_mps) else 0.0
    return -max(p.mass_kg * p.emergency_brake_decel_mps2, float(brake_force_limit(p, max(v, 0.0))))


def _finite(*xs) -> bool:
    return all(x is not None and math.isfinite(x) for x in xs)


def _finite_array(a) -> bool:
    if a is None:
        return True
    try:
        if not isinstance(a, np.ndarray):
            a = np.asarray(a, dtype=float)
        return math.isfinite(a.sum())  # a NaN or ±inf anywhere makes the sum non-finite
    except (TypeError, ValueError):
        return False


def observation_fault(obs: Observation) -> str | None:
    """What is non-finite in an observation (None: everything the controllers read is finite)."""
    try:
        e = obs.ego
        if not _finite(obs.time_s, obs.step_s) or obs.step_s <= 0:
            return f"non-finite time or step (t = {obs.time_s}, dt = {obs.step_s})"
        if not _finite(e.position_m, e.speed_mps, e.force_n):
            return f"non-finite ego state (position {e.position_m} m, speed {e.speed_mps} m/s, force {e.force_n} N)"
        if obs.sensed_gap_m is not None and not math.isfinite(obs.sensed_gap_m):
            return f"non-finite sensed gap ({obs.sensed_gap_m} m)"
        if obs.sensed_speed_mps is not None and not math.isfinite(obs.sensed_speed_mps):
            return f"non-finite sensed predecessor speed ({obs.sensed_speed_mps} m/s)"
        for sender, m in obs.received.items():
            s = m.state
            if not _finite(m.sent_time_s, s.time_s, s.position_m, s.speed_mps, m.length_m):
                return f"non-finite state in the message from {sender} (position {s.position_m} m, speed {s.speed_mps} m/s, sent at {m.sent_time_s} s)"
            if not (_finite_array(m.plan_times_s) and _finite_array(m.plan_positions_m) and _finite_array(m.plan_speeds_mps)):
                return f"non-finite predicted trajectory in the message from {sender}"
    except (AttributeError, TypeError, ValueError) as exc:
        return f"malformed observation ({type(exc).__name__}: {exc})"
    return None


def _solver_message(cmd: Command) -> str:
    viol = cmd.info.get("violation") if isinstance(cmd.info, dict) else None
    if isinstance(viol, dict):
        if viol.get("reason"):
            return f"no feasible solution: {viol['reason']}"
        parts = [f"{k} {v:.3g}" for k, v in viol.items() if isinstance(v, (int, float)) and v > 1e-9]
        if parts:
            return "no feasible plan (violations: " + ", ".join(parts) + ")"
    return f"the controller reported no feasible solution (mode {cmd.mode})"


def usable_fallback(cmd: Command) -> bool:
    """An ``infeasible`` command the stage may pass on: a finite brake (force ≤ 0) with a finite plan or none."""
    return (math.isfinite(cmd.force_n) and cmd.force_n <= 0.0 and _finite_array(cmd.plan_times_s)
            and _finite_array(cmd.plan_positions_m) and _finite_array(cmd.plan_speeds_mps) and _finite_array(cmd.plan_forces_n))


def _unusable_force(owner, cmd: Command) -> str:
    """Why ``cmd`` (from ``owner``) has no finite force, or "" if it has one."""
    try:
        force = float(cmd.force_n)
    except Exception as exc:  # noqa: BLE001 - any malformed output is a fault
        return f"{type(owner).__name__} returned no usable force ({type(exc).__name__}: {exc})"
    return "" if math.isfinite(force) else f"{type(owner).__name__} returned force {force} N"


class FaultStage:
    """Controller (+ optional supervisor) with fault handling: ``make_step(obs) -> Command`` (see module doc).

    ``params``: the train's model parameters for the emergency brake (default ``obs.params``);
    ``recovery_s``: how long the observation and the controller must be valid before the latch
    releases, s (at least one step); ``train_id``: the name in events (default ``obs.ego_id``).
    """

    def __init__(self, controller, params: TrainParams | None = None, supervisor=None, train_id: str | None = None, recovery_s: float = 1.0,
                 guard=None):
        if not (recovery_s >= 0.0 and math.isfinite(recovery_s)):
            raise ValueError(f"recovery_s must be a finite non-negative time, got {recovery_s}")
        self.controller = controller
        self.supervisor = supervisor
        self.guard = guard
        """The separation guard (:class:`~vcsumo.control.guard.SeparationGuard`): ``limit(obs, cmd)``
        applied to every command the stage issues, its own included (None: no guard)."""
        self.last_nominal: Command | None = None
        """The controller's latest command, before the supervisor and the guard."""
        self.params = params
        self.train_id = train_id
        self.recovery_s = float(recovery_s)
        self.events: list[FaultEvent] = []
        self.emergency_steps = 0
        """Steps in which the stage commanded the emergency brake (faults and latch)."""
        self.supervisor_interventions = 0
        """Steps in which the supervisor changed the controller's force."""
        self.latched = False
        self._clean = 0
        self._open: FaultEvent | None = None

    # -------------------------------------------------------------------------------------
    def _emergency_force(self, obs: Observation) -> float:
        p = self.params if self.params is not None else obs.params
        try:
            v = float(obs.ego.speed_mps)
        except Exception:
            v = math.nan
        u = emergency_brake_force_n(p, v)
        bounds = getattr(self.supervisor, "follower_bounds", None)
        if bounds is not None:
            from vcsumo.control.cbf import emergency_force_n

            try:
                u = min(u, float(emergency_force_n(bounds, v if math.isfinite(v) else 0.0)))
            except Exception:
                pass
        return u

    def _record(self, obs: Observation, kind: str, action: str, message: str) -> None:
        try:
            t = float(obs.time_s)
        except Exception:
            t = math.nan
        ev = self._open
        if ev is not None and ev.kind == kind and ev.action == action:
            ev.steps += 1
            ev.end_time_s = t
            return
        train = self.train_id or str(getattr(obs, "ego_id", "?"))
        ev = FaultEvent(time_s=t, train=train, kind=kind, action=action, message=" ".join(str(message).split()), steps=1, end_time_s=t)
        self.events.append(ev)
        self._open = ev

    def _step_controller(self, obs: Observation) -> tuple[Command | None, str | None, str]:
        """(command, fault kind or None, message)."""
        try:
            cmd = self.controller.make_step(obs)
        except Exception as exc:  # noqa: BLE001 - any controller failure brakes the train
            return None, CONTROLLER_EXCEPTION, f"{type(self.controller).__name__} raised {type(exc).__name__}: {exc}"
        self.last_nominal = cmd
        bad = _unusable_force(self.controller, cmd)
        if bad:
            return None, NON_FINITE_COMMAND, bad
        if cmd.infeasible:
            return cmd, SOLVER_FAILURE, _solver_message(cmd)
        return cmd, None, ""

    def _filter(self, obs: Observation, cmd: Command) -> tuple[Command | None, str | None, str]:
        try:
            out = self.supervisor.filter(obs, cmd)
        except Exception as exc:  # noqa: BLE001
            return None, CONTROLLER_EXCEPTION, f"{type(self.supervisor).__name__} raised {type(exc).__name__}: {exc}"
        bad = _unusable_force(self.supervisor, out)
        if bad:
            return None, NON_FINITE_COMMAND, bad
        if float(out.force_n) != cmd.force_n:
            self.supervisor_interventions += 1
        return out, None, ""

    def make_step(self, obs: Observation) -> Command:
        """One step of the controller with fault handling (the Controller interface)."""
        bad = observation_fault(obs)
        cmd = self._step(obs, bad)
        if self.guard is None or bad is not None:
            return cmd  # on a non-finite observation the emergency brake needs no guard
        try:
            out = self.guard.limit(obs, cmd)
            fault = _unusable_force(self.guard, out)
        except Exception as exc:  # noqa: BLE001 - a failing guard brakes the train like a failing controller
            out, fault = None, f"{type(self.guard).__name__} raised {type(exc).__name__}: {exc}"
        if not fault:
            return out
        kind = CONTROLLER_EXCEPTION if out is None else NON_FINITE_COMMAND
        self._record(obs, kind, EMERGENCY_BRAKE, fault)
        self._clean = 0
        self.latched = True
        if cmd.mode == FAULT_MODE:  # already the emergency brake
            return cmd
        return self._brake(obs, kind, fault, run_supervisor=False)

    def _step(self, obs: Observation, bad: str | None) -> Command:
        kind, msg, cmd = (NON_FINITE_STATE, bad, None) if bad is not None else (None, "", None)
        if kind is None:
            cmd, kind, msg = self._step_controller(obs)
        hard = kind is not None and not (kind == SOLVER_FAILURE and usable_fallback(cmd))
        if cmd is not None and not hard and self.supervisor is not None:
            filtered, k2, m2 = self._filter(obs, cmd)
            if k2 is not None:
                kind, msg, hard = k2, m2, True
            else:
                cmd = filtered
        if kind is not None:
            self._record(obs, kind, EMERGENCY_BRAKE if hard else CONTROLLER_FALLBACK, msg)
            self._clean = 0
        else:
            self._open = None
        if hard:
            self.latched = True
            return self._brake(obs, kind, msg, run_supervisor=kind != NON_FINITE_STATE)
        if self.latched:
            if kind is None:
                self._clean += 1
                if self._clean >= max(1, math.ceil(self.recovery_s / obs.step_s - 1e-9)):
                    self.latched = False  # released: the next step gets the controller's command
            return self._brake(obs, "latch", f"braking until the controller has been valid for {self.recovery_s:g} s", run_supervisor=False)
        return cmd

    def _brake(self, obs: Observation, kind: str, msg: str, run_supervisor: bool) -> Command:
        self.emergency_steps += 1
        u = self._emergency_force(obs)
        info = {"fault_kind": kind, "fault_message": msg}
        if run_supervisor and self.supervisor is not None:
            # keep the supervisor's own state (leader prediction, emergency latch) in step with the train
            try:
                sup = self.supervisor.filter(obs, Command(force_n=u, mode=FAULT_MODE, emergency=True))
                if math.isfinite(float(sup.force_n)):
                    u = min(u, float(sup.force_n))
                    info.update({k: v for k, v in sup.info.items() if k.startswith("cbf_")})
            except Exception:  # noqa: BLE001 - the fault is already recorded; brake regardless
                pass
        return Command(force_n=u, mode=FAULT_MODE, emergency=True, info=info)

    # -------------------------------------------------------------------------------------
    def counts(self) -> dict[str, int]:
        """Events per kind."""
        out = {k: 0 for k in FAULT_KINDS}
        for ev in self.events:
            out[ev.kind] = out.get(ev.kind, 0) + 1
        return out


def faults_frame(events: Iterable[FaultEvent]) -> pd.DataFrame:
    """The ``faults.csv`` table (columns :data:`FAULT_COLUMNS`), ordered by time."""
    rows = [asdict(e) for e in events]
    df = pd.DataFrame(rows, columns=FAULT_COLUMNS)
    return df.sort_values(["time_s", "train"], kind="stable").reset_index(drop=True) if len(df) else df


__all__ = [
    "FaultStage", "FaultEvent", "emergency_brake_force_n", "observation_fault", "usable_fallback", "faults_frame",
    "FAULT_KINDS", "FAULT_COLUMNS", "FAULT_MODE", "CONTROLLER_EXCEPTION", "NON_FINITE_COMMAND", "NON_FINITE_STATE", "SOLVER_FAILURE",
    "EMERGENCY_BRAKE", "CONTROLLER_FALLBACK",
]
