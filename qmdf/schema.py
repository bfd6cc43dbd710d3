"""Typed config schemas: dataclasses with declared bounds, checked so that *every* problem is reported.

Hydra (through OmegaConf) stops at the first bad value. A user fixing a sweep wants the whole list at
once, so each section of the composed config is checked here against its dataclass: unknown keys (with a
suggestion), wrong types, values out of bounds, and the section's own cross-field ``check``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any, Iterable

from omegaconf import DictConfig, ListConfig, OmegaConf

from qmdf.errors import Problem

_MISSING = dataclasses.MISSING


def param(
    default: Any = _MISSING,
    *,
    factory: Any = _MISSING,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: Sequence[Any] | None = None,
    doc: str = "",
    schemas: Any = None,
) -> Any:
    """A dataclass field with bounds that ``check_section`` enforces and a one-line doc for listings.
    ``schemas() -> {name: dataclass}``: a mapping field whose entries are settings of registered components (a
    sheet step's, a backbone's), for listings."""
    meta = {"gt": gt, "ge": ge, "lt": lt, "le": le, "choices": tuple(choices) if choices else None, "doc": doc}
    meta["schemas"] = schemas
    if factory is not _MISSING:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def to_plain(node: Any) -> Any:
    """OmegaConf containers to plain Python containers (resolving interpolations)."""
    if isinstance(node, (DictConfig, ListConfig)):
        return OmegaConf.to_container(node, resolve=True)
    return node


def defaults_of(schema: type) -> dict[str, Any]:
    """The schema's defaults as a plain dict (what the composed config starts from)."""
    return dataclasses.asdict(schema())


