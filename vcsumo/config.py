"""Strict, typed configuration loaded from YAML files.

Every input file is parsed into a frozen pydantic model whose unknown keys are rejected
(``extra="forbid"``).  Problems become :class:`~vcsumo.errors.InputError` naming the file and the
field, e.g. ``networks/x/line.yaml: stations[2].km: ...`` (several problems: one each,
:class:`InputProblems`).

The options of a command are a :class:`CommandConfig`: the same model is built from a study file
(:meth:`CommandConfig.from_file`) and from the command line (:meth:`CommandConfig.from_options`),
so every bound is checked once for both, and a problem names the file and field or the option.
"""

from __future__ import annotations

import difflib
import re
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Literal, TypeVar, get_args, get_origin

import yaml
from pydantic import BaseModel, ConfigDict, PrivateAttr, ValidationError, ValidationInfo, field_validator

from vcsumo.errors import InputError
from vcsumo.loaded_files import note_loaded

M = TypeVar("M", bound=BaseModel)


class FieldProblem(ValueError):
    """Raised by a model validator about one field: the error then names ``field`` (relative to the model)."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


def unique_ids(model: M, *lists: str) -> M:
    """``model`` when the ``id`` of each item of each of its ``lists`` is unique, else a FieldProblem
    naming the second item with that id (for a model validator: ``return unique_ids(self, "services")``)."""
    for name in lists:
        ids = [x.id for x in getattr(model, name)]
        for k in (k for k, i in enumerate(ids) if i in ids[:k]):
            raise FieldProblem(f"{name}.{k}.id", f"duplicate {name[:-1]} id '{ids[k]}' (also {name}[{ids.index(ids[k])}])")
    return model


def _admits_bool(annotation: Any) -> bool:
    """Whether a field's type takes a boolean (bool, Any, a Literal of one, a union with one)."""
    if annotation is bool or annotation is Any:
        return True
    if get_origin(annotation) is Literal:
        return any(isinstance(a, bool) for a in get_args(annotation))
    return any(_admits_bool(a) for a in get_args(annotation) if a is not Ellipsis)


