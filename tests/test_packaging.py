"""A non-editable install, used from an empty folder: the wheel ships the data, builds go to the
cache folder, and a missing data folder is an error, not an empty list (issue 13).

The wheel is built from a copy of the source (``pip wheel --no-deps``), installed with
``pip install --no-deps --target`` outside the source tree, and run with ``PYTHONPATH`` pointing
there: the dependencies come from this venv, vcsumo only from the wheel.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.sumo


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(target folder with the installed wheel, the wheel file)."""
    base = tmp_path_factory.mktemp("pkg")
    src = base / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(ROOT / "vcsumo", src / "vcsumo", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    wheels = base / "wheels"
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels), str(src)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (wheel,) = wheels.glob("vcsumo-*.whl")
    target = base / "site"
    proc = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return target, wheel


def vcsumo(installed, cwd: Path, *args: str, home: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    target, _ = installed
    env = {k: v for k, v in os.environ.items() if k not in ("VCSUMO_HOME", "PYTHONPATH", "COLUMNS")}
    env.update(PYTHONPATH=str(target), VCSUMO_CACHE=str(cwd.parent / "cache"))
    if home is not None:
        env["VCSUMO_HOME"] = str(home)
    return subprocess.run([str(target / "bin" / "vcsumo"), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def empty(tmp_path) -> Path:
    d = tmp_path / "work"
    d.mkdir()
    return d


def test_the_wheel_holds_every_shipped_data_file(installed):
    _, wheel = installed
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = {p.relative_to(ROOT).as_posix() for p in (ROOT / "vcsumo" / "data").rglob("*") if p.is_file()}
    assert len(shipped) >= 40
    assert shipped <= names, sorted(shipped - names)


def test_the_installed_package_is_the_wheel_not_the_source(installed, empty):
    target, _ = installed
    env = {k: v for k, v in os.environ.items() if k != "VCSUMO_HOME"}
    env["PYTHONPATH"] = str(target)
    out = subprocess.run([sys.executable, "-c", "import vcsumo.line as l; print(l.__file__); print(l.project_root())"], cwd=empty, env=env,
                         capture_output=True, text=True, check=True).stdout.split()
    assert Path(out[0]).is_relative_to(target) and Path(out[1]).is_relative_to(target)


def test_lines_lists_the_shipped_lines_and_trains(installed, empty):
    proc = vcsumo(installed, empty, "lines")
    assert proc.returncode == 0, proc.stderr
    for name in ("felez_test", "firenze_bologna", "hcmc_line1", "milano_bologna", "train etr1000", "train hcmc_l1", "train felez2019"):
        assert name in proc.stdout
    assert not list(empty.iterdir())


def test_lines_with_an_empty_home_fails_loudly(installed, empty, tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    proc = vcsumo(installed, empty, "lines", home=home)
    assert proc.returncode == 2 and proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "no line files" in lines[0] and "VCSUMO_HOME" in lines[0]


def test_build_network_writes_into_the_cache_folder_only(installed, empty):
    target, _ = installed
    proc = vcsumo(installed, empty, "build-network", "--line", "felez_test")
    assert proc.returncode == 0, proc.stderr
    cache = empty.parent / "cache"
    nets = list((cache / "networks" / "felez_test").glob("*/line.net.xml"))
    assert len(nets) == 1 and f"wrote {nets[0]}" in proc.stdout
    assert not list(empty.iterdir())
    assert not [p for p in (target / "vcsumo").rglob("*") if p.suffix == ".xml" or p.name == "build"]


def test_run_and_capacity_study_from_an_empty_folder(installed, empty):
    proc = vcsumo(installed, empty, "run", "--line", "felez_test", "--timetable", "test", "--regime", "fbs", "--out", "r")
    assert proc.returncode == 0, proc.stderr
    summary = pd.read_csv(empty / "r" / "summary.csv")
    assert len(summary) == 3 and summary.arrived.all()
    for f in ("trajectories.csv", "infrastructure.csv", "time_distance.png", "sumo_messages.log", "meta.json"):
        assert (empty / "r" / f).is_file(), f
    proc = vcsumo(installed, empty, "study", "capacity", "--line", "felez_test", "--controllers", "", "--directions", "up",
                  "--patterns", "non-stop", "--workers", "1", "--out", "c")
    assert proc.returncode == 0, proc.stderr
    cap = pd.read_csv(empty / "c" / "capacity.csv")
    assert list(cap.regime) == ["fbs", "mb"] and (cap.capacity_trains_per_h > 0).all()
    assert cap.loc[cap.regime == "mb", "capacity_trains_per_h"].iloc[0] > cap.loc[cap.regime == "fbs", "capacity_trains_per_h"].iloc[0]
    for f in ("capacity.png", "time_distance.png", "time_distance.csv", "infrastructure.csv"):
        assert (empty / "c" / f).is_file(), f
    assert "wrote c/capacity.csv" in proc.stdout