def _suggest(key: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(key, list(known), n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _join(path: str, key: Any) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else str(key)


def _field_of(key: str, path: str) -> str:
    """The field of section ``path`` that problem key ``key`` is about (``a.b[0].c`` -> ``b`` for ``a``)."""
    rest = key[len(path) + 1 :] if path else key
    return re.split(r"[.\[]", rest)[0]


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _check_type(tp: Any, value: Any, path: str) -> list[Problem]:
    """Problems with ``value`` against annotation ``tp`` (a small, explicit subset of typing)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return []
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return []
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _check_type(inner[0], value, path)
        for a in inner:
            if not _check_type(a, value, path):
                return []
        return [Problem(path, f"expected one of {', '.join(map(_type_name, inner))}, got {value!r}")]
    if value is None:
        return [Problem(path, f"must be set (expected {_type_name(tp)})")]
    if dataclasses.is_dataclass(tp):
        return check_section(tp, value, path)
    if origin in (list, tuple, Sequence) or tp in (list, tuple):
        if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, ListConfig)):
            return [Problem(path, f"expected a list, got {value!r}")]
        item = args[0] if args else Any
        out: list[Problem] = []
        for i, v in enumerate(value):
            out += _check_type(item, v, _join(path, i))
        return out
    if origin in (dict, Mapping) or tp is dict:
        if not isinstance(value, (Mapping, DictConfig)):
            return [Problem(path, f"expected a mapping, got {value!r}")]
        item = args[1] if len(args) == 2 else Any
        out = []
        for k, v in value.items():
            out += _check_type(item, v, _join(path, k))
        return out
    if tp is bool:
        return [] if isinstance(value, bool) else [Problem(path, f"expected true/false, got {value!r}")]
    if tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        return [] if ok else [Problem(path, f"expected an integer, got {value!r}")]
    if tp is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if ok and not math.isfinite(float(value)):
            return [Problem(path, f"must be a finite number, got {value!r}")]
        return [] if ok else [Problem(path, f"expected a number, got {value!r}")]
    if tp is str:
        return [] if isinstance(value, str) else [Problem(path, f"expected a string, got {value!r}")]
    return []


def _check_bounds(meta: Mapping[str, Any], value: Any, path: str) -> list[Problem]:
    if value is None:
        return []
    choices = meta.get("choices")
    if choices and value not in choices:
        return [Problem(path, f"must be one of {', '.join(map(str, choices))}; got {value!r}")]
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return []
    for key, ok, word in (
        ("gt", lambda b: value > b, ">"),
        ("ge", lambda b: value >= b, ">="),
        ("lt", lambda b: value < b, "<"),
        ("le", lambda b: value <= b, "<="),
    ):
        bound = meta.get(key)
        if bound is not None and not ok(bound):
            return [Problem(path, f"must be {word} {bound}, got {value!r}")]
    return []


def check_section(schema: type, node: Any, path: str) -> list[Problem]:
    """Every problem of ``node`` against dataclass ``schema``; then the schema's own ``check()``."""
    if not isinstance(node, (Mapping, DictConfig)):
        return [Problem(path or "<root>", f"expected a mapping of {schema.__name__} settings, got {node!r}")]
    hints = typing.get_type_hints(schema)
    fields = {f.name: f for f in dataclasses.fields(schema)}
    problems = [
        Problem(_join(path, k), f"unknown key{_suggest(str(k), fields)}; known keys: {', '.join(fields)}")
        for k in node.keys()
        if k not in fields
    ]
    for name, f in fields.items():
        if name not in node:
            continue
        value = node[name]
        found = _check_type(hints[name], value, _join(path, name))
        problems += found or _check_bounds(f.metadata, value, _join(path, name))
    check = getattr(schema, "check", None)
    if check is not None:
        # Run the cross-field check even when some fields are bad, so that one pass lists everything;
        # fields that failed above are replaced by their defaults for the check.
        bad = {_field_of(p.key, path) for p in problems}
        usable = {k: v for k, v in node.items() if k in fields and k not in bad}
        try:
            instance = build(schema, usable)
        except Exception:  # a value the check cannot even hold: already reported above
            return problems
        problems += [Problem(_join(path, k) if k else path, msg) for k, msg in check(instance)]
    return problems


def registered_defaults(registry: Any) -> dict[str, dict]:
    """Every registered component's default settings by name (a table's defaults, so that ``NAME.key=value`` always
    has a place)."""
    return {e.name: defaults_of(e.config) for e in registry.entries() if e.config is not None}


def registered_schemas(registry: Any) -> dict[str, type]:
    """Every registered component's settings dataclass by name (``param(schemas=...)``, for listings)."""
    return {e.name: e.config for e in registry.entries() if e.config is not None}


def check_registered(table: Mapping[str, Any], registry: Any, path: str) -> list[tuple[str, str]]:
    """Problems of a name -> settings table whose names are ``registry``'s components (a degradation's, a
    backbone's, a loss's, a sheet step's): each unknown name, and each entry against its component's schema; keys
    relative to the section, as a schema's ``check`` returns them."""
    problems: list[tuple[str, str]] = []
    for name, settings in table.items():
        if name not in registry:
            problems.append((f"{path}.{name}", registry.why_missing(name)))
        elif registry.get(name).config is not None:
            found = check_section(registry.get(name).config, settings or {}, f"{path}.{name}")
            problems += [(p.key, p.message) for p in found]
    return problems


def _build_value(tp: Any, value: Any) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if value is None:
        return None
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return _build_value(inner[0], value) if len(inner) == 1 else to_plain(value)
    if dataclasses.is_dataclass(tp):
        return build(tp, value)
    if origin in (list, tuple, Sequence):
        item = args[0] if args else Any
        return [_build_value(item, v) for v in value]
    if origin in (dict, Mapping):
        item = args[1] if len(args) == 2 else Any
        return {str(k): _build_value(item, v) for k, v in value.items()}
    if tp is float:
        return float(value)
    return to_plain(value)


def build(schema: type, node: Any) -> Any:
    """A ``schema`` instance from a checked node (missing keys take the schema's defaults)."""
    hints = typing.get_type_hints(schema)
    kwargs = {f.name: _build_value(hints[f.name], node[f.name]) for f in dataclasses.fields(schema) if f.name in node}
    return schema(**kwargs)


def describe(schema: type) -> list[tuple[str, str, Any, str]]:
    """(name, type, default, doc) rows for listings and the README."""
    hints = typing.get_type_hints(schema)
    rows = []
    for f in dataclasses.fields(schema):
        default = (
            f.default
            if f.default is not _MISSING
            else (f.default_factory() if f.default_factory is not _MISSING else None)
        )
        rows.append((f.name, _type_name(hints[f.name]), default, f.metadata.get("doc", "")))
    return rows
