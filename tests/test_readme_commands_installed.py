"""The README's commands work as written from any folder, as for a user who installed the wheel:
study files named by a path inside the source tree (``vcsumo study run
vcsumo/data/studies/capacity_firenze_bologna.yaml``) or a batch pattern ``'vcsumo/data/routes/L/*.yaml'``
exist only in a checkout — from an empty folder, until 2026-12-01, ``error: --timetables: no timetable
file matches 'vcsumo/data/routes/felez_test/*.yaml'`` and ``error: ...: file not found``.  README now
names shipped studies by name and the batch pattern relative to the data folder."""

from __future__ import annotations

import re
from pathlib import Path

from vcsumo.cli.study_files import shipped_or_path
from vcsumo.line import load_line
from vcsumo.studies.batch import resolve_timetables


def test_every_study_run_in_the_readme_resolves_from_an_empty_folder(root, tmp_path, monkeypatch):
    readme = (root / "README.md").read_text()
    monkeypatch.chdir(tmp_path)
    specs = set(re.findall(r"`vcsumo study run ([^`\s]+)", readme)) - {"X"}
    assert "capacity_hcmc_line1" in specs and len(specs) >= 3
    for spec in sorted(specs):
        assert shipped_or_path(Path(spec)).is_file(), spec


def test_the_readme_batch_pattern_matches_from_an_empty_folder(root, tmp_path, monkeypatch):
    readme = (root / "README.md").read_text()
    monkeypatch.chdir(tmp_path)
    patterns = re.findall(r"`vcsumo batch --line L --timetables '([^']+)'", readme)
    assert patterns
    line = load_line("felez_test")
    for pattern in patterns:
        found = resolve_timetables(pattern.replace("L", "felez_test"), line)
        assert sorted(p.name for p in found) == ["base.yaml", "convoy.yaml", "dense.yaml", "test.yaml"], pattern
