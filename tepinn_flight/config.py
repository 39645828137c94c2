"""Strict TOML → frozen dataclass loading, shared by every configurable component.

One typed, frozen dataclass per component describes its configuration. :func:`from_dict` builds it
from a TOML table and refuses anything it does not understand, naming the offending key:

- unknown keys (``sensor.gyro.arw``: unknown key; known: ...),
- wrong types (a string where a number is expected, ``true`` where an int is expected),
- missing keys that have no default.

Supported field types: ``bool``, ``int``, ``float`` (an int is accepted and converted; ``inf`` and
``nan`` are TOML floats), ``str``, ``Literal[...]``, ``X | None`` (omit the key for ``None``: TOML
has no null), ``tuple[X, ...]`` / ``tuple[X, Y]`` / ``list[X]`` (from arrays), ``dict[str, X]``
(from tables) and nested dataclasses (from tables, recursively). Dataclasses may define
``__post_init__`` to check values and raise :class:`~tepinn_flight.errors.ConfigError`.

:func:`apply_overrides` applies ``key=value`` strings (dotted keys into nested tables; the value is
parsed as a TOML value, a bare word is taken as a string), so every parameter can be overridden
from the command line with the same checks.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import tomllib
import types
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

from .errors import ConfigError

T = TypeVar("T")

__all__ = [
    "load_toml", "from_dict", "load_config", "to_dict", "apply_overrides", "parse_override", "check",
    "finite_nonneg", "check_range", "check_choice",
]


def load_toml(path: str | os.PathLike) -> dict:
    """Read a TOML file into a dict; a missing or malformed file is a one-line ConfigError."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError("no such file", p) from None
    except IsADirectoryError:
        raise ConfigError("is a directory, not a TOML file", p) from None
    except OSError as exc:
        raise ConfigError(f"cannot read ({exc.strerror})", p) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        first = (str(exc).strip().splitlines() or ["syntax error"])[0]
        raise ConfigError(f"invalid TOML: {first}", p) from None


def load_config(cls: type[T], path: str | os.PathLike, overrides: list[str] | tuple[str, ...] = ()) -> T:
    """``from_dict(cls, load_toml(path))`` with ``key=value`` overrides; errors name the file."""
    data = load_toml(path)
    try:
        cfg = from_dict(cls, data)
    except ConfigError as exc:
        raise ConfigError(exc.reason, path) from None
    return apply_overrides(cfg, overrides) if overrides else cfg


def from_dict(cls: type[T], data: Any, where: str = "") -> T:
    """Build dataclass ``cls`` from a mapping, recursively and strictly (see module doc)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'configuration'}: expected a table, got {_tname(data)}")
    hints = get_type_hints(cls, include_extras=False)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in data if k not in fields]
    if unknown:
        key = _join(where, unknown[0])
        raise ConfigError(f"unknown key '{key}' (known: {', '.join(fields) or 'none'})")
    kwargs = {}
    for name, f in fields.items():
        key = _join(where, name)
        if name in data:
            kwargs[name] = _convert(hints[name], data[name], key)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:  # type: ignore[misc]
            raise ConfigError(f"missing key '{key}'")
    try:
        return cls(**kwargs)
    except ConfigError as exc:  # from __post_init__: prefix the table's key path
        raise (ConfigError(f"{where}: {exc.reason}") if where else exc) from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where or cls.__name__}: {exc}") from None


def to_dict(cfg: Any) -> Any:
    """Dataclass → plain dict (tuples become lists, ``None`` fields are dropped): TOML/JSON-ready."""
    if dataclasses.is_dataclass(cfg) and not isinstance(cfg, type):
        out = {}
        for f in dataclasses.fields(cfg):
            v = getattr(cfg, f.name)
            if v is not None:
                out[f.name] = to_dict(v)
        return out
    if isinstance(cfg, (tuple, list)):
        return [to_dict(v) for v in cfg]
    if isinstance(cfg, dict):
        return {k: to_dict(v) for k, v in cfg.items()}
    return cfg


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"a.b=1.5"`` → (``["a", "b"]``, 1.5). The value is TOML; a bare word is a string."""
    if "=" not in text:
        raise ConfigError(f"override '{text}' is not KEY=VALUE")
    key, raw = (s.strip() for s in text.split("=", 1))
    if not key or any(not part for part in key.split(".")):
        raise ConfigError(f"override '{text}' has an empty key")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw  # a bare word such as  anti_alias=boxcar
    return key.split("."), value


