"""Typed configuration from YAML: one frozen dataclass per component, strict checking.

``load_config(SomeConfig, path)`` reads a YAML mapping and builds ``SomeConfig`` from it,
recursing into nested dataclasses, lists and tuples. Unknown fields, missing required fields,
wrong types and failed ``__post_init__`` checks raise :class:`ConfigError`, whose message names
the file and the dotted field path (``configs/worlds/office.yaml: walls[3].height_m: expected a
number, got 'high'``). Nothing else in the project parses YAML into objects by hand.
"""

from __future__ import annotations

import dataclasses
import sys
import types
import typing
from pathlib import Path
from typing import Any, Mapping, Type, TypeVar

import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration file or mapping is invalid. The message names the file and the field."""

    def __init__(self, source: str, field: str, problem: str):
        self.source = source
        self.field = field
        self.problem = problem
        where = f"{source}: {field}: " if field else f"{source}: "
        super().__init__(where + problem)


def read_yaml_mapping(path: str | Path) -> dict:
    """Read a YAML file that must hold a mapping; errors name the file."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(str(path), "", "is a folder, expected a YAML file")
    if not path.is_file():
        raise ConfigError(str(path), "", "file not found")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise ConfigError(str(path), "", f"not valid YAML{where}: {problem}") from None
    except UnicodeDecodeError:
        raise ConfigError(str(path), "", "not a text file (not UTF-8)") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(str(path), "", f"expected a mapping at the top level, got {type(data).__name__}")
    return data


def load_config(cls: Type[T], path: str | Path, overrides: Mapping[str, Any] | None = None,
                section: str | None = None) -> T:
    """Build dataclass ``cls`` from the YAML file at ``path`` (plus top-level ``overrides``).

    ``section``: when the file has this top-level key (a stack config), build ``cls`` from that
    section alone (errors name ``section.field``); otherwise from the whole file."""
    data = read_yaml_mapping(path)
    field = ""
    if section is not None and section in data:
        data, field = data[section], section
        if not isinstance(data, dict):
            raise ConfigError(str(path), section, f"expected a mapping, got {_describe(data)}")
    if overrides:
        data = {**data, **overrides}
    return from_mapping(cls, data, source=str(path), field=field)


def from_mapping(cls: Type[T], data: Any, source: str = "<config>", field: str = "") -> T:
    """Build dataclass ``cls`` from a plain mapping, checking every field."""
    return _convert(cls, data, source, field)


def without_unknown(cls: Type[T], data: Mapping, field: str = "") -> tuple[dict, list[str]]:
    """``data`` less the fields ``cls`` does not have, down through nested dataclasses, and those
    fields' dotted names: for reading a record written by an older version of the code, where a
    field removed since would otherwise stop :func:`from_mapping`."""
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    kept, dropped = {}, []
    for name, value in data.items():
        path = _join(field, str(name))
        if name not in fields:
            dropped.append(path)
            continue
        tp = hints[name]
        inner = [a for a in typing.get_args(tp) if a is not type(None)] if _is_union(tp) else [tp]
        if isinstance(value, Mapping) and len(inner) == 1 and dataclasses.is_dataclass(inner[0]):
            value, below = without_unknown(inner[0], value, path)
            dropped += below
        kept[name] = value
    return kept, dropped


def to_mapping(obj: Any) -> Any:
    """The inverse of :func:`from_mapping`: plain dicts, lists and scalars, ready for YAML/JSON."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_mapping(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_mapping(v) for k, v in obj.items()}
    return obj


def _is_union(tp: Any) -> bool:
    """``Optional[X]``, ``Union[X, Y]`` or ``X | Y``."""
    origin = typing.get_origin(tp)
    return origin is typing.Union or (sys.version_info >= (3, 10) and origin is types.UnionType)


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _join(field: str, name: str) -> str:
    return f"{field}.{name}" if field else name


def _convert(tp: Any, value: Any, source: str, field: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)

    if tp is Any:
        return value
    if _is_union(tp):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, source, field)
            except ConfigError as exc:
                errors.append(exc.problem)
        raise ConfigError(source, field, "; ".join(errors) or f"unexpected value {_describe(value)}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(source, field, f"expected one of {list(args)}, got {_describe(value)}")
        return value
    if dataclasses.is_dataclass(tp):
        return _convert_dataclass(tp, value, source, field)
    if origin in (list, tuple) or tp in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(source, field, f"expected a list, got {_describe(value)}")
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                raise ConfigError(source, field, f"expected a list of {len(args)} items, got {len(value)}")
            return tuple(_convert(a, v, source, f"{field}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
        item_tp = args[0] if args else Any
        items = [_convert(item_tp, v, source, f"{field}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if (origin is tuple or tp is tuple) else items
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise ConfigError(source, field, f"expected a mapping, got {_describe(value)}")
        val_tp = args[1] if args else Any
        return {str(k): _convert(val_tp, v, source, _join(field, str(k))) for k, v in value.items()}
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(source, field, f"expected a number, got {_describe(value)}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(source, field, f"expected an integer, got {_describe(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(source, field, f"expected true or false, got {_describe(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(source, field, f"expected a string, got {_describe(value)}")
        return value
    return value


def _convert_dataclass(cls: Any, value: Any, source: str, field: str) -> Any:
    if isinstance(value, cls):
        return value
    if not isinstance(value, dict):
        raise ConfigError(source, field, f"expected a mapping for {cls.__name__}, got {_describe(value)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(value) - set(fields))
    if unknown:
        raise ConfigError(source, _join(field, str(unknown[0])),
                          f"unknown field (known: {', '.join(sorted(fields))})")
    kwargs = {}
    for name, f in fields.items():
        if name in value:
            kwargs[name] = _convert(hints[name], value[name], source, _join(field, name))
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(source, _join(field, name), "required field is missing")
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        if isinstance(exc, ConfigError):
            raise
        # validators start their message with the field's name: name that field in the path
        message = str(exc)
        name, _, rest = message.partition(" ")
        if name.split(".")[0] in fields and rest:
            raise ConfigError(source, _join(field, name), rest if rest.startswith("must ") else message) from None
        raise ConfigError(source, field or cls.__name__, message) from None
