"""A results folder the command cannot write: one line naming --out, exit 2, nothing written, and
before any work is done.

Until 2026-12-01 ``vcsumo run --out exists.txt`` (a file) said ``error: exists.txt: Not a
directory``, ``--out exists.txt/sub`` said ``error: exists.txt: File exists`` (it is a file, not
that it exists), and ``--out`` on a read-only file system said ``error: <out>.partial-<pid>:
Read-only file system`` after the network had been built and the trains planned (27 s on the
shared machine); ``batch`` said ``error: <out>: Read-only file system``.  None named the option.
A folder that is not empty is refused by ``run`` with the option named too."""

from __future__ import annotations

import os

import pytest

from vcsumo.cli.main import main

COMMANDS = {
    "run": ["run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs"],
    "batch": ["batch", "--line", "felez_test", "--timetables", "test", "--regimes", "fbs", "--seeds", "1", "--workers", "1"],
    "capacity": ["study", "capacity", "--line", "felez_test", "--directions", "up", "--patterns", "non-stop", "--convoy-sizes", "1", "--workers", "1"],
    "experiment": ["experiment", "felez2019_sh"],
}


def _one_error(capsys) -> str:
    """The one line on stderr (errors go there; under pytest, sys.stdout also gets the qpOASES banner
    that the command line sends to /dev/null at the file-descriptor level)."""
    lines = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_out_onto_a_file_names_the_option(command, tmp_path, capsys):
    f = tmp_path / "exists.txt"
    f.write_text("keep me")
    code = main([*COMMANDS[command], "--out", str(f)])
    line = _one_error(capsys)
    assert code == 2 and line == f"error: --out: {f} is a file, not a folder"
    assert f.read_text() == "keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["exists.txt"]


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_out_under_a_file_names_the_file_in_the_way(command, tmp_path, capsys):
    f = tmp_path / "exists.txt"
    f.write_text("keep me")
    code = main([*COMMANDS[command], "--out", str(f / "sub")])
    line = _one_error(capsys)
    assert code == 2 and line == f"error: --out: {f / 'sub'}: {f} is a file, not a folder"
    assert f.read_text() == "keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["exists.txt"]


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_out_in_a_folder_without_write_permission(command, tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("this user (root) may write into a 0o555 folder: no unwritable folder to test with")
        code = main([*COMMANDS[command], "--out", str(ro / "sub")])
        line = _one_error(capsys)
        assert code == 2 and line.startswith(f"error: --out: {ro / 'sub'}: cannot write into {ro} ")
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


def test_run_into_a_folder_that_is_not_empty_names_the_option(tmp_path, capsys):
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("x")
    code = main([*COMMANDS["run"], "--out", str(full)])
    line = _one_error(capsys)
    assert code == 2 and line.startswith(f"error: --out: {full}: output folder exists and is not empty")
    assert [p.name for p in full.iterdir()] == ["keep.txt"] and sorted(p.name for p in tmp_path.iterdir()) == ["full"]
