"""The result store of a results folder: tidy CSV tables, appended once per resume key, locked.

One store per results folder (``batch.csv`` + ``batch_trains.csv`` of a batch, ``safety.csv`` of a
safety campaign, ``capacity_cases.csv`` of a capacity study).  Its guarantees:

* **append-only, one whole line at a time** — every write is flushed and ``fsync``-ed; a line cut
  off by a kill (``kill -9``, power loss) is dropped when the store is next opened, and rows of a
  child table (``batch_trains.csv``) whose key never reached the main table are dropped too
  (children are written before their main row);
* **exactly once per resume key** — :meth:`ResultStore.record` skips a key that is already in the
  store, and opening a folder written by an older vcsumo (which could hold a run twice) keeps the
  last row of every key (and of every key and identity in a child table) and rewrites the file;
* **one writer at a time** — :meth:`ResultStore.open` takes ``.vcsumo.lock`` in the folder (an
  ``flock`` through :mod:`filelock`: the kernel releases it when the holder dies, even by
  ``kill -9``).  A second command writing into the same folder does not wait: it stops at once
  with one error line naming the holder (:class:`StoreBusy`), before it has run or written
  anything;
* **one kind of study per folder** — ``store.json`` records the store's kind and, where a study
  asks for it, the parameters every row depends on; opening with another kind or other
  parameters is refused with one error line naming the differences.

Values are written as they are (floats rounded to 6 decimals, ``NaN`` and ``None`` as empty
cells, line breaks in text flattened to spaces) and read back with :meth:`ResultStore.read`.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import math
import os
import socket
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import pandas as pd

from vcsumo.errors import InputError, VcsumoError
from vcsumo.results import check_output_folder, write_csv

LOCK_NAME = ".vcsumo.lock"
OWNER_NAME = ".vcsumo.lock.owner"
META_NAME = "store.json"
FORMAT = 1


@dataclass(frozen=True)
class Table:
    """One CSV file of a store."""

    name: str
    """File name inside the results folder (``batch.csv``)."""
    columns: tuple[str, ...]
    key: str
    """The column holding the resume key."""
    identity: tuple[str, ...] = ()
    """Child tables: the columns that, with the key, identify a row (``("train",)``)."""
    text: tuple[str, ...] = field(default=())
    """Columns read back as text, an empty cell as ``""`` (the key is always text)."""


class StoreBusy(VcsumoError):
    """Another command holds the results folder's lock."""


def fmt(v) -> str:
    """One CSV cell: ``None``/``NaN`` empty, floats rounded to 6 decimals, text on one line."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "True" if v else "False"
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(round(v, 6))
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):  # numpy scalars
        return fmt(v.item())
    return " ".join(str(v).splitlines()) if isinstance(v, str) and ("\n" in v or "\r" in v) else str(v)


def csv_line(values: Iterable) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([fmt(v) for v in values])
    return buf.getvalue()


def atomic_write_text(path: Path, text: str) -> None:
    """Write a whole file or nothing (a temporary file in the same folder, fsync, rename)."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def atomic_csv(df: pd.DataFrame, path: Path) -> None:
    """A results table written whole or not at all (counts as integers, no float noise: :func:`vcsumo.results.write_csv`)."""
    write_csv(df, path)


def _repair(path: Path, columns: tuple[str, ...]) -> None:
    """Create the file with its header, drop a line cut off by an interruption, check the header."""
    header = csv_line(columns)
    if not path.is_file() or path.stat().st_size == 0:
        atomic_write_text(path, header)
        return
    data = path.read_bytes()
    if not data.endswith(b"\n"):
        cut = data.rfind(b"\n")
        if cut < 0:
            atomic_write_text(path, header)
            return
        with open(path, "rb+") as f:
            f.truncate(cut + 1)
            f.flush()
            os.fsync(f.fileno())
    first = path.read_text(encoding="utf-8").split("\n", 1)[0]
    if next(csv.reader(io.StringIO(first)), []) != list(columns):
        raise VcsumoError(f"{path}: its columns are not those this vcsumo writes (written by an older vcsumo?); choose another --out")


def _read_raw(path: Path, table: Table) -> pd.DataFrame:
    """Every line of a table as text (the exact cells that were written)."""
    return pd.read_csv(path, dtype=str, keep_default_na=False, na_filter=False)


