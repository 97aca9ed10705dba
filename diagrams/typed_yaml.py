"""Typed loading of nested config dataclasses from YAML, through their constructors.

``pydrake.common.yaml.yaml_load_typed`` fills a default-constructed dataclass attribute by
attribute: it cannot set frozen dataclasses and it bypasses ``__post_init__`` validation. Our
configs are frozen and validate themselves, so scenarios are loaded here instead: the YAML is
parsed with ``yaml_load_data`` (Drake's parser) and every dataclass is built by calling its
constructor with the merged fields, so every value is checked exactly as in Python code.
Unknown keys are errors that name the full path of the key.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping

import yaml
from pydrake.common.yaml import yaml_load_data

__all__ = ["config_from_data", "load_yaml_text", "merge_data"]


def load_yaml_text(text: str, source: str = "YAML") -> dict:
    """Parses YAML text into plain data (a mapping at the top).

    Raises:
        ValueError: a syntax error (naming ``source``, the line and the column) or a top
            level that is not a mapping.
    """
    try:
        data = yaml_load_data(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = "" if mark is None else f" at line {mark.line + 1}, column {mark.column + 1}"
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise ValueError(f"{source}: not valid YAML{where}: {problem}") from None
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ValueError(f"{source} must be a mapping at the top level; got "
                         f"{type(data).__name__}")
    return dict(data)


def merge_data(base, override):
    """Recursive merge: mappings merge key by key, anything else in ``override`` replaces."""
    if isinstance(base, Mapping) and isinstance(override, Mapping):
        merged = dict(base)
        for key, value in override.items():
            merged[key] = merge_data(base[key], value) if key in base else value
        return merged
    return override


def _convert(value, hint, path: str):
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is typing.Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for option in args:
            if option is type(None):
                continue
            try:
                return _convert(value, option, path)
            except (TypeError, ValueError) as error:
                errors.append(str(error))
        raise ValueError(f"{path} = {value!r} matches none of {hint}: " + "; ".join(errors))
    if dataclasses.is_dataclass(hint):
        if dataclasses.is_dataclass(value):
            return value
        if not isinstance(value, Mapping):
            raise ValueError(f"{path} = {value!r} must be a mapping of {hint.__name__} fields")
        return config_from_data(hint, value, path=path)
    if origin in (tuple, list) or hint in (tuple, list):
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
            raise ValueError(f"{path} = {value!r} must be a list")
        if args and len(args) == 2 and args[1] is Ellipsis:
            items = [_convert(v, args[0], f"{path}[{i}]") for i, v in enumerate(value)]
        elif args:
            if len(args) != len(value):
                raise ValueError(f"{path} = {value!r} must have {len(args)} entries")
            items = [_convert(v, a, f"{path}[{i}]") for i, (v, a) in enumerate(zip(value, args))]
        else:
            items = list(value)
        return tuple(items) if (origin is tuple or hint is tuple) else items
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{path} = {value!r} must be a number")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{path} = {value!r} must be an integer")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{path} = {value!r} must be true or false")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ValueError(f"{path} = {value!r} must be a string")
        return value
    if origin is dict or hint is dict:
        if not isinstance(value, Mapping):
            raise ValueError(f"{path} = {value!r} must be a mapping")
        return dict(value)
    return value


def config_from_data(cls, data: Mapping, *, path: str | None = None):
    """Builds dataclass ``cls`` from plain data; its defaults fill missing fields.

    Raises:
        ValueError: on an unknown key (naming its path), a value of the wrong type, or
            whatever the config's own validation rejects (prefixed with the path).
    """
    path = path or cls.__name__
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(
            f"{path}: unknown key(s) {unknown}; the known keys are {sorted(fields)}")
    kwargs = {name: _convert(value, hints[name], f"{path}.{name}")
              for name, value in data.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as error:
        message = str(error)
        raise ValueError(message if message.startswith(path) else f"{path}: {message}") \
            from None
