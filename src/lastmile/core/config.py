"""Typed, frozen configuration built from TOML tables, rejecting unknown keys and wrong types."""

from __future__ import annotations

import dataclasses
import enum
import math
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from lastmile.core.errors import ConfigError

T = TypeVar("T")


def load_toml(path: Path) -> dict[str, Any]:
    """Read a TOML file, turning every read or syntax problem into a :class:`ConfigError`."""
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"{path}: expected a TOML file, got no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: expected a TOML file, got a directory") from None
    except PermissionError:
        raise ConfigError(f"{path}: expected a readable TOML file, got permission denied") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: expected a UTF-8 TOML text file, got binary data (byte {exc.start})"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: expected valid TOML, got a syntax error ({exc})") from None


def file_candidates(source: Path, given: str) -> list[Path]:
    """Where a path written in the file ``source`` may point, in order: itself when absolute, else
    beside ``source``, then from the working directory (the project's examples name files from the
    repository root, where the CLI runs; a user's files usually sit beside the one naming them)."""
    p = Path(given).expanduser()
    return [p] if p.is_absolute() else [source.parent / p, Path.cwd() / p]


def resolve_file(source: Path, given: str) -> Path | None:
    """The first of :func:`file_candidates` that is a file, or None."""
    return next((c for c in file_candidates(source, given) if c.is_file()), None)


def from_mapping(cls: type[T], data: Any, where: str) -> T:
    """Build the dataclass ``cls`` from a mapping, recursively.

    Args:
        cls: a dataclass type whose fields have type annotations.
        data: the mapping (usually a TOML table).
        where: a path for messages, e.g. ``"scenario.agents[2]"``.

    Raises:
        ConfigError: an unknown key, a missing required key or a value of the wrong type, naming the
            key, what was expected and what arrived.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table, got {type(data).__name__} {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r}; expected one of {sorted(fields)}")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        if not f.init:
            continue
        if name in data:
            kwargs[name] = _convert(hints[name], data[name], f"{where}.{name}")
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where}: missing required key {name!r}")
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _convert(hint: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{where}: unexpected {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}: expected one of {list(args)}, got {value!r}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__} {value!r}")
        item = args[0] if args else Any
        converted = [_convert(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(converted) if origin is tuple else converted
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {type(value).__name__} {value!r}")
        return {k: _convert(args[1], v, f"{where}.{k}") for k, v in value.items()}
    if dataclasses.is_dataclass(hint):
        return from_mapping(hint, value, where)  # type: ignore[arg-type]
    if hint is Any:
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if isinstance(hint, enum.EnumMeta):
        try:
            return hint(value)
        except ValueError:
            allowed = [m.value for m in hint]  # type: ignore[var-annotated]
            raise ConfigError(f"{where}: expected one of {allowed}, got {value!r}") from None
    return value


def check_range(where: str, value: float, low: float, high: float) -> None:
    """Raise a :class:`ConfigError` unless ``low <= value <= high``."""
    if not (low <= value <= high):
        raise ConfigError(f"{where}: expected a value in [{low}, {high}], got {value}")
