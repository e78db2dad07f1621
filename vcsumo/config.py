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


class FieldProblem(ValueError):
    """Raised by a model validator about one field: the error then names ``field`` (relative to the model)."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


class StrictModel(BaseModel):
    """Base for every configuration model: unknown keys are errors, objects are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True, allow_inf_nan=False)
    """``allow_inf_nan=False``: no physical quantity of a vcsumo input is infinite or NaN, so ``.inf``
    and ``.nan`` in a file are errors (``none`` switches an optional limit off)."""


_UNION_MEMBERS = frozenset({"str", "int", "float", "bool", "list", "dict", "none", "constrained-str", "constrained-float", "constrained-int"})


def field_path(loc: tuple[Any, ...], keep_last: bool = False) -> str:
    """Render a pydantic error location as ``stations[2].km``.

    The names pydantic gives union members (``str``, ``function-after[...]``) are left out, except
    the last part when ``keep_last`` (an unknown key the user wrote).
    """
    out = ""
    for i, part in enumerate(loc):
        if isinstance(part, str) and ("[" in part or part in _UNION_MEMBERS) and not (keep_last and i == len(loc) - 1):
            continue  # pydantic's name of a union member ("str", "function-after[...]"), not a key
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def is_file(path: str | Path) -> bool:
    """``Path.is_file`` that answers False instead of raising for a name the OS rejects (too long, NUL)."""
    try:
        return Path(path).is_file()
    except (OSError, ValueError):
        return False


def is_dir(path: str | Path) -> bool:
    """``Path.is_dir`` that answers False instead of raising for a name the OS rejects."""
    try:
        return Path(path).is_dir()
    except (OSError, ValueError):
        return False


MAX_FILE_BYTES = 20_000_000
"""Largest input file read, bytes: the biggest shipped file is under 20 kB; a larger one is not an input."""
MAX_VALUES = 1_000_000
"""Most values a file may hold once YAML aliases are expanded (guards against alias bombs)."""
MAX_DEPTH = 50
"""Deepest nesting of mappings and lists accepted (the shipped files nest 4 levels)."""

_SafeBase = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
"""libyaml's safe loader when PyYAML has it (linear on deeply nested input), else the pure-Python one."""


class _StrictSafeLoader(_SafeBase):  # type: ignore[misc,valid-type]
    """PyYAML's safe loader (plain YAML types only: no ``!!python/...`` tags), refusing duplicate keys.

    Every YAML file vcsumo reads goes through this loader (:func:`read_yaml`).
    """

    def construct_mapping(self, node, deep=False):  # noqa: D102
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # '<<: *anchor' may be overridden by explicit keys (YAML merge)
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:  # unhashable key: SafeConstructor reports it below
                    continue
                if first is not None:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key '{key}' (first on line {first.line + 1})", key_node.start_mark
                    )
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def _size_and_depth(data: Any, limit: int) -> tuple[int, int]:
    """(values with YAML aliases expanded, nesting depth) of loaded YAML, in time linear in the file.

    A shared list or mapping (an alias) is counted at every use through a memo; a structure that
    contains itself counts as larger than ``limit``.
    """
    if not isinstance(data, (dict, list)):
        return 1, 0
    memo: dict[int, tuple[int, int] | None] = {}  # None: on the current path (not finished)
    stack: list[tuple[Any, bool]] = [(data, False)]
    while stack:
        x, done = stack.pop()
        children = list(x.values()) if isinstance(x, dict) else x
        if done:
            size, depth = 1 + (len(x) if isinstance(x, dict) else 0), 0
            for c in children:
                cs, cd = memo[id(c)] if isinstance(c, (dict, list)) else (1, -1)  # type: ignore[misc]
                size, depth = min(size + cs, limit + 1), max(depth, cd + 1)
            memo[id(x)] = (size, depth)
            continue
        if id(x) in memo:
            if memo[id(x)] is None:  # reached again from inside itself
                return limit + 1, 0
            continue
        memo[id(x)] = None
        stack.append((x, True))
        stack.extend((c, False) for c in children if isinstance(c, (dict, list)))
    return memo[id(data)]  # type: ignore[return-value]


