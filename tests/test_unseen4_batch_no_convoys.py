"""Fourth round of unseen inputs — ``vcsumo batch --regimes fbs,mb,vc`` over timetables some of which
declare no convoys (found running the README's batch command on a suburban line of our own: an
all-stops timetable and a timetable of pairs). Every vc run of a timetable without convoys failed
after the others had run ("the vc regime needs at least one convoy"), and the batch exited 1 with
"4 of 18 runs ... failed" — an input problem known before anything ran, and the README's own example
(``--timetables 'vcsumo/data/routes/L/*.yaml' --regimes fbs,mb,vc``) hits it on every shipped line
(only ``convoy.yaml`` has convoys). Now vc is not planned for such a timetable, with a warning naming
it; a batch left with no run at all is an input error (exit 2, nothing written)."""

import pytest

from vcsumo.cli.main import main
from vcsumo.delays import DelayConfig
from vcsumo.errors import InputError
from vcsumo.line import load_line
from vcsumo.studies.batch import plan_runs, resolve_timetables


def test_vc_is_planned_only_for_timetables_with_convoys(tmp_path):
    line = load_line("felez_test")
    tts = resolve_timetables("base,convoy", line)
    with pytest.warns(UserWarning, match=r"vc is not run for base\.yaml: no convoys"):
        specs = plan_runs(line, tts, ["fbs", "vc"], [1, 2], ["cbc"], DelayConfig(), tmp_path)
    assert sorted({(s.timetable, s.regime) for s in specs}) == [("base", "fbs"), ("convoy", "fbs"), ("convoy", "vc")]
    assert len(specs) == 6


def test_a_vc_batch_without_any_convoy_is_an_input_error(tmp_path):
    line = load_line("felez_test")
    with pytest.raises(InputError, match="no timetable of the batch has one"):
        plan_runs(line, resolve_timetables("base", line), ["vc"], [1], ["cbc"], DelayConfig(), tmp_path)


@pytest.mark.sumo
def test_the_cli_says_so_with_exit_2_and_writes_nothing(in_tmp, capsys):
    code = main(["batch", "--line", "felez_test", "--timetables", "base", "--regimes", "vc", "--seeds", "1", "--workers", "1", "--out", "b"])
    err = capsys.readouterr().err
    assert code == 2 and "base.yaml: convoys: the vc regime needs at least one convoy" in err
    assert not (in_tmp / "b").exists()
