"""The only module that imports libsumo.

:class:`SumoBackend` owns one SUMO simulation (a context manager: start, step, close).  It reads
train states, applies speed commands, switches vTypes at tunnel portals and reports collisions,
emergency braking and teleports.  Everything else in vcsumo sees plain Python data.

Speed modes (``setSpeedMode`` bit masks, SUMO docs "TraCI/Change Vehicle State"):

* :data:`SPEED_MODE_DEFAULT` (31) — SUMO drives: safe speed (signals, moving-block braking
  distance), traction and braking limits, right of way, red lights.
* :data:`SPEED_MODE_VC_FOLLOWER` (26) — a virtually coupled follower driven by vcsumo: SUMO's
  safe-speed (absolute braking distance) check and its braking cap (service ``decel``) are OFF, so
  the follower can apply its emergency brake; vcsumo bounds the deceleration itself with the train
  model (eq. 1b at the emergency braking force), SUMO still enforces traction and red signals.

Failures.  Every call into libsumo goes through :func:`_traci`: a TraCIException or
FatalTraCIError (SUMO stopped on an error, e.g. a route it cannot load mid-run, or the simulation
was closed) becomes one :class:`~vcsumo.errors.SumoError` naming what ran (``label``: the scenario
and network files), the simulation time of the last completed step, the call and SUMO's own error
lines; a call after :meth:`SumoBackend.close` gives the same error.
"""

from __future__ import annotations

import functools
import math
from bisect import bisect_left, insort
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from vcsumo.errors import SumoError
from vcsumo.sim.sumo_paths import sumo_binary, sumo_home

SPEED_MODE_DEFAULT = 31
SPEED_MODE_VC_FOLLOWER = 26
INSERTION_HOLD = "vcsumo:hold"
"""The foe of an insertion constraint that keeps a train out of the network until removed (no train has this id)."""
INVALID_DISTANCE = -1073741824.0


@dataclass(frozen=True)
class TrainObservation:
    """State of one train in SUMO after a step (SI units)."""

    id: str
    edge: str
    lane_pos_m: float
    speed_mps: float
    accel_mps2: float
    odometer_m: float
    route_index: int
    type_id: str


def _traci(fn):
    """Turn libsumo's exceptions (and calls after close) into one :class:`SumoError` with context."""

    @functools.wraps(fn)
    def call(self: "SumoBackend", *args, **kwargs):
        try:
            return fn(self, *args, **kwargs)
        except SumoError:
            raise
        except Exception as exc:
            ls = self._ls
            if ls is None or isinstance(exc, (ls.TraCIException, ls.FatalTraCIError)):
                raise self._failure(fn.__name__, exc) from None
            raise

    return call


