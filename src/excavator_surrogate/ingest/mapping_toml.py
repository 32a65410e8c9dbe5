"""Reading and checking an import mapping file (the layout: :mod:`.mapping`).

:func:`load_mapping` reads the TOML file, :func:`parse_mapping` builds the
:class:`~.mapping.Mapping` from its tables; both raise
:class:`~excavator_surrogate.errors.ConfigError` with one line naming the file, the table
or joint and the key, and what to write instead.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import Any

from ..config import from_dict
from ..errors import ConfigError
from .mapping import (
    TABLE,
    AngleMap,
    Channel,
    CommandMap,
    InputMap,
    JointMap,
    MachineTable,
    Mapping,
    TimeMap,
    VelocityMap,
)
from .options import CsvOptions, ImportOptions, SplitOptions
from .run_inputs import is_run_input, parse_run_input
from .units import POSITION_UNITS, check_units, is_length, parse_linkage

_TOP = {"machine", "time", "joints", "inputs", "import", "split", "csv"}


def load_mapping(path: str | Path) -> Mapping:
    """Read and check a mapping TOML file.

    Raises:
        ConfigError: one line naming the file and the offending key.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: mapping file not found (write one as in docs/import.md)")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: invalid TOML ({e})") from e
    return parse_mapping(data, path=path)


def parse_mapping(data: dict[str, Any], *, path: str | Path | None = None) -> Mapping:
    """Build a :class:`Mapping` from already-parsed TOML ``data`` (see :func:`load_mapping`)."""
    where = str(path) if path is not None else "mapping"
    unknown = sorted(set(data) - _TOP)
    if unknown:
        raise ConfigError(f"{where}: unknown table(s) {unknown}; valid: {sorted(_TOP)}")
    for key in ("machine", "time", "import", "split", "csv"):
        if key in data and not isinstance(data[key], dict):
            raise ConfigError(f"{where}: '{key}' must be a table ([{key}])")
    machine = from_dict(MachineTable, data.get("machine"), where=f"{where}: machine")
    try:
        time = from_dict(TimeMap, data.get("time"), where=f"{where}: time")
        options = from_dict(ImportOptions, data.get("import"), where=f"{where}: import")
        split = from_dict(SplitOptions, data.get("split"), where=f"{where}: split")
        csv = from_dict(CsvOptions, data.get("csv"), where=f"{where}: csv")
    except ConfigError as e:
        if str(e).startswith(where):
            raise
        raise ConfigError(f"{where}: {e}") from e
    raw_joints = data.get("joints")
    if isinstance(raw_joints, dict):  # [joints] instead of [[joints]]
        raise ConfigError(
            f"{where}: 'joints' must be a list of tables: write [[joints]] (two brackets), "
            "one table per joint"
        )
    if not isinstance(raw_joints, list) or not raw_joints:
        raise ConfigError(
            f"{where}: no joints; add one [[joints]] table per joint (name, angle, command)"
        )
    joints = tuple(_parse_joint(j, i, where) for i, j in enumerate(raw_joints))
    names = [j.name for j in joints]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(
            f"{where}: joint name '{dup[0]}' appears twice; joint names must be unique"
        )
    raw_inputs = data.get("inputs", [])
    if not isinstance(raw_inputs, list):
        raise ConfigError(f"{where}: 'inputs' must be a list of tables ([[inputs]])")
    inputs = tuple(_parse_input(i, k, where) for k, i in enumerate(raw_inputs))
    _check_input_names(joints, inputs, where)
    m = Mapping(
        machine=machine,
        inputs=inputs,
        time=time,
        joints=joints,
        options=options,
        split=split,
        csv=csv,
        path=Path(path) if path is not None else None,
        raw=data,
    )
    first = {c.series == TABLE: c for c in reversed(m.channels())}
    if len(first) > 1:
        raise ConfigError(
            f"{where}: mixes table columns ('{first[True].label}') and ROS topics "
            f"('{first[False].label}'); map either columns or topic + field"
        )
    _check_shared_channels(m, where)
    m.spec()  # checks names and ranges
    return m


def _check_input_names(
    joints: tuple[JointMap, ...], inputs: tuple[InputMap, ...], where: str
) -> None:
    """An input's column ``u_<name>`` must not clash with a joint's or another input's."""
    seen = {j.name: "a joint" for j in joints}
    for i in inputs:
        if i.name in seen:
            raise ConfigError(
                f"{where}: input '{i.name}': the name is already used by {seen[i.name]} "
                f"(columns u_<name> must be unique); rename the input"
            )
        seen[i.name] = "another input"


