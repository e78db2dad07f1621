"""Junction study (convoy merge and split at speed): junction choice, bad input, and real SUMO runs
on a small line with a merging and a diverging interconnection."""

from __future__ import annotations

import math

import pandas as pd
import pytest
from click.testing import CliRunner

from vcsumo.cli.junction import junction_cmd
from vcsumo.errors import InputError, VcsumoError
from vcsumo.line import load_line
from vcsumo.studies.junction import JUNCTION_COLUMNS, default_junctions, merge_direction, partner_junction, resolve_junctions

from .conftest import write

# 40 km at 250 km/h; 'west' merges into up at km 8 (160 km/h turnout), 'east' diverges from up at km 28
# (100 km/h turnout): up merges at west and splits at east, down merges at east and splits at west.
TWO_JUNCTIONS = """
name: jtest
title: A 40 km double-track line with a merging and a diverging interconnection
km_start: 0.0
km_end: 40.0
tracks: double
start_elevation_m: 50
line_speed_kmh: 250
default_train: etr1000
stations:
  - {id: AAA, name: Alpha, km: 0.3, platform_length_m: 400, dwell_s: 60}
  - {id: ZZZ, name: Zulu, km: 39.7, platform_length_m: 400, dwell_s: 60}
signalling: {block_length_m: 1500}
branches:
  - {id: west, name: West interconnection, junction_km: 8.0, leaves_towards: start, length_m: 4000, speed_kmh: 160, diverging_speed_kmh: 160}
  - {id: east, name: East interconnection, junction_km: 28.0, leaves_towards: end, length_m: 3000, speed_kmh: 160, diverging_speed_kmh: 100}
"""

# one branch leaving towards the end: trains diverge from up (split only) and merge into down (merge only)
ONE_JUNCTION = """
name: jone
title: A 24 km line with one spur
km_start: 0.0
km_end: 24.0
tracks: double
start_elevation_m: 50
line_speed_kmh: 200
default_train: etr1000
stations:
  - {id: AAA, name: Alpha, km: 0.4, platform_length_m: 400, dwell_s: 60}
  - {id: ZZZ, name: Zulu, km: 23.6, platform_length_m: 400, dwell_s: 60}
signalling: {block_length_m: 1500}
branches:
  - {id: spur, name: Spur line, junction_km: 12.0, leaves_towards: end, length_m: 4000, speed_kmh: 120, diverging_speed_kmh: 80}
"""

EMERGENCY_DECEL = 1.2  # etr1000


def test_junctions_are_chosen_from_the_line_file():
    mibo = load_line("milano_bologna")
    venezia = mibo.branch("venezia")
    assert merge_direction(venezia) == "up"  # leaves towards the start (Bologna): merges into up
    assert merge_direction(mibo.branch("parma")) == "down"
    # up: merge at Bivio Venezia, split at the next junction diverging from up (Parma); down: the reverse
    assert partner_junction(mibo, venezia, "up").id == "parma"
    assert partner_junction(mibo, venezia, "down").id == "parma"
    assert default_junctions(mibo) == ["venezia"]
    fibo = load_line("firenze_bologna")
    sr = fibo.branch("san_ruffillo")
    assert merge_direction(sr) == "up"  # Bivio Emilia: merges into up, diverges from down
    assert partner_junction(fibo, sr, "up") is None and partner_junction(fibo, sr, "down") is None
    assert default_junctions(fibo) == ["san_ruffillo"]
    assert resolve_junctions(mibo, "branch:parma,modena") == ["parma", "modena"]
    assert len(resolve_junctions(mibo, "all")) == len(mibo.data.branches)


def test_bad_junction_input_names_the_file_and_field(tmp_path):
    mibo = load_line("milano_bologna")
    with pytest.raises(InputError) as e:
        resolve_junctions(mibo, "bivio_nowhere")
    msg = str(e.value)
    # the request's error (the option, or the study file's field), naming the line file whose branches it lists
    assert "--junction" in msg and str(mibo.path) in msg and "bivio_nowhere" in msg and "venezia" in msg
    felez = load_line("felez_test")
    with pytest.raises(InputError) as e:
        resolve_junctions(felez, None)
    assert str(felez.path) in str(e.value) and "branches" in str(e.value) and "no branches" in str(e.value)
    # the command: one error, no results folder
    out = tmp_path / "res"
    r = CliRunner().invoke(junction_cmd, ["--line", "milano_bologna", "--junction", "bivio_nowhere", "--out", str(out)])
    assert r.exit_code != 0 and isinstance(r.exception, VcsumoError) and "bivio_nowhere" in str(r.exception)
    r = CliRunner().invoke(junction_cmd, ["--line", "felez_test", "--out", str(out)])
    assert isinstance(r.exception, InputError) and "branches" in str(r.exception)
    r = CliRunner().invoke(junction_cmd, ["--line", "firenze_bologna", "--controllers", "warp-drive", "--out", str(out)])
    assert isinstance(r.exception, VcsumoError) and "warp-drive" in str(r.exception)
    r = CliRunner().invoke(junction_cmd, ["--line", "firenze_bologna", "--offsets", "0,ten", "--out", str(out)])
    assert isinstance(r.exception, InputError) and "--offsets" in str(r.exception)
    assert not out.exists()


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """The command on the two-junction line: branch service leads, FBS, MB, VC cbc with both signal variants."""
    tmp = tmp_path_factory.mktemp("junction")
    line = write(tmp / "jtest" / "line.yaml", TWO_JUNCTIONS)
    out = tmp / "out"
    junction_cmd.main(["--line", str(line), "--junction", "west", "--first", "branch", "--controllers", "cbc", "--junction-signal", "both", "--offsets", "0,15,30,60",
                       "--approach-m", "6000", "--out", str(out)], standalone_mode=False)
    return out, pd.read_csv(out / "junction.csv")


