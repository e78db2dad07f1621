"""Strict, typed configuration loaded from YAML files.

Every input file is parsed into a frozen pydantic model whose unknown keys are rejected
(``extra="forbid"``).  Problems become one :class:`~vcsumo.errors.InputError` naming the file
and the field, e.g. ``networks/x/line.yaml: stations[2].km: ...``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from vcsumo.errors import InputError

M = TypeVar("M", bound=BaseModel)


class StrictModel(BaseModel):
    """Base for every configuration model: unknown keys are errors, objects are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


def field_path(loc: tuple[Any, ...]) -> str:
    """Render a pydantic error location as ``stations[2].km``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def read_yaml(path: Path) -> Any:
    """Read a YAML file; syntax errors become an InputError naming the line."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except OSError as exc:
        raise InputError(path, None, f"cannot read file: {exc.strerror}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise InputError(path, where, f"malformed YAML: {problem}") from None


def parse_model(model: type[M], data: Any, path: str | Path | None) -> M:
    """Validate ``data`` against ``model``; the first error becomes one InputError."""
    if not isinstance(data, dict):
        raise InputError(path, None, f"expected a mapping of {model.__name__} fields, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        first = errors[0]
        msg = first["msg"]
        if first["type"] == "extra_forbidden":
            msg = "unknown key (allowed keys: " + ", ".join(_allowed_keys(model, first["loc"][:-1])) + ")"
        elif first["type"] == "missing":
            msg = "required field is missing"
        msg = msg.removeprefix("Value error, ")
        more = f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})" if len(errors) > 1 else ""
        raise InputError(path, field_path(first["loc"]) or None, msg + more) from None


def load_model(model: type[M], path: str | Path) -> M:
    """Read ``path`` as YAML and validate it against ``model``."""
    return parse_model(model, read_yaml(Path(path)), path)


def _allowed_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """Best-effort list of the field names allowed at ``loc`` (for the unknown-key message)."""
    current: Any = model
    for part in loc:
        if isinstance(part, int):
            continue
        fields = getattr(current, "model_fields", None)
        if not fields or part not in fields:
            return []
        annotation = fields[part].annotation
        current = _inner_model(annotation)
        if current is None:
            return []
    fields = getattr(current, "model_fields", {})
    return sorted(fields)


def _inner_model(annotation: Any) -> Any:
    """The BaseModel inside ``list[X]``, ``X | None``, ``dict[str, X]`` annotations."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = _inner_model(arg)
        if found is not None:
            return found
    return None
