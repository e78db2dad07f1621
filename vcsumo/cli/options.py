"""Command-line options generated from a command's configuration model.

:func:`config_command` turns a :class:`~vcsumo.config.CommandConfig` into a click command: one
option per field (``--`` + the field name with dashes, or the field's ``option``), its help text
from the field's description and default.  click passes every value through as text; the model
converts and checks it with the same bounds as a study file's field, so ``--block-length-m -500``
is ``error: --block-length-m: -500: Input should be greater than or equal to 100`` (exit 2) before
anything runs.  Lists are comma-separated (``--convoy-sizes 1,2,3``; ``''`` is an empty list);
options marked ``multiple`` may also be repeated (``--train a --train b``); booleans are flags.

A command is then::

    @config_command(CapacityConfig, "capacity")
    def capacity_cmd(cfg: CapacityConfig) -> None:
        \"\"\"Help text.\"\"\"
        run_capacity(cfg)
"""

from __future__ import annotations

import types
import typing
from typing import Any, Callable, Literal, get_args, get_origin

import click
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from vcsumo.config import CommandConfig, option_name


def _without_none(annotation: Any) -> Any:
    if get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in get_args(annotation) if a is not type(None)]
        return args[0] if len(args) == 1 else annotation
    return annotation


def _base(annotation: Any) -> Any:
    """The type inside ``Annotated[...]`` and ``X | None``."""
    annotation = _without_none(annotation)
    while get_origin(annotation) is typing.Annotated:
        annotation = _without_none(get_args(annotation)[0])
    return annotation


def is_list(info: FieldInfo) -> bool:
    return get_origin(_base(info.annotation)) is list


def _extra(info: FieldInfo) -> dict:
    return info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}


def _metavar(info: FieldInfo) -> str:
    ann = _base(info.annotation)
    item = _base(get_args(ann)[0]) if get_origin(ann) is list else ann
    if get_origin(item) is Literal:
        choices = "|".join(str(a) for a in get_args(item))
        return f"[{choices}],..." if get_origin(ann) is list else f"[{choices}]"
    word = {int: "INTEGER", float: "NUMBER"}.get(item, "TEXT")
    return f"{word},..." if get_origin(ann) is list else word


def default_text(info: FieldInfo) -> str | None:
    """The default shown in ``--help`` (None: nothing to show)."""
    if info.default_factory is not None:
        value = info.default_factory()  # type: ignore[call-arg]
    elif info.default is PydanticUndefined or info.default is None or info.default is False:
        return None
    else:
        value = info.default
    if isinstance(value, list):
        return ",".join(map(str, value)) if value else None
    return f"{value:g}" if isinstance(value, float) else str(value)


def field_option(model: type[CommandConfig], name: str, info: FieldInfo) -> click.Option:
    """The click option of one field: text passed through to the model (a flag for a boolean)."""
    opt = option_name(model, name)
    help_text = (info.description or "").strip()
    if info.is_required():
        help_text += " [required]"
    if _base(info.annotation) is bool:
        return click.Option([opt, name], is_flag=True, default=False, help=help_text)
    shown = default_text(info)
    multiple = bool(_extra(info).get("multiple"))
    if multiple:
        help_text += " (repeat the option or separate by commas)"
    if shown is not None:
        help_text += f"  [default: {shown}]"
    return click.Option([opt, name], type=str, default=None, multiple=multiple, metavar=_metavar(info), help=help_text)


def option_values(model: type[CommandConfig], raw: dict[str, Any]) -> dict[str, Any]:
    """The options given (not their defaults), as the model takes them: lists split on commas."""
    values: dict[str, Any] = {}
    for name, value in raw.items():
        info = model.model_fields.get(name)
        if info is None or value is None or value == () or value is False:
            continue
        if is_list(info):
            parts = value if isinstance(value, tuple) else (value,)
            value = [x.strip() for p in parts for x in p.split(",") if x.strip()]
        elif isinstance(value, tuple):
            value = value[-1]
        values[name] = value
    return values


def config_command(model: type[CommandConfig], name: str, **settings: Any) -> Callable[[Callable[[Any], None]], click.Command]:
    """A click command whose options are the fields of ``model``; the function gets the validated model."""

    def make(fn: Callable[[Any], None]) -> click.Command:
        def callback(**raw: Any) -> None:
            return fn(model.from_options(option_values(model, raw)))

        params = [field_option(model, n, info) for n, info in model.model_fields.items()]
        cmd = click.Command(name, callback=callback, params=params, help=fn.__doc__, **settings)
        cmd.config_model = model  # type: ignore[attr-defined]
        return cmd

    return make
