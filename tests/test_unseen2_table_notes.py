"""Tier 1 — the note under a table for an unhealthy row names the case (found with a capacity case
of freight trains that was not healthy: "not healthy: down non-stop vc cbc False False n=2", the
yes/no columns convoy_formed and healthy spelled out in place of nothing)."""

import pandas as pd

from vcsumo.cli.ui import build_table


def test_unhealthy_row_note_names_the_case_not_its_yes_no_columns():
    df = pd.DataFrame([{"direction": "down", "stopping_pattern": "non-stop", "regime": "vc", "controller": "cbc", "convoy_size": 2,
                        "headway_sim_s": 275.6, "convoy_formed": False, "healthy": False},
                       {"direction": "down", "stopping_pattern": "non-stop", "regime": "mb", "controller": None, "convoy_size": 1,
                        "headway_sim_s": 180.5, "convoy_formed": None, "healthy": True}])
    _, notes = build_table(df, "capacity")
    assert notes[0] == "not healthy: down non-stop vc cbc n=2" and len([n for n in notes if n.startswith("not healthy")]) == 1