def _check_shared_channels(m: Mapping, where: str) -> None:
    """One log channel feeds one role of one joint (two joints reading one column is a typo)."""
    seen: dict[Channel, str] = {}
    if m.time.column is not None:
        seen[Channel(TABLE, m.time.column)] = "the time"
    users: list[tuple[str, list[tuple[str, Channel | None]]]] = []
    for j in m.joints:
        roles = [("angle", m.angle_channel(j)), ("velocity", m.velocity_channel(j))]
        roles += [("command", ch) for ch in m.command_channels(j)]
        users.append((f"joint '{j.name}'", roles))
    users += [
        (f"input '{i.name}'", [("channel", ch) for ch in m.command_channels(i)]) for i in m.inputs
    ]
    for owner, roles in users:
        for role, ch in roles:
            if ch is None:
                continue
            user = f"the {role} of {owner}"
            if ch in seen:
                raise ConfigError(
                    f"{where}: {ch.label} is mapped to both {seen[ch]} and {user}; "
                    "map each log channel once"
                )
            seen[ch] = user


def _parse_joint(raw: Any, i: int, where: str) -> JointMap:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: joints[{i}] must be a table")
    name = raw.get("name")
    jw = f"{where}: joint '{name}'" if isinstance(name, str) else f"{where}: joints[{i}]"
    if not isinstance(name, str):
        raise ConfigError(f"{jw}: 'name' is required (lower-case letters, digits, '_')")
    if "position" in raw:  # a linear joint's stroke reads better as its position
        if "angle" in raw:
            raise ConfigError(f"{jw}: give either angle or position (the same table), not both")
        raw = {("angle" if k == "position" else k): v for k, v in raw.items()}
    for key in ("angle", "command"):
        if not isinstance(raw.get(key), dict):
            raise ConfigError(
                f'{jw}: \'{key}\' table is required, e.g. {key} = {{ column = "...", unit = "..." }}'
            )
    body = {k: v for k, v in raw.items() if k not in ("angle", "velocity", "command", "linkage")}
    try:
        base = from_dict(JointMap, body, where=jw)
    except TypeError as e:  # pragma: no cover - required fields are checked above
        raise ConfigError(f"{jw}: {e}") from e
    angle = from_dict(AngleMap, raw["angle"], where=f"{jw}: angle")
    velocity = None
    if "velocity" in raw:
        if not isinstance(raw["velocity"], dict):
            raise ConfigError(f"{jw}: 'velocity' must be a table {{ column = ..., unit = ... }}")
        velocity = from_dict(VelocityMap, raw["velocity"], where=f"{jw}: velocity")
    command = from_dict(
        CommandMap, _one_way_tables(raw["command"], f"{jw}: command"), where=f"{jw}: command"
    )
    _check_source(angle.column, angle.topic, angle.field, f"{jw}: angle")
    if angle.unit is None:
        units = ", ".join(f'"{u}"' for u in POSITION_UNITS)
        raise ConfigError(f"{jw}: angle.unit (or position.unit) is required: one of {units}")
    if velocity is not None:
        _check_source(velocity.column, velocity.topic, velocity.field, f"{jw}: velocity")
        if velocity.unit is None:
            want = "m/s, cm/s or mm/s" if is_length(angle.unit) else '"deg/s" or "rad/s"'
            raise ConfigError(f"{jw}: velocity.unit is required: {want}")
        check_units(angle.unit, velocity.unit, jw)
    if is_length(angle.unit) and base.periodic:
        raise ConfigError(
            f"{jw}: a linear joint (position in {angle.unit}) cannot be periodic; "
            "set periodic = false"
        )
    _check_command(command, f"{jw}: command")
    if base.limits is not None and not base.limits[1] > base.limits[0]:
        raise ConfigError(f"{jw}: limits {list(base.limits)} must be [low, high] with high > low")
    linkage = parse_linkage(raw.get("linkage"), angle.unit, jw, limits=base.limits)
    return dataclasses.replace(
        base, angle=angle, velocity=velocity, command=command, linkage=linkage
    )