@pytest.mark.sumo
def test_study_writes_tables_and_plots(study):
    out, df = study
    for f in ("junction.csv", "junction_sweep.csv", "junction_trajectories.csv", "junction_signals.csv", "junction_fbs.png", "junction_mb.png",
              "junction_vc.png", "junction_sweep.png", "meta.json"):
        assert (out / f).is_file(), f
    assert list(df.columns) == JUNCTION_COLUMNS
    assert len(df) == 8  # 2 directions × (fbs, mb, vc cbc sumo, vc cbc braking-curve)
    assert set(df.junction_kind[df.direction == "up"]) == {"merge"} and set(df.junction_kind[df.direction == "down"]) == {"split"}
    assert (df.merge_junction[df.direction == "up"] == "west").all() and (df.split_junction[df.direction == "up"] == "east").all()
    traj = pd.read_csv(out / "junction_trajectories.csv")
    assert {"distance_to_merge_m", "distance_to_split_m", "speed_mps", "virtual_gap_m", "sensed_gap_m", "time_s"} <= set(traj.columns)
    assert set(traj.run) >= {"solo", "simultaneous", "merge_min"}


@pytest.mark.sumo
def test_vc_merges_closer_and_lets_more_trains_through(study):
    _, df = study
    for d, g in df.groupby("direction"):
        r = {(x.regime, x.junction_signal if isinstance(x.junction_signal, str) else ""): x for _, x in g.iterrows()}
        fbs, mb, vc, vcb = r[("fbs", "")], r[("mb", "")], r[("vc", "sumo")], r[("vc", "braking-curve")]
        # junction throughput through the merge: VC >= MB >= FBS (and MB strictly above FBS)
        assert vc.merge_throughput_trains_per_h >= mb.merge_throughput_trains_per_h > fbs.merge_throughput_trains_per_h, d
        assert vcb.merge_throughput_trains_per_h >= mb.merge_throughput_trains_per_h, d
        # the merged pair ends closer under VC than under MB, and the merging service loses less
        assert vc.formed_gap_m < mb.formed_gap_m < fbs.formed_gap_m, d
        assert vc.merging_service_delay_s < mb.merging_service_delay_s < fbs.merging_service_delay_s, d
        # the convoy has to start forming before the junction
        assert vc.formation_start_m_before_merge > 0 and vc.formation_time_s > 0 and vc.formation_distance_m > 0, d
        for x in (fbs, mb, vc, vcb):
            assert x.collisions == 0 and x.order_kept, (d, x.regime)
            assert x.max_overspeed_mps < 1.5, (d, x.regime)  # VC followers brake for the turnouts too
        # the red merge signal: SUMO-driven trains brake for it at their service rate; the braking-curve
        # variant keeps the VC follower able to stop with its emergency brake; the plain mode-26 follower
        # needs at least as much
        for x in (fbs, mb):
            assert x.merge_red_max_required_decel_mps2 < 0.7, (d, x.regime)
        assert vcb.merge_red_max_required_decel_mps2 <= EMERGENCY_DECEL + 0.02 and vcb.junction_signal_overruns == 0, d
        assert vc.merge_red_max_required_decel_mps2 >= vcb.merge_red_max_required_decel_mps2 - 1e-6, d
    up = df[(df.direction == "up") & (df.regime == "vc") & (df.junction_signal == "sumo")].iloc[0]
    # the leader diverges at east and slows to 100 km/h in front of its coupled follower
    assert up.split_is_bottleneck and up.split_min_offset_s > up.merge_min_offset_s


