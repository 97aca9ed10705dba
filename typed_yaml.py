"""Typed loading of nested config dataclasses from YAML, through their constructors.

``pydrake.common.yaml.yaml_load_typed`` fills a default-constructed dataclass attribute by
attribute: it cannot set frozen dataclasses and it bypasses ``__post_init__`` validation. Our
configs are frozen and validate themselves, so scenarios are loaded here instead: the YAML is
parsed as plain data within bounds (:func:`load_yaml_text`: size, nesting, aliases, string keys
given once) and every dataclass is built by calling its constructor with the merged fields, so
every value is checked exactly as in Python code. Unknown keys are errors that name the full
path of the key, and a config's own error naming one of its fields is given the key path.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from collections.abc import Mapping

import yaml

from telesmooth.user_input import (
    MAX_YAML_ALIASES,
    MAX_YAML_BYTES,
    MAX_YAML_DEPTH,
    MAX_YAML_NODES,
    MAX_YAML_SCALAR_CHARS,
    describe_size,
    leading_field,
    quote,
)

__all__ = ["config_from_data", "load_yaml_text", "merge_data"]


def load_yaml_text(text: str, source: str = "YAML") -> dict:
    """Parses YAML text into plain data (a mapping at the top), within bounds.

    The YAML is plain data: mappings whose keys are strings, each given once, lists and
    scalars. Anchors, aliases and merge keys (``<<: *defaults``) work, but the text may not
    exceed ``MAX_YAML_BYTES``, nest deeper than ``MAX_YAML_DEPTH``, use more than
    ``MAX_YAML_ALIASES`` aliases or expand (aliases counted in full) to more than
    ``MAX_YAML_NODES`` nodes, or hold a scalar longer than ``MAX_YAML_SCALAR_CHARS``: these
    are checked on the event stream, before anything is built, so an alias bomb ("billion
    laughs") costs no memory. As in Drake's ``yaml_load_data``, top-level keys that start
    with ``_`` are dropped (a place for anchors).

    Raises:
        ValueError: naming ``source``, the key path and the line: a syntax error, a bound
            exceeded, a key that is not a string (``{1: 2}``, ``{~: 2}``), a key given twice
            in one mapping, or a top level that is not a mapping.
    """
    if len(text) > MAX_YAML_BYTES or len(text.encode("utf-8", "surrogatepass")) > MAX_YAML_BYTES:
        raise ValueError(f"{source}: {describe_size(len(text.encode('utf-8', 'surrogatepass')))}"
                         f" of YAML; the limit is {describe_size(MAX_YAML_BYTES)}")
    try:
        _check_yaml_events(text, source)
        loader = _PlainDataLoader(text)
        try:
            node = loader.get_single_node()
            if node is None:
                return {}
            _check_mapping_keys(node, source)
            data = loader.construct_document(node)
        finally:
            loader.dispose()
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = "" if mark is None else f" at line {mark.line + 1}, column {mark.column + 1}"
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise ValueError(f"{source}: not valid YAML{where}: {problem}") from None
    if not isinstance(data, Mapping):
        raise ValueError(f"{source} must be a mapping at the top level; got "
                         f"{type(data).__name__}")
    return {key: value for key, value in data.items() if not key.startswith("_")}


class _PlainDataLoader(yaml.SafeLoader):
    """PyYAML's safe loader (no Python objects from tags)."""


def _line(node_or_event) -> int:
    return node_or_event.start_mark.line + 1


def _check_yaml_events(text: str, source: str) -> None:
    """Depth, scalar length, alias count and expanded size, from the event stream alone."""
    depth = 0
    nodes = 0
    aliases = 0
    open_anchors = []            # (anchor or None, node count at the collection's start)
    anchor_sizes = {}
    for event in yaml.parse(text, Loader=_PlainDataLoader):
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                raise ValueError(f"{source}: nesting deeper than {MAX_YAML_DEPTH} levels at "
                                 f"line {_line(event)}")
            nodes += 1
            open_anchors.append((event.anchor, nodes))
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1
            anchor, start = open_anchors.pop()
            if anchor is not None:
                anchor_sizes[anchor] = nodes - start + 1
        elif isinstance(event, yaml.ScalarEvent):
            if len(event.value) > MAX_YAML_SCALAR_CHARS:
                raise ValueError(f"{source}: line {_line(event)}: the value "
                                 f"{quote(event.value, 40)} is longer than "
                                 f"{MAX_YAML_SCALAR_CHARS} characters")
            nodes += 1
            if event.anchor is not None:
                anchor_sizes[event.anchor] = 1
        elif isinstance(event, yaml.AliasEvent):
            aliases += 1
            if aliases > MAX_YAML_ALIASES:
                raise ValueError(f"{source}: more than {MAX_YAML_ALIASES} aliases (line "
                                 f"{_line(event)})")
            nodes += anchor_sizes.get(event.anchor, 1)
        if nodes > MAX_YAML_NODES:
            raise ValueError(f"{source}: expands to more than {MAX_YAML_NODES} values with its "
                             f"aliases (line {_line(event)}); write the values out")


_STR_TAG = "tag:yaml.org,2002:str"
_MERGE_TAG = "tag:yaml.org,2002:merge"
_TAG_NAMES = {"tag:yaml.org,2002:int": "an integer", "tag:yaml.org,2002:float": "a number",
              "tag:yaml.org,2002:null": "null", "tag:yaml.org,2002:bool": "a boolean",
              "tag:yaml.org,2002:timestamp": "a date"}


def _check_mapping_keys(root, source: str) -> None:
    """Every mapping key is a string given once (merge keys aside); errors name the path."""
    seen = set()
    stack = [(root, "")]
    while stack:
        node, path = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.SequenceNode):
            stack.extend((item, f"{path}[{index}]") for index, item in enumerate(node.value))
            continue
        if not isinstance(node, yaml.MappingNode):
            continue
        marks = {}
        where = path or "the top level"
        for key, value in node.value:
            if key.tag == _MERGE_TAG:
                stack.append((value, path))
                continue
            if not isinstance(key, yaml.ScalarNode) or key.tag != _STR_TAG:
                what = ("a list" if isinstance(key, yaml.SequenceNode) else
                        "a mapping" if isinstance(key, yaml.MappingNode) else
                        _TAG_NAMES.get(key.tag, f"tagged {key.tag}"))
                text = key.value if isinstance(key, yaml.ScalarNode) else "…"
                raise ValueError(f"{source}: line {_line(key)}: the key {quote(text, 40)} in "
                                 f"{where} is {what}, not a name; keys are names such as "
                                 "'arm' (quote it if you mean a string)")
            child = f"{path}.{key.value}" if path else key.value
            if key.value in marks:
                first, second = marks[key.value], key.start_mark
                where_given = (f"lines {first.line + 1} and {second.line + 1}"
                               if first.line != second.line else
                               f"line {first.line + 1}, columns {first.column + 1} and "
                               f"{second.column + 1}")
                raise ValueError(f"{source}: {quote(child, 80)} is given twice ({where_given}); "
                                 "keep one")
            marks[key.value] = key.start_mark
            stack.append((value, child))


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
        raise ValueError(f"{path} = {quote(value)} matches none of {hint}: " + "; ".join(errors))
    if dataclasses.is_dataclass(hint):
        if dataclasses.is_dataclass(value):
            return value
        if not isinstance(value, Mapping):
            raise ValueError(
                f"{path} = {quote(value)} must be a mapping of {hint.__name__} fields")
        return config_from_data(hint, value, path=path)
    if origin in (tuple, list) or hint in (tuple, list):
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
            raise ValueError(f"{path} = {quote(value)} must be a list")
        if args and len(args) == 2 and args[1] is Ellipsis:
            items = [_convert(v, args[0], f"{path}[{i}]") for i, v in enumerate(value)]
        elif args:
            if len(args) != len(value):
                raise ValueError(f"{path} = {quote(value)} must have {len(args)} entries")
            items = [_convert(v, a, f"{path}[{i}]") for i, (v, a) in enumerate(zip(value, args))]
        else:
            items = list(value)
        return tuple(items) if (origin is tuple or hint is tuple) else items
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{path} = {quote(value)} must be a number")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{path} = {quote(value)} must be an integer")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{path} = {quote(value)} must be true or false")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ValueError(f"{path} = {quote(value)} must be a string")
        return value
    if origin is dict or hint is dict:
        if not isinstance(value, Mapping):
            raise ValueError(f"{path} = {quote(value)} must be a mapping")
        return dict(value)
    return value


