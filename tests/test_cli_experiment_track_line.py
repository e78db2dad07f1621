"""An experiment file whose ``track.line`` names no line: one line naming the file and the field, not
an option the user never gave — until 2026-12-01 ``error: x.yaml: track.line.line: --line: unknown line
'nosuch' ...``."""

from __future__ import annotations

from vcsumo.cli.main import main

from .conftest import DATA


def test_an_unknown_track_line_names_the_field_not_an_option(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    text = (DATA / "studies" / "experiments" / "felez2019_sh.yaml").read_text()
    old = "  straight:\n    length_m: 4100.0\n    speed_limit_mps: 27.78"
    assert old in text
    path = tmp_path / "x.yaml"
    path.write_text(text.replace(old, "  line: {line: nosuch, direction: up, km_from: 1.0, km_to: 4.0}"))
    assert main(["experiment", str(path), "--out", "r"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {path}: track.line.line: unknown line 'nosuch' (shipped lines: ") and "--line" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.yaml"]