@pytest.mark.sumo
def test_every_case_is_healthy_in_every_regime(study):
    """Issue 11: the merges are violation-free in every regime, FBS included — over every simulation
    of every case (sweep probes and analysis runs), counted by the run-health monitor from the first
    step; and the junction's own minimum offset is never above the one through the merge check
    point, which adds forming up on the trunk (lost time only grows along the route)."""
    out, df = study
    cols = ["gap_violations_all_runs", "collisions_all_runs", "authority_overruns", "overspeed_events", "sumo_emergency_stops", "teleports"]
    for _, x in df.iterrows():
        assert x.healthy and x.unhealthy_runs == 0 and x.min_margin_m >= 0.0, (x.direction, x.regime, x.junction_signal)
        assert {c: x[c] for c in cols} == {c: 0 for c in cols}, (x.direction, x.regime, x.junction_signal)
        assert x.assumptions == "etcs_typical"
    sweep = pd.read_csv(out / "junction_sweep.csv")
    assert sweep.healthy.all() and (sweep.min_margin_m >= 0.0).all()
    merges = df[df.junction_kind == "merge"]
    assert len(merges) and (merges.junction_throughput_trains_per_h == merges.merge_junction_throughput_trains_per_h).all()
    assert (merges.merge_junction_min_offset_s <= merges.merge_min_offset_s + 1.0).all()


@pytest.mark.sumo
def test_violations_and_signals_are_counted_from_the_runs(study):
    out, df = study
    sig = pd.read_csv(out / "junction_signals.csv")
    for _, x in df.iterrows():
        slug = f"west_{x.direction}_branch-first_{x.regime}" + (f"_cbc_{x.junction_signal}" if x.regime == "vc" else "")
        runs = list((out / "runs" / f"west_{x.direction}" / slug).glob("simultaneous_o*"))
        assert len(runs) == 1, slug
        v = pd.read_csv(runs[0] / "violations.csv")
        assert x.gap_violations == len(v), slug
        assert x.gap_violations_merge + x.gap_violations_split <= x.gap_violations
        # the merge signal was red for the merging service at some point of the simultaneous run
        s = sig[(sig.direction == x.direction) & (sig.regime == x.regime) & (sig.run == "simultaneous") & (sig.junction_kind == "merge")]
        if x.regime == "vc":
            s = s[s.junction_signal == x.junction_signal]
        assert ((s.role == "follower") & (s.aspect == "red")).any(), slug


@pytest.mark.sumo
def test_split_only_and_merge_only_directions(tmp_path):
    from vcsumo.sim.network import build_network
    from vcsumo.rolling_stock import load_rolling_stock
    from vcsumo.studies.junction import run_junction_study

    line = load_line(write(tmp_path / "jone" / "line.yaml", ONE_JUNCTION))
    df = run_junction_study(line, build_network(line), load_rolling_stock("etr1000"), tmp_path / "out", controllers=[], firsts=("branch",),
                            offsets_s=(0.0, 30.0, 60.0), approach_m=6000.0, post_m=8000.0)
    assert set(df.regime) == {"fbs", "mb"}
    up = df[df.direction == "up"]  # split only: both start on the main line, the branch service leads and diverges
    assert (up.merge_junction.isna() | (up.merge_junction == "")).all() and (up.junction_kind == "split").all()
    assert up.split_throughput_trains_per_h.notna().all() and up.formation_start_m_before_merge.isna().all()
    down = df[df.direction == "down"]  # merge only: the pair runs on to the end of the window
    assert (down.junction_kind == "merge").all() and down.merge_throughput_trains_per_h.notna().all()
    assert down.split_throughput_trains_per_h.isna().all()
    for _, x in df.iterrows():
        assert x.collisions == 0 and not math.isnan(x.junction_throughput_trains_per_h)
        assert x.healthy and x.gap_violations_all_runs == 0, (x.direction, x.regime)  # the split pair is released at the regime's own separation
    mb, fbs = (df[(df.direction == "up") & (df.regime == r)].iloc[0] for r in ("mb", "fbs"))
    assert mb.split_throughput_trains_per_h > fbs.split_throughput_trains_per_h


def test_junction_study_file_runs_the_command(in_tmp, capsys, root):
    from vcsumo.cli.main import main
    from vcsumo.cli.study_files import load_study

    # the shipped files map onto the parameters of `vcsumo study junction`
    st = load_study(root / "vcsumo" / "data" / "studies" / "junction_milano_bologna.yaml")
    values = st.command_values()
    assert values["junctions"] == "venezia" and values["variants"] == "braking-curve"
    # through `vcsumo study run`: a bad junction id is one error naming the line file and field, exit 2, no folder
    f = write(in_tmp / "j.yaml", "study: junction\nline: milano_bologna\njunction: bivio_nowhere\nout: res\n")
    assert main(["study", "run", str(f)]) == 2
    err = capsys.readouterr().err
    assert str(f) in err and "junction:" in err and "line.yaml" in err and "branches" in err and "bivio_nowhere" in err
    assert not (in_tmp / "res").exists() and not list(in_tmp.glob("res*"))
    # an unknown key in the study file
    f = write(in_tmp / "k.yaml", "study: junction\nline: firenze_bologna\njunction_sigal: sumo\n")
    assert main(["study", "run", str(f)]) == 2
    assert "junction_sigal" in capsys.readouterr().err
