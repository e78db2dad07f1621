"""Tier 2 — a line file whose ``default_train`` is a train file next to it (found running studies on
a suburban line of our own from another folder): the file was looked for in the current folder, so
``vcsumo study tradeoff --line sub/suburb.yaml`` stopped with "default_train: train file 'emu.yaml'
not found" although it lay beside the line file (a timetable's train files are taken next to it)."""

from vcsumo.cli.main import main
from vcsumo.line import load_line

from .conftest import write
from .test_unseen2_safety_files import EMU, LINE


def test_a_default_train_file_next_to_the_line_file(in_tmp, capsys):
    write(in_tmp / "sub" / "suburb.yaml", LINE)
    write(in_tmp / "sub" / "emu.yaml", EMU)
    assert load_line("sub/suburb.yaml").data.default_train == str(in_tmp / "sub" / "emu.yaml")
    code = main(["study", "tradeoff", "--line", "sub/suburb.yaml", "--convoy-sizes", "2", "--out", "t"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert (in_tmp / "t" / "tradeoff.csv").is_file()


def test_a_default_train_file_missing_beside_the_line_is_still_an_error(in_tmp, capsys):
    write(in_tmp / "sub" / "suburb.yaml", LINE)
    assert main(["study", "tradeoff", "--line", "sub/suburb.yaml", "--convoy-sizes", "2", "--out", "t"]) == 2
    err = capsys.readouterr().err
    assert "default_train" in err and "emu.yaml" in err and not (in_tmp / "t").exists()