def _parse_input(raw: Any, k: int, where: str) -> InputMap:
    if not isinstance(raw, dict) or not isinstance(raw.get("name"), str):
        raise ConfigError(f"{where}: inputs[{k}] must be a table with a name")
    iw = f"{where}: input '{raw['name']}'"
    if is_run_input(raw):
        run, rng, unit = parse_run_input(raw, iw)
        c = CommandMap(unit="physical", range=rng, physical_unit=unit)
        return InputMap(name=raw["name"], command=c, unit=unit, run=run)
    body = {key: v for key, v in raw.items() if key != "name"}
    if "range" not in body:
        raise ConfigError(f"{iw}: range = [lo, hi] is required (the input's valid values)")
    if any(k in body for k in ("up", "down", "up_topic", "down_topic")):
        raise ConfigError(
            f"{iw}: an input is one channel (column, or topic + field); up/down are for a "
            "joint's two one-way commands"
        )
    c = from_dict(CommandMap, body, where=iw)
    _check_command(c, iw)
    unit = c.physical_unit if c.unit == "physical" else str(c.unit)
    if c.unit == "%":  # 0..100 % spans the range (inputs are not signed)
        c = dataclasses.replace(c, unit="raw", raw_range=(0.0, 100.0))
    return InputMap(name=raw["name"], command=c, unit=unit)


def _check_source(column: str | None, topic: str | None, fld: str | None, where: str) -> None:
    if topic is not None:
        if column is not None:
            raise ConfigError(
                f"{where}: give either column (CSV/Parquet) or topic + field (ROS), not both"
            )
        if not fld:
            raise ConfigError(f"{where}: topic '{topic}' needs field, e.g. field = \"position[0]\"")
    elif column is None:
        raise ConfigError(f"{where}: column (CSV/Parquet) or topic + field (ROS) is required")
    elif fld is not None:
        raise ConfigError(f"{where}: field is only used with topic; for tables use column")


def _one_way_tables(raw: dict[str, Any], where: str) -> dict[str, Any]:
    """A command table with ``up = { topic = ..., field = ... }`` (and ``down``) as the flat
    keys of :class:`CommandMap` (``up`` the field, ``up_topic`` its topic): a ROS machine
    that publishes each direction of a valve on a topic of its own."""
    out = dict(raw)
    for key in ("up", "down"):
        v = raw.get(key)
        if not isinstance(v, dict):
            continue
        if set(v) != {"topic", "field"} or not all(isinstance(x, str) for x in v.values()):
            raise ConfigError(
                f'{where}: {key} = {{ topic = "...", field = "..." }} names a channel of a ROS '
                f"topic by both keys and nothing else (got {sorted(v)}); a table column is "
                f'{key} = "column"'
            )
        if f"{key}_topic" in raw:
            raise ConfigError(
                f"{where}: give {key}'s topic in its table or as {key}_topic, not both"
            )
        out[key], out[f"{key}_topic"] = v["field"], v["topic"]
    return out


def _check_command(c: CommandMap, where: str) -> None:
    if c.two_channel:
        if c.up is None or c.down is None:
            raise ConfigError(f"{where}: two-channel commands need both up and down")
        if c.column is not None or c.field is not None:
            raise ConfigError(
                f"{where}: give either up + down or one signed column/field, not both"
            )
        for key, own in (("up", c.up_topic), ("down", c.down_topic)):
            if (c.up_topic or c.down_topic) and not (own or c.topic):
                raise ConfigError(
                    f'{where}: {key} needs a topic too: {key} = {{ topic = "...", field = '
                    f'"{getattr(c, key)}" }}, or topic = "..." for both'
                )
    elif c.up_topic is not None or c.down_topic is not None:
        raise ConfigError(f"{where}: up_topic and down_topic are for up + down commands")
    else:
        _check_source(c.column, c.topic, c.field, where)
    if c.unit is None:
        raise ConfigError(f'{where}: unit is required: "%", "raw" or "physical"')
    if not c.range[1] > c.range[0]:
        raise ConfigError(
            f"{where}: range {list(c.range)} must be [u_min, u_max] with u_max > u_min"
        )
    if c.unit == "raw":
        if c.raw_range is None:
            raise ConfigError(
                f'{where}: unit = "raw" needs raw_range = [low, high] (the raw signed span)'
            )
        if not c.raw_range[1] > c.raw_range[0]:
            raise ConfigError(
                f"{where}: raw_range {list(c.raw_range)} must be [low, high] with high > low"
            )
    elif c.raw_range is not None:
        raise ConfigError(f'{where}: raw_range is only used with unit = "raw"')
    if c.scale == 0:
        raise ConfigError(f"{where}: scale must not be 0")
