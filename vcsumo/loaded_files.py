"""The input files a command read: every file :func:`vcsumo.config.load_model` reads within
:func:`noting_loaded_files` is noted, so that a results folder's ``meta.json`` names (with SHA-256)
the train types, assumption sets and parameter files a command used, not only its line and
timetable (:func:`vcsumo.results.write_meta`)."""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Iterator

_LOADED: ContextVar[dict[Path, str] | None] = ContextVar("loaded_files", default=None)


@contextmanager
def noting_loaded_files() -> Iterator[None]:
    """Within this block every file read by :func:`vcsumo.config.load_model` is noted (:func:`loaded_files`)."""
    token = _LOADED.set({})
    try:
        yield
    finally:
        _LOADED.reset(token)


def note_loaded(path: Path, model: str) -> None:
    """``path`` was read as ``model`` (a no-op outside :func:`noting_loaded_files`)."""
    noted = _LOADED.get()
    if noted is not None:
        noted.setdefault(Path(path).resolve(), model)


def loaded_files() -> dict[Path, str]:
    """The files read so far within :func:`noting_loaded_files`, each with the model it was read as."""
    return dict(_LOADED.get() or {})
