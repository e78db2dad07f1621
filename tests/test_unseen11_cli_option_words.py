"""Eleventh round of unseen inputs — two option errors that did not name what the user typed.

``vcsumo study junction --controllers zz`` said ``error: --controller: unknown controller 'zz'`` (an
option the junction study does not have), and ``vcsumo study tradeoff --convoy-sizes 1`` said
``error: --convoy-sizes: Input should be greater than or equal to 2 (0)`` — "(0)" is the list index,
read as the value. Now the option is the one given, and the value is named by its place and itself,
as ``--delays`` already did (``value 1 (-1): …``).
"""

from vcsumo.cli.main import main


def test_junction_controllers_names_its_own_option(in_tmp, capsys):
    assert main(["study", "junction", "--line", "regional_graded", "--controllers", "cbc,zz", "--out", "r"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --controllers: unknown controller 'zz'"), err
    assert not (in_tmp / "r").exists()


def test_tradeoff_convoy_sizes_names_the_value(in_tmp, capsys):
    assert main(["study", "tradeoff", "--line", "felez_test", "--convoy-sizes", "3,1", "--out", "r"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: --convoy-sizes: value 2 (1): Input should be greater than or equal to 2", err
    assert not (in_tmp / "r").exists()