class SumoBackend:
    """A running SUMO simulation (libsumo), used as ``with SumoBackend(args) as sim: ...``.

    ``label`` names the run in error messages (e.g. the scenario and network files); ``on_failure``
    is called with the time of the last step completed when the run ends by an exception.
    """

    def __init__(self, args: list[str], error_log: Path | None = None, label: str = "", on_failure: Callable[[float], None] | None = None):
        self.args = list(args)
        self.on_failure = on_failure
        self.error_log = error_log
        self.label = label
        self._ls = None
        self._time = math.nan
        self._running: list[str] = []
        self._departed: list[str] = []
        self._arrived: list[str] = []
        self._min_gap: dict[str, float] = {}
        self._edge_length: dict[str, float] = {}

    def translate_failure(self, where: str, exc: Exception) -> Exception | None:
        """libsumo's exception (or a call after close) as one :class:`SumoError` with context; None for
        any other exception (to be raised as it is)."""
        ls = self._ls
        if ls is None or isinstance(exc, (ls.TraCIException, ls.FatalTraCIError)):
            return self._failure(where, exc)
        return None

    # ----------------------------------------------------------------------------- lifecycle
    def __enter__(self) -> "SumoBackend":
        self.start()
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is not None and self.on_failure is not None and not math.isnan(self._time):
            self.on_failure(self._time)  # where the run stopped (before the error ends it)
        self.close()

    def start(self) -> None:
        sumo_home()  # sets SUMO_HOME for XML validation
        import libsumo  # noqa: PLC0415  (the one place libsumo is imported)

        self._ls = libsumo
        cmd = [sumo_binary("sumo")] + self.args
        if self.error_log is not None:  # warnings go into the log only, not onto the terminal (over the progress bar)
            cmd += ["--error-log", str(self.error_log), "--no-warnings", "true"]
        try:
            libsumo.start(cmd)
        except Exception as exc:  # libsumo raises TraCIException / FatalTraCIError
            where = f"{self.label}: " if self.label else ""
            raise SumoError(f"{where}SUMO failed to start: {self._errors() or _one_line(exc)}") from None
        self._time = libsumo.simulation.getTime()
        # the per-train getters straight from the extension module (libsumo's Python wrappers only
        # forward their arguments: one call layer less for every value of every train at every step)
        raw = getattr(libsumo, "_libsumo", None)
        v = libsumo.vehicle

        def pick(name: str):
            return getattr(raw, f"vehicle_{name}", None) or getattr(v, name)

        self._get = tuple(pick(n) for n in ("getRoadID", "getLanePosition", "getSpeed", "getAcceleration", "getDistance", "getRouteIndex"))
        self._get_leader = pick("getLeader")
        self._get_min_gap = pick("getMinGap")
        self._get_length = pick("getLength")
        self.get_driving_distance = pick("getDrivingDistance")

    def close(self) -> None:
        if self._ls is not None:
            try:
                self._ls.close()
            except Exception:
                pass
            self._ls = None

    def _failure(self, call: str, exc: BaseException) -> SumoError:
        where = f"{self.label}: " if self.label else ""
        if self._ls is None:
            return SumoError(f"{where}SUMO is not running (closed before '{call}', last step t = {self._time:g} s)")
        return SumoError(f"{where}SUMO failed during the simulation after t = {self._time:g} s ({call}): {self._errors() or _one_line(exc)}")

    def _errors(self) -> str:
        if self.error_log is not None and self.error_log.is_file():
            lines = [ln.strip() for ln in self.error_log.read_text(errors="replace").splitlines() if ln.startswith("Error")]
            return " | ".join(lines[:5])
        return ""

    # ----------------------------------------------------------------------------- stepping
    @_traci
    def step(self) -> float:
        """Advance one step; returns the new simulation time, s.  Keeps the list of running trains
        (:meth:`running`) from the trains that departed and arrived in the step."""
        ls = self._ls
        ls.simulationStep()
        self._time = ls.simulation.getTime()
        self._departed = list(ls.simulation.getDepartedIDList())
        self._arrived = list(ls.simulation.getArrivedIDList())
        running = self._running
        for vid in self._departed:
            insort(running, vid)
            self._min_gap[vid] = self._get_min_gap(vid)
        for vid in self._arrived:
            i = bisect_left(running, vid)
            if i < len(running) and running[i] == vid:
                del running[i]
            self._min_gap.pop(vid, None)
        return self._time

    @property
    def time(self) -> float:
        return self._get_time()

    @_traci
    def _get_time(self) -> float:
        return self._ls.simulation.getTime()

    @_traci
    def min_expected(self) -> int:
        """Trains still in the simulation or waiting to be inserted."""
        return self._ls.simulation.getMinExpectedNumber()

    def departed(self) -> list[str]:
        """Trains that entered the network in the last step."""
        return list(self._departed)

    def arrived(self) -> list[str]:
        """Trains that left the network in the last step."""
        return list(self._arrived)

    def running(self) -> list[str]:
        """Trains in the network after the last step, in SUMO's order (by id, as ``getIDList``),
        kept from the departures and arrivals of every step (no call into SUMO)."""
        return list(self._running)

    @_traci
    def train_ids(self) -> list[str]:
        """SUMO's own list of the trains in the network (one call; :meth:`running` is the same list)."""
        return list(self._ls.vehicle.getIDList())

    @_traci
    def observe_all(self, ids: list[str]) -> list[tuple[str, float, float, float, float, int]]:
        """(edge, lane position m, speed m/s, acceleration m/s², odometer m, route index) of each
        train in ``ids`` — the values :meth:`observe` gives, read in one go."""
        road, pos, speed, accel, odo, index = self._get
        return [(road(vid), pos(vid), speed(vid), accel(vid), odo(vid), index(vid)) for vid in ids]

    @_traci
    def leaders(self, ids: list[str], lookahead_m: float) -> list[tuple[str, float] | None]:
        """:meth:`leader` of each train in ``ids``."""
        get, min_gap = self._get_leader, self._min_gap
        out: list[tuple[str, float] | None] = []
        for vid in ids:
            res = get(vid, lookahead_m)
            if not res or not res[0]:
                out.append(None)
            else:
                g = min_gap.get(vid)
                if g is None:
                    g = min_gap[vid] = self._get_min_gap(vid)
                out.append((res[0], res[1] + g))
        return out

    @_traci
    def observe(self, vid: str) -> TrainObservation:
        v = self._ls.vehicle
        return TrainObservation(
            id=vid, edge=v.getRoadID(vid), lane_pos_m=v.getLanePosition(vid), speed_mps=v.getSpeed(vid),
            accel_mps2=v.getAcceleration(vid), odometer_m=v.getDistance(vid), route_index=v.getRouteIndex(vid),
            type_id=v.getTypeID(vid),
        )

    @_traci
    def leader(self, vid: str, lookahead_m: float) -> tuple[str, float] | None:
        """(leader id, gap front-to-rear in m) within ``lookahead_m`` on the route ahead, or None."""
        res = self._ls.vehicle.getLeader(vid, lookahead_m)
        if not res or not res[0]:
            return None
        lid, gap = res
        return lid, gap + self._ls.vehicle.getMinGap(vid)

    def route_leader(self, vid: str, others: list[tuple[str, str, float, float]], lookahead_m: float) -> tuple[str, float] | None:
        """The nearest train ahead on ``vid``'s remaining route by driving distance: (id, gap
        front-to-rear in m) or None.  ``others``: (id, edge, front position on the edge, length).

        SUMO's getLeader only searches as far as its lane look-ahead reaches, which on long rail
        routes can stop kilometres short of the train ahead; this is the fallback (one driving
        distance per other train: :meth:`route_leader_indexed` finds the candidates from the route).
        """
        best: tuple[str, float] | None = None
        for oid, edge, pos, length in others:
            if oid == vid:
                continue
            if edge.startswith(":"):
                edge, pos, length = self.crossing(oid, pos, length)
            d = self.driving_distance(vid, edge, pos)
            if d is None or d <= 0.0:
                continue
            gap = d - length
            if gap <= lookahead_m and (best is None or gap < best[1]):
                best = (oid, gap)
        return best

    @_traci
    def crossing(self, vid: str, pos: float, length: float) -> tuple[str, float, float]:
        """A train whose front is ``pos`` into a junction's internal lane, as a candidate train ahead:
        (the route edge it is leaving, that edge's end, its length less ``pos``) — the same gap to
        its rear as its front's (a train crossing a junction stays the train ahead)."""
        edge = self._ls.vehicle.getRoute(vid)[self._ls.vehicle.getRouteIndex(vid)]
        end = self._edge_length.get(edge)
        if end is None:
            end = self._edge_length[edge] = self._ls.lane.getLength(f"{edge}_0")
        return edge, end, length - pos

    @_traci
    def train_length(self, vid: str) -> float:
        """The train's length in SUMO (its vType's), m."""
        return self._get_length(vid)

    @_traci
    def edge_length(self, edge: str) -> float:
        """Length of a (single-lane) edge in SUMO's network, m."""
        end = self._edge_length.get(edge)
        if end is None:
            end = self._edge_length[edge] = self._ls.lane.getLength(f"{edge}_0")
        return end

    @_traci
    def junction_passage(self, from_edge: str, to_edge: str) -> list[tuple[str, float]]:
        """The junction's internal lanes a train runs over from ``from_edge`` onto ``to_edge``: (internal
        edge id, length m) in running order (empty where the edges meet without one)."""
        lane = self._ls.lane
        out: list[tuple[str, float]] = []
        via = next((link[4] for link in lane.getLinks(f"{from_edge}_0") if link[0] == f"{to_edge}_0"), "")
        while via:
            out.append((lane.getEdgeID(via), lane.getLength(via)))
            via = next((link[4] or link[0] for link in lane.getLinks(via) if link[0].startswith(":") or link[4]), "")
        return out

    @_traci
    def route_leader_indexed(self, vid: str, s_m: float, route: list[str], starts_m: list[float], index: int,
                             on_edge: dict[str, list[tuple[str, float, float]]], max_length_m: float, lookahead_m: float) -> tuple[str, float] | None:
        """:meth:`route_leader` with the candidates taken from the route instead of from every train.

        ``s_m``: ``vid``'s front on its route (``starts_m``: where each edge of ``route`` starts);
        ``index``: its route index; ``on_edge``: the trains on each normal edge this step as (id,
        front position on the edge, length); ``max_length_m``: the longest train.  The edges ahead are
        walked as far as a train on them could be within the look-ahead; the trains found are
        ranked by their gap on the route (which leaves out the junctions' internal lanes, so it
        is at most SUMO's driving distance, the more so the farther the train), and SUMO's driving
        distance decides among those that can be nearest: the same answer as :meth:`route_leader`.
        """
        if index < 0:
            return None
        return self.nearest_candidate(vid, self.walk_route(vid, s_m, route, starts_m, index, on_edge, max_length_m, lookahead_m)[0], lookahead_m)

    @staticmethod
    def walk_route(vid: str, s_m: float, route: list[str], starts_m: list[float], index: int, on_edge: dict[str, list[tuple[str, float, float]]],
              max_length_m: float, lookahead_m: float) -> tuple[list[tuple[float, str, str, float, float]], int]:
        """The candidates on the route from edge ``index`` on (approximate gap, id, edge, position,
        length) and the first edge not looked at."""
        cands: list[tuple[float, str, str, float, float]] = []
        reach = lookahead_m + max_length_m + 1.0
        best_approx = math.inf
        k = index
        for k in range(index, len(route)):
            ahead = starts_m[k] - s_m
            if ahead > reach or ahead - max_length_m > best_approx + 100.0:
                return cands, k
            for oid, pos, length in on_edge.get(route[k], ()):
                if oid == vid or ahead + pos < -50.0:  # (a train more than 50 m behind on the same edge)
                    continue
                approx = ahead + pos - length
                cands.append((approx, oid, route[k], pos, length))
                if ahead + pos > 0.0 and approx < best_approx:
                    best_approx = approx
        return cands, len(route)

    def nearest_candidate(self, vid: str, cands: list[tuple[float, str, str, float, float]], lookahead_m: float) -> tuple[str, float] | None:
        """The candidate with the smallest gap by SUMO's driving distance (within the look-ahead)."""
        if not cands:
            return None
        if len(cands) > 1:
            cands.sort(key=lambda c: c[0])
        best: tuple[str, float] | None = None
        driving = self.get_driving_distance
        for approx, oid, edge, pos, length in cands:
            if best is not None and approx > best[1] + 1.0:
                break
            d = driving(vid, edge, pos)
            if d <= INVALID_DISTANCE + 1 or d < -1e8 or d <= 0.0:
                continue
            gap = d - length
            if gap <= lookahead_m and (best is None or gap < best[1]):
                best = (oid, gap)
        return best

    @_traci
    def driving_distance(self, vid: str, edge: str, pos: float) -> float | None:
        d = self._ls.vehicle.getDrivingDistance(vid, edge, pos)
        return None if d <= INVALID_DISTANCE + 1 or d < -1e8 else d

    # ----------------------------------------------------------------------------- commands
    @_traci
    def set_type(self, vid: str, type_id: str) -> None:
        self._ls.vehicle.setType(vid, type_id)
        self._min_gap[vid] = self._get_min_gap(vid)

    @_traci
    def set_speed(self, vid: str, speed_mps: float) -> None:
        """Command a speed for the next step (−1 gives control back to SUMO)."""
        self._ls.vehicle.setSpeed(vid, speed_mps)

    @_traci
    def set_speed_mode(self, vid: str, mode: int) -> None:
        self._ls.vehicle.setSpeedMode(vid, mode)

    @_traci
    def release(self, vid: str) -> None:
        """Hand a train back to SUMO's own driver."""
        self._ls.vehicle.setSpeedMode(vid, SPEED_MODE_DEFAULT)
        self._ls.vehicle.setSpeed(vid, -1)

    @_traci
    def at_stop(self, vid: str) -> bool:
        """The train stands at one of its stops (SUMO holds it there for its dwell)."""
        return bool(self._ls.vehicle.getStopState(vid) & 1)

    @_traci
    def resume(self, vid: str) -> None:
        """End a train's current stop (its dwell) if it is standing at one."""
        if self._ls.vehicle.getStopState(vid) & 1:
            self._ls.vehicle.resume(vid)

    @_traci
    def hold_stop(self, vid: str, until_s: float) -> None:
        """The train's present stop does not end before ``until_s`` (its remaining duration — what
        SUMO's stop reports and takes as ``duration`` — lengthened; never shortened)."""
        stops = self._ls.vehicle.getStops(vid, 1)
        rest = until_s - self._ls.simulation.getTime()
        if stops and stops[0].arrival >= 0.0 and rest > stops[0].duration + 1e-6:
            self._ls.vehicle.setStopParameter(vid, 0, "duration", f"{rest:.3f}")

    @_traci
    def hold_insertion(self, signal: str, vid: str, hold: bool) -> None:
        """Keep a train not yet in the network from being inserted in front of ``signal`` (an
        insertion constraint on a foe that never comes), or let it be inserted again."""
        if hold:
            self._ls.trafficlight.addConstraint(signal, vid, signal, INSERTION_HOLD, 1, 1)
        else:
            self._ls.trafficlight.removeConstraints(signal, vid, signal, INSERTION_HOLD)

    @_traci
    def add_constraint(self, signal: str, train: str, foe_signal: str, foe: str) -> None:
        """Rail-signal constraint: ``train`` may pass ``signal`` only after ``foe`` passed ``foe_signal``."""
        self._ls.trafficlight.addConstraint(signal, train, foe_signal, foe, 0, 1)

    # ----------------------------------------------------------------------------- safety events
    @_traci
    def collisions(self) -> list[tuple[str, str]]:
        """(collider, victim) pairs of this step."""
        return [(c.collider, c.victim) for c in self._ls.simulation.getCollisions()]

    @_traci
    def emergency_stops(self) -> list[str]:
        """Trains SUMO stopped within one step this step ('performs emergency stop': at the end of a
        lane, e.g. a red signal passed at speed or the end of the track)."""
        return list(self._ls.simulation.getEmergencyStoppingVehiclesIDList())

    @_traci
    def teleports(self) -> list[str]:
        return list(self._ls.simulation.getStartingTeleportIDList())

    @_traci
    def signal_states(self) -> dict[str, str]:
        tl = self._ls.trafficlight
        return {t: tl.getRedYellowGreenState(t) for t in tl.getIDList()}


