"""One resolver for the parameter files of controllers, supervisors, the channel and the guard.

A parameter *spec* is either

* a **name** of a file shipped in ``controllers/`` (:func:`controllers_dir`, i.e.
  ``vcsumo.line.project_root()/"controllers"``; ``$VCSUMO_HOME/controllers`` when that is set):
  ``cbc_plf`` → ``controllers/cbc_plf.yaml``;
* or a **path** to a YAML file (it ends in ``.yaml``/``.yml`` or contains a folder separator).  A
  relative path is taken relative to the ``base_dir`` the caller passes — a study file's folder —
  or, without one, to the working directory.

No spec (None or empty) means the caller's default name.  A spec that does not resolve is an
:class:`~vcsumo.errors.InputError` naming the *field* the caller passes (``--controller``,
``controllers[1]``, ``cbf_config``, ...), so the user sees which option or file field to fix.
Every module that reads such a file resolves it here (the controller registry, the channel and
guard loaders, the reproductions).
"""

from __future__ import annotations

import os
from pathlib import Path

from vcsumo.config import is_file
from vcsumo.errors import InputError

YAML_SUFFIXES = (".yaml", ".yml")


def controllers_dir() -> Path:
    """The folder of the shipped parameter files (``project_root()/controllers``)."""
    from vcsumo.line import project_root

    return project_root() / "controllers"


def shipped_parameter_sets() -> list[str]:
    """Names of the parameter files in :func:`controllers_dir` (without ``.yaml``)."""
    return sorted(p.stem for p in controllers_dir().glob("*.yaml"))


def is_path_spec(spec: str | Path) -> bool:
    """True when ``spec`` names a file (a Path, a YAML suffix or a folder separator), not a shipped name."""
    if isinstance(spec, Path):
        return True
    s = str(spec)
    return Path(s).suffix in YAML_SUFFIXES or "/" in s or os.sep in s


def resolve_params(spec: str | Path | None, default: str, field: str | None = "--controller", base_dir: str | Path | None = None,
                   kind: str = "controller") -> Path:
    """The parameter file for ``spec`` (see the module doc); ``default`` is the shipped name used
    when ``spec`` is None or empty.  ``kind`` names the file in messages (controller, channel, guard).

    Raises :class:`~vcsumo.errors.InputError` (file None, field ``field``) when nothing is found."""
    if spec is None or (isinstance(spec, str) and not spec.strip()):
        spec = default
    if is_path_spec(spec):
        p = Path(spec)
        if not p.is_absolute() and base_dir is not None:
            p = Path(base_dir) / p
        if not is_file(p):
            where = f" (relative to {base_dir})" if base_dir is not None and not Path(spec).is_absolute() else ""
            raise InputError(None, field, f"{kind} parameter file '{spec}' not found{where}")
        return p
    name = str(spec)
    cand = controllers_dir() / f"{name}.yaml"
    if not is_file(cand):
        avail = ", ".join(shipped_parameter_sets()) or f"none in {controllers_dir()}"  # (a VCSUMO_HOME without controllers/)
        raise InputError(None, field, f"unknown {kind} settings: {kind} parameter set '{name}' not found (available: {avail}; or a path to a .yaml file)")
    return cand


__all__ = ["YAML_SUFFIXES", "controllers_dir", "shipped_parameter_sets", "is_path_spec", "resolve_params"]
