"""A train or station a user names ``NA`` is read back as ``NA`` from vcsumo's own CSVs (pandas'
default reading takes 'NA', 'N/A', 'null', 'None' … as missing: the train vanished from the run's
trajectories read back and from the plot's legend — noticed by unseen10)."""

from __future__ import annotations

from vcsumo.line import load_line
from vcsumo.plots.charts import plot_run
from vcsumo.sim.loop import Scenario, simulate
from vcsumo.sim.network import build_network
from vcsumo.timetable import load_timetable, plan_trains

from .conftest import write


def test_a_train_named_na_keeps_its_name_in_the_results_read_back(tmp_path):
    line = load_line("felez_test")
    net = build_network(line)
    tt, p = load_timetable(write(tmp_path / "na.yaml", "name: na\nline: felez_test\nservices:\n"
                                 "  - {id: NA, train: felez2019, origin: ORIG, destination: STOP, departure: 0}\n"
                                 "  - {id: 'null', train: felez2019, origin: ORIG, destination: STOP, departure: 120}\n"), line)
    trains = plan_trains(tt, p, line, net.topology)
    res = simulate(Scenario(line, net, trains, "fbs"), tmp_path / "run")
    traj = res.trajectories
    assert set(traj["train"]) == {"NA", "null"}
    assert traj.loc[traj["train"] == "null", "leader"].dropna().eq("NA").any()  # the train ahead, read back by name
    assert traj.loc[traj["train"] == "NA", "leader"].isna().all()  # nobody ahead: missing, as written (empty)
    fig = plot_run(tmp_path / "run" / "trajectories.csv", tmp_path / "td.png", infrastructure=tmp_path / "run" / "infrastructure.csv")
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend()] + list(fig.legends)
    legend = {t.get_text() for lg in legends for t in lg.get_texts()}
    assert {"NA", "null"} <= legend, legend
