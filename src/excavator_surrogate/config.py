"""Typed, frozen configs and TOML presets.

Each pipeline stage has one frozen dataclass config (``SimulateConfig``, ``CleanConfig``,
``TrainConfig`` ...), every field with a type, a default and a one-line docstring.
A preset is a TOML file shipped in ``excavator_surrogate/presets/<name>.toml`` with one
table per stage::

    [simulate]
    n_train = 12
    [train]
    epochs = 30

:func:`load_preset` reads it; :func:`from_dict` builds a config from one table and rejects
unknown keys with a one-line error; :func:`to_dict` turns a config back into plain data, so
every output folder can record the config that produced it (``config.toml``).
"""

from __future__ import annotations

import dataclasses
import tomllib
import types
import typing
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from .errors import ConfigError

C = TypeVar("C")


def preset_names() -> list[str]:
    """Names of the presets shipped with the package."""
    root = resources.files("excavator_surrogate") / "presets"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def load_preset(name_or_path: str | Path) -> dict[str, Any]:
    """Load a preset by name (shipped) or by path to a TOML file.

    Returns the raw nested dict (one table per stage).  A preset may ``extends = "other"``
    another preset; tables are merged key by key.
    """
    p = Path(str(name_or_path))
    if p.suffix == ".toml" or p.is_file():
        if not p.exists():
            raise ConfigError(
                f"{p}: preset file not found (give a shipped name: {', '.join(preset_names())})"
            )
        text = p.read_text()
        where = str(p)
    else:
        res = resources.files("excavator_surrogate") / "presets" / f"{name_or_path}.toml"
        if not res.is_file():
            raise ConfigError(
                f"unknown preset '{name_or_path}': choose one of {', '.join(preset_names())} or a .toml path"
            )
        text = res.read_text()
        where = f"preset '{name_or_path}'"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{where}: invalid TOML ({e})") from e
    base = data.pop("extends", None)
    own_name = data.get(
        "name", Path(str(name_or_path)).stem if p.suffix == ".toml" else str(name_or_path)
    )
    if base is not None:
        merged = load_preset(base)
        for k, v in data.items():
            if isinstance(v, dict) and isinstance(merged.get(k), dict):
                merged[k] = {**merged[k], **v}
            else:
                merged[k] = v
        data = merged
    data["name"] = own_name
    return data


def _coerce(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errs = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(a, value, where)
            except ConfigError as e:
                errs.append(str(e))
        raise ConfigError(errs[0] if errs else f"{where}: bad value {value!r}")
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v, where) for v in value)
        if len(args) != len(value):
            raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(a, v, where) for a, v in zip(args, value))
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return dict(value)
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}: must be one of {list(args)}, got {value!r}")
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return from_dict(tp, value, where=where)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type[C], data: dict[str, Any] | None, *, where: str = "config") -> C:
    """Build frozen dataclass ``cls`` from ``data``; unknown keys are an error."""
    data = dict(data or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {unknown} for {cls.__name__}; valid keys: {sorted(fields)}"
        )
    kwargs = {k: _coerce(hints[k], v, f"{where}.{k}") for k, v in data.items()}
    return cls(**kwargs)


def to_dict(cfg: Any) -> dict[str, Any]:
    """Plain-data form of a (nested) config dataclass, tuples as lists, None dropped (TOML has no null)."""

    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {
                f.name: conv(getattr(v, f.name))
                for f in dataclasses.fields(v)
                if getattr(v, f.name) is not None
            }
        if isinstance(v, tuple | list):
            return [conv(x) for x in v]
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items() if x is not None}
        if isinstance(v, Path):
            return str(v)
        return v

    return conv(cfg)


def dumps_toml(tables: dict[str, Any]) -> str:
    """Minimal TOML writer for config records (scalars, lists, nested tables)."""

    def scalar(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int | float):
            return repr(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list):
            return "[" + ", ".join(scalar(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {scalar(x)}" for k, x in v.items()) + " }"
        raise TypeError(f"cannot write {type(v).__name__} to TOML")

    lines: list[str] = []
    plain = {k: v for k, v in tables.items() if not isinstance(v, dict)}
    for k, v in plain.items():
        lines.append(f"{k} = {scalar(v)}")

    def table(prefix: str, d: dict[str, Any]) -> None:
        lines.append("")
        lines.append(f"[{prefix}]")
        subs = {}
        for k, v in d.items():
            if isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values()):
                subs[k] = v
            elif isinstance(v, dict) and any(isinstance(x, dict) for x in v.values()):
                subs[k] = v
            else:
                lines.append(f"{k} = {scalar(v)}")
        for k, v in subs.items():
            table(f"{prefix}.{k}", v)

    for k, v in tables.items():
        if isinstance(v, dict):
            table(k, v)
    return "\n".join(lines).lstrip("\n") + "\n"
