"""Results folders: written completely or not at all, with the inputs and versions recorded.

A command writes into ``<out>.partial-<pid>`` and renames it to ``<out>`` only when everything is
written; on any error (and on SIGINT or SIGTERM, which the command line turns into
``KeyboardInterrupt``) the partial folder is removed, so a results folder on disk is always whole,
and folders the command created around it (an empty ``results/``) are removed too.  A process
killed outright (SIGKILL) cannot clean up: its ``<out>.partial-<pid>`` is removed by the next
command writing to the same place, once no process with that pid is alive
(:func:`remove_stale_partials`).
``meta.json`` records the command, the input files (with their SHA-256; a study file run with
``vcsumo study run`` through :func:`recording`), the versions of vcsumo, SUMO, CasADi, numpy,
pandas and Python, the seed and the wall time.

JSON files are written by :func:`write_json` (a missing or non-finite number is ``null``: ``NaN``
is not JSON) and tables by :func:`write_csv` (counts as integers, measures without float noise).
"""

from __future__ import annotations

import contextvars
import datetime as _dt
import hashlib
import json
import math
import os
import platform
import re
import shutil
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import pandas as pd

from vcsumo.errors import InputError, VcsumoError


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


def pid_alive(pid: int) -> bool:
    """Whether a process with this pid exists on this machine."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


_PARTIAL = re.compile(r"^(?P<name>.+)\.partial-(?P<pid>\d+)$")


def check_output_folder(folder: Path, option: str = "--out") -> None:
    """Refuse a results folder SUMO cannot write into: a ':' in its path (after a Windows drive)
    makes SUMO read an output file as ``host:port`` of a socket ("Given port number ... is not
    numeric", reported as a failure of the line's network) — one line naming the option instead,
    before anything is written."""
    full = str(Path(folder).expanduser().absolute())
    drive = Path(full).drive
    if ":" in full[len(drive):]:
        raise InputError(None, option, f"{folder}: a ':' in the results folder's path is read by SUMO as host:port of a socket; "
                                       f"choose a folder whose path has no ':'")
    # The folder, or the nearest of its parents that exists, must be a folder this process can write
    # into: before, a file in the way or a read-only place was an OSError after the work ("error:
    # out.partial-123: Read-only file system", "error: x: File exists" for a file x in x/sub) naming
    # neither the option nor what was wrong.
    here = Path(full)
    while not here.exists() and not here.is_symlink() and here != here.parent:
        here = here.parent
    if here.exists() and not here.is_dir():
        where = "" if here == Path(full) else f"{folder}: "
        raise InputError(None, option, f"{where}{here if where else folder} is a file, not a folder")
    if here.is_dir() and not os.access(here, os.W_OK | os.X_OK):
        raise InputError(None, option, f"{folder}: cannot write into {here} (no permission, or a read-only file system)")


def remove_stale_partials(folder: Path, name: str | None = None, pids: set[int] | None = None) -> list[Path]:
    """Remove ``<name>.partial-<pid>`` entries of ``folder`` left by processes that are gone.

    ``name``: only the partials of that results folder (default: every one in ``folder``);
    ``pids``: only those of these processes (known dead), else those whose pid is not alive.
    Returns what was removed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    for p in folder.iterdir():
        m = _PARTIAL.match(p.name)
        if not m or (name is not None and m["name"] != name):
            continue
        pid = int(m["pid"])
        if pid == os.getpid() or (pids is not None and pid not in pids) or (pids is None and pid_alive(pid)):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed.append(p)
    return removed


def write_meta(folder: Path, inputs: dict[str, Path] | None = None, seed: int | None = None, params: dict[str, Any] | None = None,
               wall_time_s: float = 0.0, extra: dict[str, Any] | None = None) -> None:
    """``meta.json`` of a results folder: command, time, versions, inputs with SHA-256, seed, parameters."""
    inputs = {**_RECORDING.get(), **(inputs or {})}
    inputs.update(read_inputs({Path(v).resolve() for v in inputs.values() if v}))
    meta = {
        "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]),
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "wall_time_s": round(wall_time_s, 3),
        "seed": seed,
        "versions": versions(),
        "inputs": {k: {"path": str(v), "sha256": file_digest(v)} for k, v in inputs.items() if v and Path(v).is_file()},
        "parameters": params or {},
    }
    meta.update(extra or {})
    write_json(Path(folder) / "meta.json", meta)


INPUT_KINDS = {"RollingStock": "train", "AssumptionSet": "assumptions", "TimetableFile": "timetable", "LineFile": "line", "NetworkFile": "network",
               "DelayConfig": "delays", "ChannelConfig": "channel", "GuardConfig": "guard", "CBFConfig": "cbf", "CbcParams": "controller",
               "MPCSettings": "controller", "CruiseConfig": "controller"}
"""How a file read as each model is named among a ``meta.json``'s inputs (``train:emu140``)."""


def read_inputs(known: set[Path]) -> dict[str, Path]:
    """The files the command read (:func:`vcsumo.loaded_files.loaded_files`) that ``known`` does not
    hold, each as ``<kind>:<file stem>``."""
    from vcsumo.loaded_files import loaded_files

    out: dict[str, Path] = {}
    for path, model in loaded_files().items():
        if path in known:
            continue
        key = f"{INPUT_KINDS.get(model, model)}:{path.stem}"
        k = 2
        while key in out:
            key, k = f"{INPUT_KINDS.get(model, model)}:{path.stem}-{k}", k + 1
        out[key] = path
    return out


_RECORDING: contextvars.ContextVar[dict[str, Path]] = contextvars.ContextVar("recorded_inputs", default={})


@contextmanager
def recording(inputs: dict[str, Path]) -> Iterator[None]:
    """Results folders written inside also record ``inputs`` in their ``meta.json`` (the study file
    a command was run from, when a library function writes its own ``meta.json``)."""
    token = _RECORDING.set({**_RECORDING.get(), **inputs})
    try:
        yield
    finally:
        _RECORDING.reset(token)


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite or missing number as None and numpy scalars as Python numbers."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)) and getattr(value, "ndim", None) == 0:
        value = value.item()  # numpy scalar
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is pd.NA or value is pd.NaT:
        return None
    return value


def write_json(path: Path, value: Any) -> None:
    """Write ``value`` as JSON, whole or not at all; NaN and infinities become ``null`` (valid JSON)."""
    path = Path(path)
    text = json.dumps(json_safe(value), indent=2, default=str, allow_nan=False)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(text + "\n")
    os.replace(tmp, path)


COUNT_WORDS = ("violations", "collisions", "brakes", "brakings", "runs", "failed", "simulations", "scenarios", "size", "breaches", "interventions",
               "activations", "trains", "count", "steps", "events", "probes", "stops", "overruns", "teleports", "warnings", "cases", "seed")
"""Words of a column name that make it a count (stored as an integer when every value is whole)."""
SIGNIFICANT_DIGITS = 12
"""Digits a measure is written with: float noise (``-23.599999999999994``) goes, the resolution stays."""


def is_count_column(column: str) -> bool:
    """A column holding counts: no unit suffix (``_s``, ``_m`` ...) and a counting word in its name."""
    if re.search(r"_(s|m|km|mps|mps2|kmh|pct|min|h|n|w|kg|per_h|trains_per_h)$", column):
        return False
    return any(w in column for w in COUNT_WORDS)


def table_for_csv(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` as written: counts of whole numbers as integers (a missing count stays empty)."""
    out = df.copy()
    for c in out.columns:
        col = out[c]
        if col.dtype.kind == "f" and is_count_column(str(c)):
            finite = col.dropna()
            if len(finite) and (finite == finite.round()).all() and finite.abs().max() < 2**53:
                out[c] = col.astype("Int64")
    return out


def _float_text(x: float) -> str:
    return repr(float(f"{x:.{SIGNIFICANT_DIGITS}g}"))  # shortest text of the rounded value: -23.6, 1.0


def write_csv(df: pd.DataFrame, path: Path) -> None:
    """Write a results table: whole or not at all, counts as integers, measures to
    :data:`SIGNIFICANT_DIGITS` significant digits."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    table_for_csv(df).to_csv(tmp, index=False, float_format=_float_text)
    os.replace(tmp, path)


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

    def __enter__(self) -> "ResultsFolder":
        check_output_folder(self.final)
        if self.final.exists() and any(self.final.iterdir()) and not self.overwrite:
            raise InputError(None, "--out", f"{self.final}: output folder exists and is not empty (choose another --out or remove it)")
        self._made = []
        p = self.final.parent
        while not p.exists():
            self._made.append(p)
            p = p.parent
        self.final.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_partials(self.final.parent, self.final.name)
        if self.path.exists():
            shutil.rmtree(self.path)
        self.path.mkdir(parents=True)
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            shutil.rmtree(self.path, ignore_errors=True)
            for p in self._made:  # folders made for this one (an empty results/) go too
                try:
                    p.rmdir()
                except OSError:
                    break
            return
        write_meta(self.path, self.inputs, self.seed, self.params, time.perf_counter() - self._t0, self.extra_meta)
        if self.final.exists():
            shutil.rmtree(self.final)
        os.replace(self.path, self.final)


RESULTS_NA = ["", "nan", "NaN"]
"""What vcsumo writes for a missing value in its CSVs (empty, or a float nan): read back as missing.
pandas' default list also takes ``NA``, ``N/A``, ``null``, ``None``… — a station or train a user
named ``NA`` came back as missing (unseen10)."""


def read_results_csv(path: Path | str, **kw) -> pd.DataFrame:
    """A vcsumo results CSV, with only vcsumo's own missing values taken as missing (:data:`RESULTS_NA`;
    a caller that says how to read missing values, ``keep_default_na`` / ``na_values`` / ``na_filter``, is
    followed as it says)."""
    if not {"keep_default_na", "na_values", "na_filter"} & kw.keys():
        kw = {**kw, "keep_default_na": False, "na_values": RESULTS_NA}
    return pd.read_csv(path, **kw)