def read_yaml(path: Path) -> Any:
    """Read a YAML file safely; every problem becomes one InputError naming the file (and line).

    Plain YAML only (:class:`_StrictSafeLoader`): ``!!python/...`` tags, duplicate keys, text that is
    not UTF-8, binary files, files over :data:`MAX_FILE_BYTES` and alias bombs are refused.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise InputError(path, None, f"file is {size / 1e6:.0f} MB; vcsumo input files are at most {MAX_FILE_BYTES / 1e6:.0f} MB")
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, None, "is a folder, not a file") from None
    except OSError as exc:
        raise InputError(path, None, f"cannot read file: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError(path, f"line {line}", f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); is it a binary file?") from None
    if "\x00" in text:
        line = text[: text.index("\x00")].count("\n") + 1
        raise InputError(path, f"line {line}", "contains a NUL character; is it a binary file?")
    text = text.removeprefix("\ufeff")
    try:
        data = yaml.load(text, Loader=_StrictSafeLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else None
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        if "could not determine a constructor for the tag" in problem:
            tag = problem.split("tag", 1)[1].strip().strip("'")
            tag = tag.replace("tag:yaml.org,2002:", "!!")
            raise InputError(path, where, f"YAML tag '{tag}' is not allowed (vcsumo reads plain YAML: mappings, lists, numbers, strings)") from None
        raise InputError(path, where, f"malformed YAML: {problem}") from None
    except RecursionError:
        raise InputError(path, None, f"nested more than {MAX_DEPTH} levels deep") from None
    size, depth = _size_and_depth(data, MAX_VALUES)
    if size > MAX_VALUES:
        raise InputError(path, None, f"holds more than {MAX_VALUES:,} values once YAML aliases are expanded (or an alias refers to itself)")
    if depth > MAX_DEPTH:
        raise InputError(path, None, f"nested more than {MAX_DEPTH} levels deep")
    return data


def parse_model(model: type[M], data: Any, path: str | Path | None) -> M:
    """Validate ``data`` against ``model``; the first error becomes one InputError."""
    if data is None:
        raise InputError(path, None, f"the file is empty (expected a mapping of {model.__name__} fields)")
    if not isinstance(data, dict):
        raise InputError(path, None, f"expected a mapping of {model.__name__} fields, got {_yaml_kind(data)}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise validation_error(exc, path, model) from None
    except (TypeError, ArithmeticError, RecursionError) as exc:  # a validator tripped over an absurd value
        raise InputError(path, None, f"invalid value: {exc}") from None


def validation_error(exc: ValidationError, path: str | Path | None, model: type[BaseModel] | None = None, skip: tuple[str, ...] = ()) -> InputError:
    """The first problem of a pydantic ValidationError as one InputError naming the file and field.

    ``skip``: names that are left out when they lead the location (the tag of a discriminated
    union, e.g. ``capacity`` in ``('capacity', 'convoy_sizes', 1)``).
    """
    errors = exc.errors()
    first = errors[0]
    loc = tuple(first["loc"])
    if loc and loc[0] in skip:
        loc = loc[1:]
    cause = (first.get("ctx") or {}).get("error")
    if isinstance(cause, FieldProblem):
        loc += tuple(cause.field.split("."))
    msg = " ".join(str(first["msg"]).split())
    if first["type"] == "extra_forbidden":
        allowed = _allowed_keys(model, loc[:-1]) if model is not None else []
        msg = "unknown key" + (" (allowed keys: " + ", ".join(allowed) + ")" if allowed else "")
    elif first["type"] == "missing":
        msg = "required field is missing"
    msg = msg.removeprefix("Value error, ").removeprefix("Assertion failed, ")
    more = f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})" if len(errors) > 1 else ""
    return InputError(path, field_path(loc, keep_last=first["type"] == "extra_forbidden") or None, msg + more)


def _yaml_kind(data: Any) -> str:
    """How a YAML document reads to a user: 'a list', 'a string', 'a number'."""
    if isinstance(data, list):
        return "a list"
    if isinstance(data, str):
        return "a string"
    if isinstance(data, bool):
        return "a boolean"
    if isinstance(data, (int, float)):
        return "a number"
    return type(data).__name__


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