def apply_overrides(cfg: T, overrides: list[str] | tuple[str, ...]) -> T:
    """Apply ``key=value`` strings to a dataclass instance, re-checking types and values."""
    data = to_dict(cfg)
    for text in overrides:
        path, value = parse_override(text)
        node = data
        cls: Any = type(cfg)
        for i, part in enumerate(path):
            names = {f.name for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else None
            if names is not None and part not in names:
                raise ConfigError(f"unknown key '{'.'.join(path[: i + 1])}' in override '{text}'")
            if i == len(path) - 1:
                node[part] = value
                break
            sub = get_type_hints(cls)[part] if names is not None else None
            sub = _strip_optional(sub)
            if not (dataclasses.is_dataclass(sub) or get_origin(sub) is dict):
                raise ConfigError(f"'{'.'.join(path[: i + 1])}' is not a table in override '{text}'")
            node = node.setdefault(part, {})
            cls = sub if dataclasses.is_dataclass(sub) else None
    try:
        return from_dict(type(cfg), data)
    except ConfigError as exc:
        raise ConfigError(f"{exc.reason} (after overrides {list(overrides)})") from None


# --------------------------------------------------------------------------- conversion


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _tname(v: Any) -> str:
    return {bool: "a boolean", int: "an integer", float: "a float", str: "a string", list: "an array",
            dict: "a table"}.get(type(v), type(v).__name__)


def _strip_optional(tp: Any) -> Any:
    if _is_union(tp):
        args = [a for a in get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _is_union(tp: Any) -> bool:
    return get_origin(tp) is Union or (sys.version_info >= (3, 10) and isinstance(tp, types.UnionType))


def _convert(tp: Any, v: Any, key: str) -> Any:
    if tp is Any:
        return v
    if _is_union(tp):
        args = get_args(tp)
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _convert(a, v, key)
            except ConfigError as exc:
                errors.append(exc)
        raise errors[0] if len(errors) == 1 else ConfigError(f"'{key}': unexpected value {v!r}")
    origin = get_origin(tp)
    if origin is Literal:
        allowed = get_args(tp)
        if v not in allowed or type(v) is not type(allowed[0]):
            raise ConfigError(f"'{key}' must be one of {', '.join(map(repr, allowed))}, got {v!r}")
        return v
    if dataclasses.is_dataclass(tp):
        return from_dict(tp, v, key)
    if origin in (tuple, list):
        if not isinstance(v, list):
            raise ConfigError(f"'{key}' must be an array, got {_tname(v)}")
        args = get_args(tp)
        if origin is tuple and args and (len(args) != 2 or args[1] is not Ellipsis):
            if len(v) != len(args):
                raise ConfigError(f"'{key}' must have {len(args)} elements, got {len(v)}")
            items = [_convert(a, x, f"{key}[{i}]") for i, (a, x) in enumerate(zip(args, v))]
        else:
            elem = args[0] if args else Any
            items = [_convert(elem, x, f"{key}[{i}]") for i, x in enumerate(v)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(v, dict):
            raise ConfigError(f"'{key}' must be a table, got {_tname(v)}")
        kt, vt = get_args(tp) or (str, Any)
        return {str(k): _convert(vt, x, f"{key}.{k}") for k, x in v.items()}
    if tp is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"'{key}' must be true or false, got {_tname(v)}")
        return v
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"'{key}' must be an integer, got {_tname(v)}")
        return v
    if tp is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"'{key}' must be a number, got {_tname(v)}")
        return float(v)
    if tp is str:
        if not isinstance(v, str):
            raise ConfigError(f"'{key}' must be a string, got {_tname(v)}")
        return v
    raise TypeError(f"config field '{key}' has unsupported type {tp!r}")


def check(cond: bool, message: str) -> None:
    """For ``__post_init__`` value checks: raise a ConfigError with ``message`` unless ``cond``."""
    if not cond:
        raise ConfigError(message)


def finite_nonneg(name: str, value: float, allow_inf: bool = False) -> None:
    """Shorthand check: ``value >= 0`` and finite (or +inf when ``allow_inf``)."""
    ok = value >= 0 and (math.isfinite(value) or (allow_inf and value == math.inf))
    check(ok, f"'{name}' must be {'>= 0' if allow_inf else 'finite and >= 0'}, got {value!r}")



def _fmt(v: float) -> str:
    return repr(int(v)) if float(v).is_integer() and abs(v) < 1e15 else repr(float(v))


def check_range(name: str, value: float, lo: float | None = None, hi: float | None = None, *,
                lo_open: bool = False, hi_open: bool = False) -> None:
    """Range check for ``__post_init__``: ``value`` must be finite and within ``lo``..``hi``
    (``None``: unbounded on that side; ``*_open``: that bound is excluded). The ConfigError names
    the key and the allowed range, e.g. ``'batch_size' must be >= 1, got 0``."""
    if lo is not None and hi is not None:
        allowed = f"in {'(' if lo_open else '['}{_fmt(lo)}, {_fmt(hi)}{')' if hi_open else ']'}"
    elif lo is not None:
        allowed = f"{'>' if lo_open else '>='} {_fmt(lo)}"
    elif hi is not None:
        allowed = f"{'<' if hi_open else '<='} {_fmt(hi)}"
    else:
        allowed = "finite"
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and lo is not None:
        ok = value > lo if lo_open else value >= lo
    if ok and hi is not None:
        ok = value < hi if hi_open else value <= hi
    if not ok:
        finite = "" if allowed == "finite" or isinstance(value, int) else "finite and "
        raise ConfigError(f"'{name}' must be {finite}{allowed}, got {value!r}")


def check_choice(name: str, value, choices) -> None:
    """Enum check for ``__post_init__`` (a dataclass built in code, not only from TOML): the
    ConfigError names the key and the allowed values, e.g. ``'yaw' must be one of 'gyro', 'zero', got 'x'``."""
    if not isinstance(value, str) or value not in choices:
        raise ConfigError(f"'{name}' must be one of {', '.join(map(repr, choices))}, got {value!r}")
