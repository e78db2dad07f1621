"""Finding SUMO: the binaries and data of the ``eclipse-sumo`` wheel, no SUMO_HOME needed.

``SUMO_HOME`` is set for this process (if the user has not set it) so SUMO validates XML and
finds its data files.  Nothing here imports libsumo (see :mod:`vcsumo.sim.sumo_backend`).
"""

from __future__ import annotations

import functools
import os
import shutil
from pathlib import Path

from vcsumo.errors import SumoError


@functools.lru_cache(maxsize=1)
def sumo_home() -> Path:
    """SUMO's installation folder: the eclipse-sumo wheel, else $SUMO_HOME."""
    try:
        import sumo  # the eclipse-sumo wheel

        home = Path(sumo.SUMO_HOME)
    except ImportError:
        env = os.environ.get("SUMO_HOME")
        if not env:
            raise SumoError("SUMO not found: install the 'eclipse-sumo' package (pip install eclipse-sumo)") from None
        home = Path(env)
    os.environ.setdefault("SUMO_HOME", str(home))
    return home


def sumo_binary(name: str) -> str:
    """Absolute path of a SUMO program (sumo, netconvert, sumo-gui)."""
    exe = sumo_home() / "bin" / name
    if exe.is_file():
        return str(exe)
    found = shutil.which(name)
    if found:
        return found
    raise SumoError(f"SUMO program '{name}' not found in {sumo_home() / 'bin'} or on PATH")


@functools.lru_cache(maxsize=1)
def sumo_version() -> str:
    """Version of the installed SUMO (from the eclipse-sumo wheel metadata)."""
    try:
        from importlib.metadata import version

        return version("eclipse-sumo")
    except Exception:  # pragma: no cover - SUMO from elsewhere
        return "unknown"
