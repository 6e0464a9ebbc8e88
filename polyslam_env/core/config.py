"""Configuration: nested frozen dataclasses, validated on construction (STYLE habit 1).

Every config class derives from :class:`Config`, which gives

* ``from_dict(data)``: build from plain data (e.g. parsed YAML), coercing lists to tuples and
  ints to floats, rejecting unknown keys and ill-typed values with a :class:`ConfigError` that
  names the dotted key and the value;
* ``from_yaml(path, **overrides)``: the same from a file, the error also naming the file;
* ``replace(**overrides)``: a copy with some fields changed; nested fields are reached with
  ``__`` (``world__camera__range=2.0``) or by passing a dict (``camera={"range": 2.0}``);
* ``to_dict()``: plain data that ``from_dict`` turns back into an equal config.

Validation lives in each class's ``validate`` and runs in ``__post_init__``.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar, get_args, get_origin, get_type_hints

import yaml

from polyslam_env.core.errors import ConfigError
from polyslam_env.core.io import parse_yaml

C = TypeVar("C", bound="Config")


@dataclasses.dataclass(frozen=True)
class Config:
    """Base class of every configuration dataclass."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field. Override in subclasses."""

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_dict(cls: type[C], data: Mapping[str, Any] | None, *, where: str = "") -> C:
        """Build from plain data; unknown keys and bad values raise :class:`ConfigError`."""
        data = {} if data is None else data
        if not isinstance(data, Mapping):
            raise ConfigError(f"{_label(where, cls)}: expected a mapping, got {data!r}")
        hints = get_type_hints(cls)
        fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
        unknown = sorted(set(data) - set(fields))
        if unknown:
            raise ConfigError(
                f"{_label(where, cls)}: unknown key {_dotted(where, str(unknown[0]))!r}"
                f" (valid keys: {', '.join(sorted(fields))})"
            )
        kwargs = {
            name: _coerce(value, hints[name], _dotted(where, name)) for name, value in data.items()
        }
        try:
            return cls(**kwargs)
        except ConfigError as err:
            if where:
                raise ConfigError(_under(where, str(err))) from None
            raise

    @classmethod
    def from_yaml(cls: type[C], path: str | Path, **overrides: Any) -> C:
        """Load from a YAML file; errors name the file as well as the key. An empty file (or
        one holding only comments) means "all defaults", like an empty mapping."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as err:
            raise ConfigError(f"{path}: cannot read config file ({err.strerror})") from None
        except UnicodeDecodeError:
            raise ConfigError(f"{path}: not a YAML text file (not UTF-8 text)") from None
        try:
            data = parse_yaml(text)
        except yaml.YAMLError as err:
            raise ConfigError(f"{path}: not valid YAML: {err}") from None
        try:
            return cls.from_dict(data).replace(**overrides)
        except ConfigError as err:
            raise ConfigError(f"{path}: {err}") from None

    def replace(self: C, **overrides: Any) -> C:
        """A copy with fields changed; ``a__b=1`` or ``a={"b": 1}`` reach nested fields."""
        if not overrides:
            return self
        data = self.to_dict()
        for key, value in overrides.items():
            _set_nested(data, key.split("__"), value)
        return type(self).from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (tuples become lists) that :meth:`from_dict` turns back into ``self``."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            out[f.name] = _plain(getattr(self, f.name))
        return out


# -- validation helpers used by the config classes ------------------------------------------
def check_positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{name}: must be a finite number > 0, got {value!r}")


def check_non_negative(name: str, value: float) -> None:
    if not (math.isfinite(value) and value >= 0):
        raise ConfigError(f"{name}: must be a finite number >= 0, got {value!r}")


def check_range(name: str, value: float, low: float, high: float) -> None:
    if not (math.isfinite(value) and low <= value <= high):
        raise ConfigError(f"{name}: must be in [{low}, {high}], got {value!r}")


def check_choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ConfigError(f"{name}: must be one of {', '.join(choices)}; got {value!r}")


def parse_overrides(pairs: Sequence[str], label: str = "--set") -> dict[str, Any]:
    """``["slam.eps_z=10", ...]`` as :meth:`Config.replace` keywords (``slam__eps_z=10``):
    dotted keys reach nested fields, values are YAML. A malformed pair or an unreadable value
    is a one-line :class:`ConfigError` starting with ``label``; unknown fields and bad values
    are the ``replace``'s errors."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"{label}: expected KEY=VALUE (e.g. slam.eps_z=10), got {pair!r}")
        try:
            out[key.replace(".", "__")] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ConfigError(f"{label}: {key}: {value!r} is not a value") from None
    return out


# -- internals ------------------------------------------------------------------------------
def _label(where: str, cls: type) -> str:
    return where or cls.__name__


def _under(where: str, message: str) -> str:
    """``message`` (which a nested ``validate`` may start with its own section name, e.g.
    ``range_sensor.max_range: ...``) with the full dotted path ``where`` in front, once:
    ``world.range_sensor.max_range: ...``, not ``world.range_sensor.range_sensor.max_range``."""
    parts = where.split(".")
    for k in range(len(parts)):
        tail = ".".join(parts[k:])
        if message.startswith((f"{tail}.", f"{tail}:", f"{tail}[")):
            return ".".join([*parts[:k], message])
    return f"{where}.{message}"


def _dotted(where: str, name: str) -> str:
    return f"{where}.{name}" if where else name


def _plain(value: Any) -> Any:
    if isinstance(value, Config):
        return value.to_dict()
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value


def _set_nested(data: dict[str, Any], keys: list[str], value: Any) -> None:
    head, rest = keys[0], keys[1:]
    if not rest:
        if isinstance(value, Mapping) and isinstance(data.get(head), dict):
            for k, v in value.items():
                _set_nested(data[head], [k], v)
        else:
            data[head] = _plain(value) if isinstance(value, Config) else value
        return
    child = data.setdefault(head, {})
    if not isinstance(child, dict):
        raise ConfigError(f"{'.'.join(keys)}: {head!r} is not a nested config")
    _set_nested(child, rest, value)


def _coerce(value: Any, hint: Any, key: str) -> Any:
    """Turn plain data into the type ``hint`` names, or raise ConfigError naming ``key``."""
    origin = get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = get_args(hint)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, key)
            except ConfigError as err:
                errors.append(str(err))
        raise ConfigError(errors[0] if errors else f"{key}: bad value {value!r}")
    if origin is typing.Literal:
        choices = get_args(hint)
        if value not in choices:
            raise ConfigError(
                f"{key}: must be one of {', '.join(map(repr, choices))}; got {value!r}"
            )
        return value
    if isinstance(hint, type) and issubclass(hint, Config):
        if isinstance(value, hint):
            return value
        return hint.from_dict(value, where=key)
    if origin is tuple:
        if isinstance(value, str) or not isinstance(value, list | tuple):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        args = get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f"{key}: expected {len(args)} values, got {len(value)}")
        pairs = enumerate(zip(args, value, strict=True))
        return tuple(_coerce(v, a, f"{key}[{i}]") for i, (a, v) in pairs)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{key}: must be finite, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    if hint is Any:
        return value
    raise ConfigError(f"{key}: unsupported config type {hint!r}")  # a bug in a config class
