"""CPU cost of vcsumo's simulation loop, by part, against a bare libsumo loop on the same scenario.

For each scenario the bench runs, in fresh child processes and one after the other (paired):

1. **vcsumo** — the loop of ``vcsumo run`` (:func:`vcsumo.sim.loop.simulate`, with the VC driver
   for vc): CPU time of the loop (setup — loading, planning, building the driver — reported apart),
   CPU time by part as the loop accounts it (``summary["loop_cpu_s"]``: SUMO stepping, observation,
   supervision, health, driver — channel, controllers, records —, recording, I/O), peak memory;
2. **bare** — a plain libsumo loop started from the ``scenario.sumocfg`` the vcsumo run wrote (so
   the same network, routes, step, end and SUMO outputs) that reads, for every running train at
   every step, the values vcsumo knows of it (road, lane position, speed, acceleration, odometer,
   route index with libsumo's extension getters, as vcsumo reads them, and the train ahead within
   30 km with the gap to its rear — SUMO's ``getLeader``; vcsumo finds the same from its own route
   index, :class:`vcsumo.sim.trains_ahead.TrainsAhead`, without a call into SUMO), and does nothing else;
3. **sumo** — the same libsumo loop reading nothing (SUMO's own cost, for reference).

It prints CPU seconds, CPU per simulated hour, CPU per 1,000 train-steps by part, the real-time
factor (simulated s per CPU s), the ratio vcsumo / bare, the peak resident memory of each child
and the load average before and after each run (the machine is shared: compare the paired ratios,
not the absolute times, across machines or loads).

Scenarios (``--scenarios``):

* ``fbs``, ``mb`` — italy_av_north ``full_day`` (384 trains, 05:09–23:45), the whole day;
* ``cbc``, ``cbf-cbc`` — italy_av_north ``full_day_vc`` under vc until ``--vc-end`` (default
  09:00, a window from the first departure); the figure for the day is extrapolated from the
  window by CPU per train-second and said so (``--vc-end 24:00`` runs the whole day instead);
* ``felez`` — felez_test ``convoy`` (12 trains, 6 coupled followers) under vc with cbc;
* ``felez-fbs`` — felez_test ``dense`` (20 trains) under fbs.

    python bench/bench_loop.py                                  # all scenarios (long: ~15 min)
    python bench/bench_loop.py --scenarios felez felez-fbs      # a quick look
    python bench/bench_loop.py --scenarios fbs --repeats 2
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SCENARIOS: dict[str, dict] = {
    "fbs": {"line": "italy_av_north", "timetable": "full_day", "regime": "fbs"},
    "mb": {"line": "italy_av_north", "timetable": "full_day", "regime": "mb"},
    "cbc": {"line": "italy_av_north", "timetable": "full_day_vc", "regime": "vc", "controller": "cbc", "window": True},
    "cbf-cbc": {"line": "italy_av_north", "timetable": "full_day_vc", "regime": "vc", "controller": "cbf-cbc", "window": True},
    "felez": {"line": "felez_test", "timetable": "convoy", "regime": "vc", "controller": "cbc"},
    "felez-fbs": {"line": "felez_test", "timetable": "dense", "regime": "fbs"},
}
PARTS = ("sumo", "observation", "supervision", "health", "driver", "channel", "controllers", "vc_records", "recording", "io")
LEADER_LOOKAHEAD_M = 30000.0


# ----------------------------------------------------------------------------------------------- children
def child_vcsumo(spec: dict, out: Path, end: str | None) -> dict:
    """Run the scenario with vcsumo's loop (as ``vcsumo run`` does) and return the figures."""
    c0 = time.process_time()
    from vcsumo.cli.commands import network
    from vcsumo.network_file import load_line_or_network
    from vcsumo.signalling.assumptions import load_assumptions
    from vcsumo.sim.loop import Scenario, simulate
    from vcsumo.timetable import load_timetable, plan_trains
    from vcsumo.units import parse_clock

    dt = 0.1 if spec["regime"] == "vc" else 0.5
    line = load_line_or_network(spec["line"])
    tt, tt_path = load_timetable(spec["timetable"], line)
    net = network(line, None)
    trains = plan_trains(tt, tt_path, line, net.topology, dt=dt)
    aset = load_assumptions(None)
    driver = None
    if spec["regime"] == "vc":
        from vcsumo.sim.vc_driver import make_vc_driver

        driver = make_vc_driver(tt, tt_path, trains, spec["controller"], dt, 42, assumptions=aset)
    end_s = parse_clock(end) if end else None
    scn = Scenario(line, net, trains, spec["regime"], step_length_s=dt, seed=42, driver=driver, end_time_s=end_s, assumptions=aset)
    setup = time.process_time() - c0
    c1 = time.process_time()
    res = simulate(scn, out)
    if driver is not None:
        w0 = time.process_time()
        driver.write_report(out)
        vc_io = time.process_time() - w0
        res.summary.update(driver.summary())
    else:
        vc_io = 0.0
    cpu = time.process_time() - c1
    s = res.summary
    begin = min(t.depart_s for t in trains) // 1
    # planned train-seconds (open ends: the route at 87 % of the line speed), all day and in the window run
    spans = [(t.depart_s, t.scheduled_arrival_s if t.scheduled_arrival_s is not None
              else t.depart_s + 1.15 * t.profile.length_m / min(t.stock.max_speed_ms, t.profile.max_speed())) for t in trains]
    planned_day = sum(b - a for a, b in spans)
    planned_window = sum(max(0.0, min(b, s["simulated_until_s"]) - max(a, begin)) for a, b in spans)
    parts = dict(s.get("loop_cpu_s") or {})
    if parts:
        parts["io"] = parts.get("io", 0.0) + vc_io
    return {
        "cpu_s": cpu, "setup_cpu_s": setup, "parts": parts, "simulated_s": s["simulated_until_s"] - begin,
        "planned_train_s_day": planned_day, "planned_train_s_window": planned_window, "begin_s": begin, "last_arrival_s": max(b for _, b in spans),
        "train_steps": s.get("train_steps"), "steps": s.get("steps"), "trains": s["trains"], "arrived": s["trains_arrived"],
        "healthy": s["healthy"], "coupled_steps": s.get("coupled_steps"), "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def child_bare(cfg: Path, read: bool) -> dict:
    """A plain libsumo loop on a vcsumo run's scenario.sumocfg (outputs go to replay-* files)."""
    import xml.etree.ElementTree as ET

    from vcsumo.sim.sumo_paths import sumo_binary, sumo_home

    sumo_home()
    import libsumo

    root = ET.parse(cfg).getroot()
    end = float(root.find("end").get("value"))
    os.chdir(cfg.parent)
    libsumo.start([sumo_binary("sumo"), "-c", cfg.name, "--no-warnings", "true"])
    v = libsumo.vehicle
    raw = getattr(libsumo, "_libsumo", None)

    def pick(name: str):  # the extension's getters, as vcsumo's SumoBackend calls them
        return getattr(raw, f"vehicle_{name}", None) or getattr(v, name)

    road, pos, speed, accel, odo, index, leader = (pick(n) for n in ("getRoadID", "getLanePosition", "getSpeed", "getAcceleration", "getDistance",
                                                                     "getRouteIndex", "getLeader"))
    c0 = time.process_time()
    begin = libsumo.simulation.getTime()
    steps = train_steps = 0
    t = begin
    while True:
        libsumo.simulationStep()
        t = libsumo.simulation.getTime()
        steps += 1
        ids = v.getIDList()
        train_steps += len(ids)
        if read:
            for vid in ids:
                road(vid), pos(vid), speed(vid), accel(vid), odo(vid), index(vid)
                leader(vid, LEADER_LOOKAHEAD_M)
        if libsumo.simulation.getMinExpectedNumber() == 0 or t >= end - 1e-9:
            break
    cpu = time.process_time() - c0
    libsumo.close()
    return {"cpu_s": cpu, "simulated_s": t - begin, "steps": steps, "train_steps": train_steps,
            "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


# ----------------------------------------------------------------------------------------------- parent
def _child(argv: list[str]) -> dict:
    load0 = os.getloadavg()
    p = subprocess.run([sys.executable, __file__, "--child", *argv], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"child {' '.join(argv)} failed:\n{p.stderr[-3000:]}")
    res = json.loads(p.stdout.strip().splitlines()[-1])
    res["load"] = (load0[0], os.getloadavg()[0])
    return res


def _fmt_parts(parts: dict, train_steps: int) -> str:
    if not parts or not train_steps:
        return "    (no loop_cpu_s in the summary: this loop does not account its parts)"
    k = 1000.0 / train_steps
    items = [(p, parts[p]) for p in PARTS if parts.get(p)] + [(p, x) for p, x in parts.items() if p not in PARTS and x]
    total = sum(x for _, x in items)
    rows = [f"    {p:<12} {x:8.2f} s {1000 * x * k:8.3f} ms/1k train-steps {100 * x / total:5.1f} %" for p, x in items]
    return "\n".join(rows)


def run_scenario(name: str, spec: dict, args, tmp: Path) -> None:
    end = None
    if spec.get("window"):
        end = args.vc_end
    out = tmp / name
    print(f"\n== {name}: {spec['line']} {spec['timetable']} {spec['regime']}{' ' + spec['controller'] if 'controller' in spec else ''}"
          f"{' until ' + end if end else ''}", flush=True)
    for rep in range(args.repeats):
        vs = _child(["vcsumo", name, str(out)] + ([end] if end else []))
        bare = _child(["bare", str(out / "scenario.sumocfg")])
        sumo = _child(["sumo", str(out / "scenario.sumocfg")]) if not args.no_sumo_alone else None
        sim_h = vs["simulated_s"] / 3600.0
        ts = vs["train_steps"] or bare["train_steps"]
        print(f"  run {rep + 1}: simulated {vs['simulated_s']:.0f} s ({sim_h:.2f} h), {vs['steps'] or bare['steps']} steps, {ts} train-steps, "
              f"{vs['arrived']}/{vs['trains']} arrived, healthy {vs['healthy']}")
        print(f"    vcsumo loop  CPU {vs['cpu_s']:8.2f} s  {vs['cpu_s'] / sim_h:7.2f} s per simulated h  {vs['simulated_s'] / vs['cpu_s']:7.1f}x real time  "
              f"{1e6 * vs['cpu_s'] / ts:7.2f} ms/1k train-steps  peak {vs['maxrss_mb']:.0f} MB  (setup {vs['setup_cpu_s']:.1f} s)  "
              f"load {vs['load'][0]:.2f}->{vs['load'][1]:.2f}")
        print(f"    bare libsumo CPU {bare['cpu_s']:8.2f} s  {bare['cpu_s'] / sim_h:7.2f} s per simulated h  {bare['simulated_s'] / bare['cpu_s']:7.1f}x real time  "
              f"{1e6 * bare['cpu_s'] / bare['train_steps']:7.2f} ms/1k train-steps  peak {bare['maxrss_mb']:.0f} MB  load {bare['load'][0]:.2f}->{bare['load'][1]:.2f}")
        if sumo is not None:
            print(f"    SUMO alone   CPU {sumo['cpu_s']:8.2f} s  {sumo['simulated_s'] / sumo['cpu_s']:7.1f}x real time  load {sumo['load'][0]:.2f}->{sumo['load'][1]:.2f}")
        print(f"    ratio vcsumo / bare {vs['cpu_s'] / bare['cpu_s']:.2f}" + (f", vcsumo / SUMO alone {vs['cpu_s'] / sumo['cpu_s']:.2f}" if sumo else ""))
        print("    by part (CPU, as the loop accounts it):")
        print(_fmt_parts(vs["parts"], ts))
        if end and vs["planned_train_s_window"] < 0.98 * vs["planned_train_s_day"]:
            day, window = vs["planned_train_s_day"], vs["planned_train_s_window"]
            cpu_day = vs["cpu_s"] * day / window
            print(f"    EXTRAPOLATED to the whole day (linear in planned train-seconds: window {window / 3600:.0f} of {day / 3600:.0f} train-h): "
                  f"CPU {cpu_day:.0f} s for the day's {day / 3600:.0f} train-h; the day's simulated span / CPU = "
                  f"{(vs['last_arrival_s'] - vs['begin_s']) / cpu_day:.0f}x real time")


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        kind = sys.argv[2]
        if kind == "vcsumo":
            res = child_vcsumo(SCENARIOS[sys.argv[3]], Path(sys.argv[4]), sys.argv[5] if len(sys.argv) > 5 else None)
        else:
            res = child_bare(Path(sys.argv[3]), read=kind == "bare")
        print(json.dumps(res))
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    ap.add_argument("--vc-end", default="09:00", help="end of the vc window (HH:MM; 24:00: the whole day)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--no-sumo-alone", action="store_true", help="skip the SUMO-alone reference run")
    ap.add_argument("--keep", type=Path, default=None, help="keep the results folders here (default: a temporary folder)")
    args = ap.parse_args()
    print(f"vcsumo loop bench; python {sys.version.split()[0]}, {os.cpu_count()} CPUs, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    with tempfile.TemporaryDirectory(prefix="vcsumo-bench-loop-") as tmp:
        base = args.keep or Path(tmp)
        base.mkdir(parents=True, exist_ok=True)
        for name in args.scenarios:
            run_scenario(name, SCENARIOS[name], args, base)


if __name__ == "__main__":
    main()
