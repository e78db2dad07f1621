"""Junction study: wall time per SUMO run, and the SUMO pitfalls at merges and splits reproduced with
the study's workarounds switched off one at a time.

1. ``mode-26 red``: a train driven through ``setSpeed`` under speed mode 26 (the VC follower's mode)
   at 160 km/h towards a red block signal (FBS, a slow train ahead): SUMO does not brake for the red
   but stops the train at the signal within one step (its warning gives the deceleration), and
   again at every step it is commanded on while the signal stays red.
2. ``first come``: Milano-Bologna, down, merge at Bivio Parma Est, the branch service leads a VC
   (cbc) convoy, without the planned merge order (``ordered=False``: the approach locking serves the
   junction first come, first served): the fast follower on the main line locks the junction first,
   but the locking never lets a convoy follower pass before its predecessor, so both runs agree
   (before that rule the two trains waited for each other and neither arrived).
3. ``no handshake``: Firenze-Bologna, up, merge at Bivio Emilia, branch service leads, the follower
   coupled as soon as the leader is inserted (no message received yet).
4. ``no speed profile``: Milano-Bologna, up, Bivio Venezia -> Bivio Parma Est, main service leads, the
   branch follower diverging at Parma without the braking curve to the turnout.

    python bench/bench_junction.py
"""

from __future__ import annotations

import platform
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path


def _red_stop_decels(folder: Path) -> list[float]:
    f = folder / "sumo_errors.log"
    if not f.is_file():
        return []
    return [abs(float(m.group(1))) for m in re.finditer(r"red traffic light \(decel=(-?[0-9.]+)", f.read_text())]


def mode26_red(tmp: Path) -> dict:
    """A commanded train (speed mode 26) meets a red block signal."""
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.route_profile import RouteProfile
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.timetable import PlannedTrain

    @dataclass
    class Constant:
        train: str
        speed_mps: float

        def make_step(self, snap):
            return {self.train: self.speed_mps} if self.train in snap.trains else {}

        def safe_gap_m(self, train_id: str) -> float:
            return 0.0

        def predecessor_of(self, train_id: str) -> None:
            return None

    line = load_line("firenze_bologna")
    net = build_network(line)
    topo = net.topology
    main = topo.track_for("main", "up").edges
    slow = load_rolling_stock("hcmc_l1")
    fast = load_rolling_stock("etr1000")
    trains = []
    for tid, stock, i0, dep, v0 in (("slow", slow, 18, 0.0, 10.0), ("commanded", fast, 12, 60.0, 44.0)):
        edges = main[i0:40]
        prof = RouteProfile.from_edges(topo, edges)
        pos = min(stock.length_m + 1.0, float(prof.lengths_m[0]))
        trains.append(PlannedTrain(tid, tid, stock, edges, prof, dep, pos, v0, "up", end_pos_m=None, start_s_m=pos, stop_at_end=False))
    res = simulate(Scenario(line, net, trains, "fbs", driver=Constant("commanded", 44.4), end_time_s=600.0), tmp / "mode26")
    d = _red_stop_decels(tmp / "mode26")
    from vcsumo.sim.sumo_io import read_sumo_log

    return {"case": "mode-26 red", "red_signal_stops": read_sumo_log(tmp / "mode26" / "sumo_errors.log").emergency_stops, "red_stop_decel_mps2": max(d) if d else float("nan"),
            "loop_emergency_brakes": res.summary["emergency_brakes"], "collisions": res.summary["collisions"]}


def study_case(tmp: Path, line_name: str, junction: str, direction: str, first: str, offset: float, label: str, **flags) -> list[dict]:
    from vcsumo.line import load_line
    from vcsumo.sim.network import build_network
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.studies import junction as J

    line = load_line(line_name)
    net = build_network(line)
    setup = J.build_setup(line, net, load_rolling_stock("etr1000"), junction, direction)
    solo = J.solo_runs(setup, "mb", 0.2, tmp / f"{label}_solo", 42)
    key = "M" if setup.merge is not None else "S"
    solo_times = {r: solo[r].passages[key][r] - solo[r].departures[r] for r in J.ROLES}
    links = J.signal_links(setup)
    case = J.Case(junction, direction, first, "vc", "cbc", "sumo")
    rows = []
    for name, fl in (("workaround on", {}), ("workaround off", flags)):
        t0 = time.perf_counter()
        rr = J.simulate_pair(setup, case, offset, solo_times, tmp / f"{label}_{name.replace(' ', '_')}", 0.2, 42, **fl)
        wall = time.perf_counter() - t0
        m = J.run_metrics(setup, case, rr, solo, links, 5000.0)
        follower = "main" if first == "branch" else "branch"
        red = _red_stop_decels(rr.folder)
        rows.append({"case": f"{label} ({name})", "offset_s": offset, "leader_lost_end_s": round(m["leader_lost_END_s"], 2),
                     "follower_lost_end_s": round(m["follower_lost_END_s"], 2), "order_kept": m["order_kept"],
                     "red_signal_stops": m["red_signal_stops"], "red_stop_decel_mps2": max(red) if red else float("nan"),
                     "loop_emergency_brakes": m["sumo_emergency_brakes"], "sumo_emergency_warnings": m["sumo_emergency_warnings"], "max_overspeed_mps": m["max_overspeed_mps"],
                     "follower_speed_at_split_mps": round(J.speed_at_trace(rr, follower, setup.s_split[follower]), 2) if setup.split else float("nan"),
                     "wall_s": round(wall, 2)})
    return rows


def main() -> None:
    import pandas as pd

    print(f"vcsumo junction study pitfalls — python {platform.python_version()} on {platform.machine()}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="vcsumo-bench-junction-") as d:
        tmp = Path(d)
        rows.append(mode26_red(tmp))
        for off in (0.0, 45.0):
            rows += study_case(tmp, "milano_bologna", "venezia", "down", "branch", off, f"first come Δ={off:g}", ordered=False)
        rows += study_case(tmp, "firenze_bologna", "san_ruffillo", "up", "branch", 0.0, "no handshake", link_warmup=False)
        rows += study_case(tmp, "milano_bologna", "venezia", "up", "main", 0.0, "no speed profile", speed_profile=False)
    pd.set_option("display.width", 250)
    pd.set_option("display.max_columns", 30)
    print(pd.DataFrame(rows).to_string(index=False))


if __name__ == "__main__":
    main()