def sumo_args(
    net_file: Path, route_file: Path, additional: list[Path], out: Path, step_length: float, end_time: float,
    moving_block: bool, seed: int = 42, fcd_period: float = 1.0, full_outputs: bool = True, fcd: bool = False,
) -> list[str]:
    """SUMO options for a vcsumo run (also written into the results' .sumocfg).  ``full_outputs``:
    the rail-signal output; ``fcd``: SUMO's fcd output too (vcsumo's trajectories.csv holds the same samples)."""
    args = [
        "-n", str(net_file), "-r", str(route_file), "-a", ",".join(str(a) for a in additional),
        "--step-length", f"{step_length}", "--end", f"{end_time}", "--seed", str(seed),
        "--time-to-teleport", "-1", "--collision.action", "warn", "--collision.check-junctions", "true",
        "--collision.mingap-factor", "0",
        "--no-step-log", "true", "--duration-log.disable", "true", "--default.speeddev", "0",
        "--message-log", str(out / "sumo_messages.log"), "--aggregate-warnings", "3",
        "--tripinfo-output", str(out / "tripinfo.xml"), "--stop-output", str(out / "stops.xml"),
    ]
    if fcd:
        args += [
            "--fcd-output", str(out / "fcd.xml"), "--device.fcd.period", f"{fcd_period}",
            "--fcd-output.distance", "true", "--fcd-output.acceleration", "true",
        ]
    if full_outputs:
        args += ["--railsignal-vehicle-output", str(out / "railsignal_vehicles.xml")]
    if moving_block:
        args += ["--railsignal-moving-block", "true"]
    return args


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def is_valid_distance(d: float) -> bool:
    return d > -1e8 and not math.isnan(d)