def config_from_data(cls, data: Mapping, *, path: str | None = None):
    """Builds dataclass ``cls`` from plain data; its defaults fill missing fields.

    Args:
        cls: The config dataclass.
        data: Its fields as plain data (e.g. from :func:`load_yaml_text`).
        path: The key path of ``data`` for messages (``"haptic"``); ``""`` for the top level;
            default the class name.

    Raises:
        ValueError: on an unknown key (naming its path), a value of the wrong type, or
            whatever the config's own validation rejects. A message of the config that starts
            with one of its field names (``"period_s = -1 must be > 0"``) gets the key path
            (``"haptic.period_s = -1 must be > 0"``); any other is prefixed with the path.
    """
    path = cls.__name__ if path is None else path
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(str(key) for key in set(data) - set(fields))
    if unknown:
        raise ValueError(
            f"{path or 'the top level'}: unknown key(s) {quote(unknown, 100)}; the known keys "
            f"are {sorted(fields)}")
    kwargs = {name: _convert(value, hints[name], _child(path, name))
              for name, value in data.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as error:
        raise ValueError(_with_path(str(error), path, fields, cls.__name__)) from None


def _child(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _with_path(message: str, path: str, fields, cls_name: str = "") -> str:
    """``message`` of a config at ``path``, its leading field name given the key path."""
    if not path or re.match(re.escape(path) + r"(?=[.\[ :=]|$)", message):
        return message
    own = f"{cls_name}."
    if message.startswith(own) and leading_field(message[len(own):]) in fields:
        message = message[len(own):]     # "DelayFifoConfig.period_s = 0" names the field
    if leading_field(message) in fields:
        return f"{path}.{message}"
    return f"{path}: {message}"
