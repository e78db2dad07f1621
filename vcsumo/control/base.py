"""The controller interface shared by MPC, consensus control and the CBF safety supervisor.

Controllers are pure Python objects: they never import libsumo and can be unit-tested alone.
Every controller has one verb, :meth:`Controller.make_step`, taking an :class:`Observation` (the
ego train's state, what the channel has delivered about other trains, and on-board sensing) and
returning a :class:`Command` (the traction/brake force u of Felez eq. 1b/3, in N).

Positions are metres along the *ego train's route* (the loop maps other trains into that frame),
so a gap is ``leader.position_m - leader_length_m - ego.position_m``.  The ego route's profile
(speed limits, gradients, tunnels) is given as a :class:`~vcsumo.route_profile.RouteProfile`.

A safety filter wraps a controller: ``Supervisor.filter(obs, nominal) -> Command`` (the CBF
supervisor of Terlizzi et al. is one).  The stack that drives a follower (controller →
supervisor → separation guard → fault stage) is built by name in :mod:`vcsumo.control.registry`.
The SUMO loop applies a command by asking SUMO for the speed the train reaches after one step
under that force (eq. 1b), with SUMO's traction limit still enforced; the offline loop applies
it to a :class:`~vcsumo.plant.TrainPlant` (``emergency`` commands with the emergency brake).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from vcsumo.dynamics import TrainParams
from vcsumo.route_profile import RouteProfile


@dataclass(frozen=True)
class TrainStateMsg:
    """A train's state at a time (position in the receiver's route frame)."""

    time_s: float
    position_m: float
    """Front position, m (ego route frame)."""
    speed_mps: float
    accel_mps2: float = 0.0
    force_n: float = 0.0


@dataclass(frozen=True)
class Message:
    """A train-to-train message as delivered by the channel (time stamp = when it was sent)."""

    sender: str
    sent_time_s: float
    state: TrainStateMsg
    length_m: float
    plan_times_s: np.ndarray | None = None
    """Predicted trajectory of the sender (absolute times), if it sends one (SH predictor, RLP)."""
    plan_positions_m: np.ndarray | None = None
    plan_speeds_mps: np.ndarray | None = None
    plan_forces_n: np.ndarray | None = None
    received_time_s: float = math.nan


@dataclass(frozen=True)
class Observation:
    """Everything a controller may use at one step."""

    time_s: float
    step_s: float
    ego_id: str
    ego: TrainStateMsg
    params: TrainParams
    """The ego train's nominal model parameters (eq. 1-5)."""
    profile: RouteProfile
    """The ego route: speed limits, gradients, tunnels along position."""
    received: dict[str, Message] = field(default_factory=dict)
    """Latest message delivered from each other train (may be old or missing)."""
    predecessor: str | None = None
    """Id of the train directly ahead in the convoy (None for the convoy leader)."""
    convoy: tuple[str, ...] = ()
    """Convoy members, leader first."""
    sensed_gap_m: float | None = None
    """On-board sensed front-to-rear gap to the predecessor, m (where the paper assumes a sensor)."""
    sensed_speed_mps: float | None = None
    """On-board sensed speed of the predecessor, m/s."""
    target_speed_mps: float | None = None
    """For a convoy leader: the speed the timetable/scenario asks for (None: line speed)."""
    next_stop_m: float | None = None
    """The ego's own stop ahead (ego route frame, m) once the loop is about to hand the train over
    for it (None: no stop near); the separation guard keeps to the service brake and treats it as
    an obstacle."""


@dataclass(frozen=True)
class Command:
    """A controller's output for one step."""

    force_n: float
    """Traction (+) or brake (−) force u, N (Felez eq. 3)."""
    mode: str = "nominal"
    """Active controller/mode (e.g. 'mpc', 'cbc', 'cruise-1', 'safety', 'emergency', 'fallback')."""
    emergency: bool = False
    infeasible: bool = False
    """The nominal problem had no solution this step and a safe fallback was used."""
    plan_times_s: np.ndarray | None = None
    plan_positions_m: np.ndarray | None = None
    plan_speeds_mps: np.ndarray | None = None
    plan_forces_n: np.ndarray | None = None
    info: dict = field(default_factory=dict)


class Controller(Protocol):
    """Every controller: ``make_step(observation) -> command``."""

    def make_step(self, obs: Observation) -> Command:
        ...


class Supervisor(Protocol):
    """A safety filter between a nominal controller and the train."""

    def filter(self, obs: Observation, nominal: Command) -> Command:
        ...


def gap_to(obs: Observation, other: str) -> float | None:
    """Front-to-rear gap to a train whose latest message was delivered (its state at send time)."""
    m = obs.received.get(other)
    if m is None:
        return None
    return m.state.position_m - m.length_m - obs.ego.position_m