class StrictModel(BaseModel):
    """Base for every configuration model: unknown keys are errors, objects are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True, allow_inf_nan=False)
    """``allow_inf_nan=False``: no physical quantity of a vcsumo input is infinite or NaN, so ``.inf``
    and ``.nan`` in a file are errors (``none`` switches an optional limit off)."""

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_number(cls, value: Any, info: ValidationInfo) -> Any:
        """A boolean is no number: pydantic would read ``overlap_m: on`` (YAML 1.1: on/off/yes/no are
        booleans) as 1 and ``off`` as 0."""
        if isinstance(value, bool) and info.field_name in cls.model_fields and not _admits_bool(cls.model_fields[info.field_name].annotation):
            raise ValueError(f"'{str(value).lower()}' is a boolean (YAML reads true/false, yes/no, on/off so), not a value of this field")
        return value


_UNION_MEMBERS = frozenset({"str", "int", "float", "bool", "list", "dict", "none", "constrained-str", "constrained-float", "constrained-int"})


def _is_member(part: Any) -> bool:
    """Whether a location part is pydantic's name of a union member (``str``, ``function-after[...]``,
    a model class such as ``StockSpec``), not a key of the file (keys are snake_case or ids)."""
    return isinstance(part, str) and (part in _UNION_MEMBERS or "[" in part or re.fullmatch(r"[A-Z][a-z0-9]+(?:[A-Z][a-z0-9]*)+", part) is not None)


def field_path(loc: tuple[Any, ...], keep_last: bool = False) -> str:
    """Render a pydantic error location as ``stations[2].km``.

    The names pydantic gives union members (``str``, ``function-after[...]``) are left out, except
    the last part when ``keep_last`` (an unknown key the user wrote).
    """
    out = ""
    for i, part in enumerate(loc):
        if _is_member(part) and not (keep_last and i == len(loc) - 1):
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
    """Validate ``data`` against ``model``; its problems become InputErrors (:func:`validation_error`)."""
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


class InputProblems(InputError):
    """Several problems of one input (a file or the options of one command).

    ``str()`` is the first problem and how many more there are (one line, as every InputError);
    :attr:`problems` holds every one of them as its own InputError, which the command line prints
    one per line.
    """

    def __init__(self, problems: list[InputError]):
        first = problems[0]
        more = f" (and {len(problems) - 1} more problem{'s' if len(problems) > 2 else ''})"
        super().__init__(first.path, first.field, first.message + more)
        self.problems = problems


MAX_PROBLEMS_SHOWN = 20
"""Most problems of one input reported, one line each (a file of garbage would give thousands)."""


def validation_error(exc: ValidationError, path: str | Path | None, model: type[BaseModel] | None = None, skip: tuple[str, ...] = (),
                     rename: Callable[[tuple[Any, ...]], str] | None = None) -> InputError:
    """Every problem of a pydantic ValidationError as InputErrors naming the file and the field.

    One problem: one InputError; several: an :class:`InputProblems` holding each (the first
    :data:`MAX_PROBLEMS_SHOWN`).  ``skip``: names that are left out when they lead the location
    (the tag of a discriminated union, e.g. ``capacity`` in ``('capacity', 'convoy_sizes', 1)``).
    ``rename``: the name shown for a location instead of its field path (a command-line option).
    """
    errors = _one_per_union(exc.errors())
    problems = [_problem(e, path, model, skip, rename) for e in errors[:MAX_PROBLEMS_SHOWN]]
    return problems[0] if len(problems) == 1 else InputProblems(problems)


def _one_per_union(errors: list[Any]) -> list[Any]:
    """A value that fits no member of a union gets one error per member from pydantic; keep the
    errors of the members whose type it has (a mapping's problems, a string's format), or when it
    has none of their types, one error: "Input should be a valid string or a valid number"."""
    out: list[Any] = []
    groups: dict[tuple, list[Any]] = {}
    for e in errors:
        loc = tuple(e["loc"])
        i = next((i for i, p in enumerate(loc) if _is_member(p)), None)
        if i is None:
            out.append(e)
            continue
        if loc[:i] not in groups:
            groups[loc[:i]] = []
            out.append(loc[:i])  # the group's place in the order
        groups[loc[:i]].append(e)
    merged = []
    for item in out:
        if isinstance(item, dict):
            merged.append(item)
            continue
        errs = groups[item]
        fitting = [e for e in errs if not e["type"].endswith(("_type", "_parsing"))]
        if fitting or len(errs) == 1:
            merged += fitting or errs
            continue
        wanted = list(dict.fromkeys(str(e["msg"]).split(",")[0].removeprefix("Input should be ") for e in errs))
        merged.append(dict(errs[0], loc=item, type="union_type", msg="Input should be " + " or ".join(wanted)))
    return merged


def _problem(error: Any, path: str | Path | None, model: type[BaseModel] | None, skip: tuple[str, ...],
             rename: Callable[[tuple[Any, ...]], str] | None) -> InputError:
    loc = tuple(error["loc"])
    if loc and loc[0] in skip:
        loc = loc[1:]
    cause = (error.get("ctx") or {}).get("error")
    if isinstance(cause, FieldProblem):
        loc += tuple(int(p) if p.isdigit() else p for p in cause.field.split("."))  # "trains.2.id" -> trains[2].id
    msg = " ".join(str(error["msg"]).split())
    unknown = error["type"] == "extra_forbidden"
    if unknown:
        allowed = _allowed_keys(model, loc[:-1]) if model is not None else []
        close = difflib.get_close_matches(str(loc[-1]), allowed, n=1) if loc else []
        msg = "unknown key" + (f" (did you mean '{close[0]}'?)" if close else "") + (" (allowed keys: " + ", ".join(allowed) + ")" if allowed else "")
    elif error["type"] == "missing":
        msg = "required option is missing" if rename else "required field is missing"
    msg = msg.removeprefix("Value error, ").removeprefix("Assertion failed, ")
    given = error.get("input")
    if rename and error["type"] not in ("missing", "value_error") and isinstance(given, (str, int, float)):
        msg = f"{given}: {msg}"  # an option's value is shown: the command line is gone once the error is printed
    where = rename(loc) if rename and loc else field_path(loc, keep_last=unknown) or None
    return InputError(path, where, msg)


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
    """Read ``path`` as YAML and validate it against ``model`` (noted: :mod:`vcsumo.loaded_files`)."""
    out = parse_model(model, read_yaml(Path(path)), path)
    note_loaded(Path(path), model.__name__)
    return out


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


# --------------------------------------------------------------------------------------------
# The options of a command: one model for the command line and for study files


def option_name(model: type[BaseModel], field: str) -> str:
    """The command-line option of a field: ``json_schema_extra["option"]``, else ``--`` + the name
    with dashes (``block_length_m`` → ``--block-length-m``)."""
    info = model.model_fields.get(field)
    extra = info.json_schema_extra if info is not None and isinstance(info.json_schema_extra, dict) else {}
    return str(extra.get("option") or "--" + field.replace("_", "-"))


def looks_like_path(spec: str) -> bool:
    """Whether a name given in a file is a path (``my.yaml``, ``lines/x``, ``./x``) rather than a shipped name."""
    return spec.endswith((".yaml", ".yml")) or "/" in spec or "\\" in spec or spec.startswith((".", "~"))


def resolve_path(spec: str, base: Path) -> str:
    """A path written in a file at ``base`` is relative to that file; names and absolute paths stay."""
    if not isinstance(spec, str) or not spec or Path(spec).is_absolute():
        return spec
    try:
        if looks_like_path(spec) or (base / spec).exists():
            return str(base / spec)
    except (OSError, ValueError):  # a name the OS rejects is left for the loader to report
        pass
    return spec


class CommandConfig(StrictModel):
    """The options of one command, one field each, with bounds, unit and description.

    Built from the command line (:meth:`from_options`: a problem is ``--option-name: ...``) or from
    a study file (:meth:`from_file`: ``<file>: <field>: ...``, paths relative to the file).  Fields
    whose ``json_schema_extra`` has ``"path": True`` hold a file name or a shipped name (a list of
    them, or ``NAME:PARAMS`` with ``"path": "spec"``); ``"option"`` names the command-line option
    when it is not ``--`` + the field name.
    """

    _source: Path | None = PrivateAttr(default=None)

    @property
    def source(self) -> Path | None:
        """The study file this configuration was read from (None: the command line)."""
        return self._source

    @property
    def out_path(self) -> Path | None:
        """The results folder given (``out``), as a path; None: the command's default."""
        out = getattr(self, "out", None)
        return Path(out) if out else None

    def recorded_inputs(self) -> dict[str, Path]:
        """Input files a results folder records besides those the command loads: the study file."""
        return {"study": self._source} if self._source is not None else {}

    @classmethod
    def option_label(cls, loc: tuple[Any, ...]) -> str:
        """How a problem at ``loc`` is named on the command line: ``--convoy-sizes`` (item 2)."""
        head = option_name(cls, str(loc[0]))
        items = [f"item {p + 1}" for p in loc[1:] if isinstance(p, int)]
        return head + (f" ({', '.join(items)})" if items else "")

    @classmethod
    def from_options(cls, values: dict[str, Any]) -> "CommandConfig":
        """Validate the options given on the command line (field name → value; absent: the default)."""
        try:
            return cls.model_validate(values)
        except ValidationError as exc:
            raise validation_error(exc, None, cls, rename=cls.option_label) from None
        except (TypeError, ArithmeticError, RecursionError) as exc:
            raise InputError(None, None, f"invalid option value: {exc}") from None

    @classmethod
    def resolve_paths(cls, data: dict[str, Any], base: Path) -> dict[str, Any]:
        """``data`` with the path fields made relative to ``base`` (the study file's folder)."""
        out = dict(data)
        for name, info in cls.model_fields.items():
            kind = (info.json_schema_extra or {}).get("path") if isinstance(info.json_schema_extra, dict) else None
            if not kind or out.get(name) is None:
                continue
            fix = (lambda v: _resolve_spec(v, base)) if kind == "spec" else (lambda v: resolve_path(v, base))
            value = out[name]
            out[name] = [fix(v) for v in value] if isinstance(value, list) else fix(value)
        return out

    @classmethod
    def from_file(cls, data: dict[str, Any], path: Path) -> "CommandConfig":
        """Validate a study file's mapping; paths in it are relative to the file."""
        path = Path(path)
        cfg = parse_model(cls, cls.resolve_paths(data, path.resolve().parent), path)
        cfg._source = path
        return cfg

    def problem(self, field: str, message: str) -> InputError:
        """An InputError about ``field``: naming the study file and field, or the option."""
        if self._source is not None:
            return InputError(self._source, field, message)
        loc = tuple(int(x) if x.isdigit() else x for x in re.findall(r"[^.\[\]]+", field))
        return InputError(None, self.option_label(loc), message)

    @contextmanager
    def blame(self, field: str) -> Iterator[None]:
        """Input errors raised inside that name no file (a name looked up, e.g. an unknown line) are
        about ``field``: they are raised again naming the study file and field, or the option."""
        try:
            yield
        except InputError as exc:
            if exc.path is not None:
                raise
            raise self.problem(field, exc.message) from None


def _resolve_spec(spec: str, base: Path) -> str:
    """``NAME:PARAMS`` (a controller and its parameter file): a path after the colon is relative to ``base``."""
    if not isinstance(spec, str) or ":" not in spec:
        return resolve_path(spec, base) if isinstance(spec, str) and looks_like_path(spec) else spec
    name, params = spec.split(":", 1)
    return f"{name}:{resolve_path(params, base)}"
