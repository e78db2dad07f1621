"""Results folders: written completely or not at all, with the inputs and versions recorded.

A command writes into ``<out>.partial-<pid>`` and renames it to ``<out>`` only when everything is
written; on any error the partial folder is removed, so a results folder on disk is always whole.
``meta.json`` records the command, the input files (with their SHA-256), the versions of vcsumo,
SUMO, CasADi, numpy, pandas and Python, the seed and the wall time.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import platform
import re
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from vcsumo.errors import VcsumoError


_UNSAFE = re.compile(r"[/\\\x00-\x1f]")


def safe_component(text: str, max_length: int = 120) -> str:
    """``text`` as one harmless path component: a results sub-folder named after file contents.

    Names taken from input files or options (timetable names, controller specs such as
    ``cbc:../x.yaml``, ids) must not climb out of the results folder: path separators and control
    characters become ``-``, a name that is only dots gets a ``_`` in front, and an over-long name
    is cut and made unique with a hash (file systems allow 255 bytes).
    """
    out = _UNSAFE.sub("-", str(text))
    if not out.strip("."):
        out = "_" + out
    if len(out.encode("utf-8")) > max_length:
        digest = hashlib.sha256(str(text).encode("utf-8")).hexdigest()[:10]
        out = out.encode("utf-8")[: max_length - 11].decode("utf-8", "ignore") + "-" + digest
    return out


def default_out(kind: str, name: str) -> Path:
    """A new folder under ./results/ named after the command, the line and the time.

    ``name`` comes from input files: it is made one safe path component (:func:`safe_component`).
    """
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path("results") / safe_component(f"{kind}-{name}-{stamp}")
    out = base
    k = 1
    while out.exists():
        k += 1
        out = Path(f"{base}-{k}")
    return out


def versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for pkg in ("vcsumo", "eclipse-sumo", "libsumo", "casadi", "numpy", "pandas", "matplotlib"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def file_digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class ResultsFolder:
    """Context manager for an atomic results folder.

    >>> with ResultsFolder(Path("results/x"), inputs={"line": p}) as rf:   # doctest: +SKIP
    ...     df.to_csv(rf.path / "headway.csv")
    """

    def __init__(self, out: Path, inputs: dict[str, Path] | None = None, seed: int | None = None, params: dict[str, Any] | None = None, overwrite: bool = False):
        self.final = Path(out)
        self.inputs = inputs or {}
        self.seed = seed
        self.params = params or {}
        self.overwrite = overwrite
        self.path = self.final.with_name(f"{self.final.name}.partial-{os.getpid()}")
        self._t0 = 0.0
        self.extra_meta: dict[str, Any] = {}

    def _all_inputs(self) -> dict[str, Path]:
        inputs = dict(self.inputs)
        study = os.environ.get("VCSUMO_STUDY_FILE")
        if study:
            inputs.setdefault("study", Path(study))
        return inputs

    def __enter__(self) -> "ResultsFolder":
        if self.final.exists() and any(self.final.iterdir()) and not self.overwrite:
            raise VcsumoError(f"{self.final}: output folder exists and is not empty (choose another --out or remove it)")
        self.final.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists():
            shutil.rmtree(self.path)
        self.path.mkdir(parents=True)
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            shutil.rmtree(self.path, ignore_errors=True)
            return
        meta = {
            "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]),
            "created": _dt.datetime.now().isoformat(timespec="seconds"),
            "wall_time_s": round(time.perf_counter() - self._t0, 3),
            "seed": self.seed,
            "versions": versions(),
            "inputs": {k: {"path": str(v), "sha256": file_digest(v)} for k, v in self._all_inputs().items() if v and Path(v).is_file()},
            "parameters": self.params,
        }
        meta.update(self.extra_meta)
        (self.path / "meta.json").write_text(json.dumps(meta, indent=2, default=str))
        if self.final.exists():
            shutil.rmtree(self.final)
        os.replace(self.path, self.final)
