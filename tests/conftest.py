"""Shared fixtures: shipped lines and networks are built once per test session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "vcsumo" / "data"


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def line_factory():
    from vcsumo.line import load_line

    cache = {}

    def get(name: str):
        if name not in cache:
            cache[name] = load_line(name)
        return cache[name]

    return get


@pytest.fixture(scope="session")
def network_factory(line_factory):
    from vcsumo.sim.network import build_network

    cache = {}

    def get(name: str, block_length_m=None):
        key = (name, block_length_m)
        if key not in cache:
            cache[key] = build_network(line_factory(name), block_length_m)
        return cache[key]

    return get


@pytest.fixture
def in_tmp(tmp_path, monkeypatch):
    """Run a test from inside an empty temporary folder (for CLI default ./results)."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


os.environ.setdefault("MPLBACKEND", "Agg")