def _describe(value) -> str:
    text = json.dumps(value, default=str)
    return text if len(text) <= 60 else text[:57] + "..."


class ResultStore:
    """The store of one results folder; use as a context manager (it holds the folder's lock).

    ``main`` is the table of finished tasks (one row per resume key); ``children`` are tables of
    rows that belong to a main row (several per key).  ``kind`` names the study; ``params``, if
    given, are the parameters every row depends on: a folder whose store was made with other
    parameters is refused.  ``exclusive``: a non-empty folder without a store of this kind is
    refused (a study that owns its folder); otherwise the store is added to the folder.
    """

    def __init__(self, folder: Path, main: Table, children: Iterable[Table] = (), kind: str = "", params: dict | None = None,
                 exclusive: bool = False, option: str = "--out"):
        self.folder = Path(folder)
        self.main = main
        self.children = tuple(children)
        self.kind = kind
        self.params = params
        self.exclusive = exclusive
        self.option = option
        self._lock = None
        self._keys: set[str] = set()
        self._made_folder = False

    # -- opening and closing --------------------------------------------------------------------

    def __enter__(self) -> "ResultStore":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> "ResultStore":
        from filelock import FileLock, Timeout

        folder = self.folder
        check_output_folder(folder, self.option)
        if folder.exists() and not folder.is_dir():
            raise InputError(None, self.option, f"{folder} is a file, not a folder")
        if not folder.exists():
            made = []
            p = folder
            while not p.exists():
                made.append(p)
                p = p.parent
            folder.mkdir(parents=True)
            self._made_folder = made
        lock = FileLock(str(folder / LOCK_NAME), timeout=0, thread_local=False)
        try:
            lock.acquire()
        except Timeout:
            owner = ""
            try:
                owner = (folder / OWNER_NAME).read_text().strip()
            except OSError:
                pass
            raise StoreBusy(f"{folder}: another vcsumo command is writing into this folder ({owner or 'owner unknown'}); "
                            f"wait until it has finished or choose another {self.option}") from None
        self._lock = lock
        try:
            # written whole, then renamed: a second command never reads it empty ("owner unknown" when it
            # looked between the file's creation and its write)
            owner_tmp = folder / f"{OWNER_NAME}.tmp-{os.getpid()}"
            owner_tmp.write_text(f"pid {os.getpid()} on {socket.gethostname()} since "
                                 f"{_dt.datetime.now().isoformat(timespec='seconds')}: {' '.join([Path(sys.argv[0]).name] + sys.argv[1:])[:300]}\n")
            os.replace(owner_tmp, folder / OWNER_NAME)
            self._check_meta()
            for t in (self.main, *self.children):
                _repair(folder / t.name, t.columns)
            self._tidy()
        except BaseException:
            self.close(failed=True)
            raise
        return self

    def close(self, failed: bool = False) -> None:
        if self._lock is None:
            return
        try:
            (self.folder / OWNER_NAME).unlink(missing_ok=True)
        except OSError:
            pass
        self._lock.release()
        self._lock = None
        if failed and self._made_folder:  # nothing of ours is left: remove what we made
            import shutil

            shutil.rmtree(self.folder, ignore_errors=True)
            for p in self._made_folder[1:]:
                try:
                    p.rmdir()
                except OSError:
                    break

    def _check_meta(self) -> None:
        path = self.folder / META_NAME
        if path.is_file():
            try:
                meta = json.loads(path.read_text())
            except (OSError, ValueError) as exc:
                raise InputError(path, None, f"not a vcsumo store description ({exc}); choose another {self.option}") from None
            if meta.get("kind") != self.kind:
                raise InputError(path, "kind", f"this folder holds the results of a {meta.get('kind')!s} study, not of a {self.kind} study; "
                                               f"choose another {self.option}")
            if self.params is not None:
                have = meta.get("params") or {}
                want = json.loads(json.dumps(self.params, default=str))
                diff = [f"{k} {_describe(want.get(k))} now, {_describe(have.get(k))} in the folder" for k in sorted(set(have) | set(want))
                        if have.get(k) != want.get(k)]
                if diff:
                    raise InputError(path, "parameters", f"this folder holds a {self.kind} study with other parameters ({'; '.join(diff)}); "
                                                         f"run with the same parameters to resume it, or choose another {self.option}")
            return
        own = {LOCK_NAME, OWNER_NAME, META_NAME, self.main.name, *(t.name for t in self.children)}
        others = [p.name for p in self.folder.iterdir() if p.name not in own]
        if self.exclusive and others and not (self.folder / self.main.name).is_file():
            raise VcsumoError(f"{self.folder}: output folder exists and is not empty (choose another {self.option} or remove it)")
        meta = {"kind": self.kind, "format": FORMAT, "params": self.params,
                "created": _dt.datetime.now().isoformat(timespec="seconds")}
        atomic_write_text(path, json.dumps(meta, indent=2, default=str) + "\n")

    def _tidy(self) -> None:
        """Exactly once per key: keep the last row of every key; drop orphaned child rows."""
        main_path = self.folder / self.main.name
        df = _read_raw(main_path, self.main)
        if df[self.main.key].duplicated().any() or (df[self.main.key] == "").any():
            df = df[df[self.main.key] != ""].drop_duplicates(self.main.key, keep="last")
            atomic_csv(df, main_path)
        self._keys = set(df[self.main.key])
        for t in self.children:
            path = self.folder / t.name
            ch = _read_raw(path, t)
            keep = ch[ch[t.key].isin(self._keys)].drop_duplicates([t.key, *t.identity], keep="last")
            if len(keep) != len(ch):
                atomic_csv(keep, path)

    # -- the rows -------------------------------------------------------------------------------

    @property
    def keys(self) -> frozenset[str]:
        """Resume keys of every finished task in the store."""
        return frozenset(self._keys)

    def __contains__(self, key: str) -> bool:
        return key in self._keys

    def _append(self, table: Table, rows: list[dict]) -> None:
        if not rows:
            return
        text = "".join(csv_line(r.get(c) for c in table.columns) for r in rows)
        with open(self.folder / table.name, "a", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    def record(self, rows: list[dict], children: dict[str, list[dict]] | None = None) -> int:
        """Append main rows (each with its key) and their child rows, skipping keys already stored.

        Children go first: a kill between the two leaves children without a main row, which the
        next :meth:`open` drops.  Returns the number of main rows written.
        """
        if self._lock is None:
            raise RuntimeError("the store is not open")
        new, seen = [], set()
        for r in rows:
            k = str(r[self.main.key])
            if k not in self._keys and k not in seen:
                new.append(r)
                seen.add(k)
        if not new:
            return 0
        for t in self.children:
            self._append(t, [c for c in (children or {}).get(t.name, []) if str(c[t.key]) in seen])
        self._append(self.main, new)
        self._keys |= seen
        return len(new)

    def forget(self, keys: Iterable[str]) -> None:
        """Remove the rows of these keys (to run those tasks again, e.g. failed ones)."""
        drop = set(keys) & self._keys
        if not drop:
            return
        for t in (self.main, *self.children):
            path = self.folder / t.name
            df = _read_raw(path, t)
            atomic_csv(df[~df[t.key].isin(drop)], path)
        self._keys -= drop

    def read(self, table: Table | None = None) -> pd.DataFrame:
        """A table of the store, typed (numbers as numbers; text columns with ``""`` for empty)."""
        return read_table(self.folder, table or self.main)


def read_table(folder: Path, table: Table) -> pd.DataFrame:
    """A store table of a results folder without opening (locking) it: the last row per key
    (child tables: per key and identity); an empty frame if there is none."""
    path = Path(folder) / table.name
    if not path.is_file() or path.stat().st_size == 0:
        return pd.DataFrame(columns=list(table.columns))
    text = {c: str for c in (table.key, *table.text)}
    try:
        df = pd.read_csv(path, dtype=text, keep_default_na=True)
    except pd.errors.EmptyDataError:
        return pd.DataFrame(columns=list(table.columns))
    if list(df.columns) != list(table.columns):
        raise VcsumoError(f"{path}: its columns are not those this vcsumo writes (written by an older vcsumo?); choose another --out")
    for c in text:
        df[c] = df[c].fillna("")
    df = df[df[table.key] != ""]
    return df.drop_duplicates([table.key, *table.identity], keep="last").reset_index(drop=True)
