"""Generic validation of nested TOML tables into frozen dataclasses.

A section is a frozen dataclass whose fields are declared with `option(...)`: a default (or REQUIRED),
a one-line doc, and limits (choices, bounds, length). `build(cls, table, path)` rejects unknown keys,
missing required keys, wrong types, NaN/inf and out-of-range values with a SceneError naming the key
path, then runs the section's optional `check(path)` for constraints between keys.
"""

import dataclasses
import math
import typing

from psph.errors import SceneError

REQUIRED = dataclasses.MISSING


def option(default=REQUIRED, *, doc: str, choices=None, ge=None, gt=None, le=None, lt=None,
           length=None):
    """Declare a scene key. `length` constrains tuples: an int, or the name of an int sibling key."""
    meta = {"doc": doc, "choices": choices, "ge": ge, "gt": gt, "le": le, "lt": lt, "length": length}
    if isinstance(default, (list, dict)):
        raise TypeError("use tuples for sequence defaults")
    if dataclasses.is_dataclass(default):
        return dataclasses.field(default_factory=lambda: default, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _type_name(tp) -> str:
    origin = typing.get_origin(tp)
    if origin is tuple:
        return f"array of {_type_name(typing.get_args(tp)[0])}"
    if dataclasses.is_dataclass(tp):
        return "table"
    return {int: "integer", float: "number", bool: "boolean", str: "string"}.get(tp, str(tp))


def _describe(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _scalar(tp, value, path):
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = float(value)
            if not math.isfinite(value):
                raise SceneError(path, f"must be a finite number, got {_describe(value)}")
            return value
    elif tp is str:
        if isinstance(value, str):
            return value
    raise SceneError(path, f"expected {_type_name(tp)}, got {type(value).__name__} {_describe(value)}")


def _convert(tp, value, path):
    if dataclasses.is_dataclass(tp):
        return build(tp, value, path)
    if typing.get_origin(tp) is tuple:
        if not isinstance(value, (list, tuple)):
            raise SceneError(path, f"expected {_type_name(tp)}, got {type(value).__name__} {_describe(value)}")
        item = typing.get_args(tp)[0]
        return tuple(_convert(item, v, f"{path}[{k}]") for k, v in enumerate(value))
    return _scalar(tp, value, path)


def _check_limits(meta, value, path, siblings):
    items = value if isinstance(value, tuple) else (value,)
    choices = meta.get("choices")
    for v in items:
        if choices is not None and v not in choices:
            raise SceneError(path, f"{_describe(v)} is not one of: {', '.join(map(str, choices))}")
        for key, ok, word in (("ge", lambda a, b: a >= b, ">="), ("gt", lambda a, b: a > b, ">"),
                              ("le", lambda a, b: a <= b, "<="), ("lt", lambda a, b: a < b, "<")):
            bound = meta.get(key)
            if bound is not None and not ok(v, bound):
                raise SceneError(path, f"must be {word} {bound}, got {_describe(v)}")
    length = meta.get("length")
    if length is not None and isinstance(value, tuple):
        want = siblings[length] if isinstance(length, str) else length
        if len(value) != want:
            why = f" ({length} = {want})" if isinstance(length, str) else ""
            raise SceneError(path, f"expected {want} entries{why}, got {len(value)}")


def build(cls, table, path: str = ""):
    """Validate `table` (a dict from TOML) into dataclass `cls`; errors name the key path."""
    where = path or "scene"
    if not isinstance(table, dict):
        raise SceneError(where, f"expected a table, got {type(table).__name__} {_describe(table)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in table:
        if key not in fields:
            raise SceneError(f"{path}.{key}" if path else str(key),
                             f"unknown key (valid keys: {', '.join(fields)})")
    hints = typing.get_type_hints(cls)
    values = {}
    for name, f in fields.items():
        key = f"{path}.{name}" if path else name
        if name in table:
            values[name] = _convert(hints[name], table[name], key)
        elif f.default is not REQUIRED:
            values[name] = f.default
        elif f.default_factory is not REQUIRED:
            values[name] = f.default_factory()
        else:
            raise SceneError(key, "required key missing")
    for name, f in fields.items():
        key = f"{path}.{name}" if path else name
        _check_limits(f.metadata, values[name], key, values)
    obj = cls(**values)
    check = getattr(obj, "check", None)
    if check is not None:
        check(path)
    return obj


def to_table(obj) -> dict:
    """A dataclass back to plain TOML-like data (tuples as lists)."""
    out = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v):
            out[f.name] = to_table(v)
        elif isinstance(v, tuple):
            out[f.name] = [to_table(x) if dataclasses.is_dataclass(x) else x for x in v]
        else:
            out[f.name] = v
    return out


def describe_keys(cls, path: str = ""):
    """(key path, type, default, doc) for every key of `cls`, for documentation and `psph info`."""
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        key = f"{path}.{f.name}" if path else f.name
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            rows += describe_keys(tp, key)
            continue
        default = "required" if f.default is REQUIRED else f.default
        rows.append((key, _type_name(tp), default, f.metadata.get("doc", "")))
        item = typing.get_args(tp)[0] if typing.get_origin(tp) is tuple else None
        if dataclasses.is_dataclass(item):  # an array of tables ([[bodies]]): the keys of each entry
            rows += describe_keys(item, f"{key}[]")
    return rows
