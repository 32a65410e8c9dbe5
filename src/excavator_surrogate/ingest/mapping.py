"""The import mapping: a TOML file that describes the machine and maps log channels to joints.

Layout (see ``docs/import.md`` for the full reference)::

    [machine]                # name, target rate_hz, condition
    [time]                   # column + unit (s|ms|us|ns|datetime); ROS: stamp = auto|header|log
    [[joints]]               # one table per joint, in order
    name = "boom"
    periodic = false
    angle    = { column = "boom_deg", unit = "deg", scale = 1.0, offset = 0.0 }
    velocity = { column = "boom_rate", unit = "deg/s" }                  # optional
    # a stroke instead: position = { column = "boom_mm", unit = "mm" } (m | cm | mm), speeds
    # in mm/s, limits in mm, optional linkage = { a, b, l0, phi } (ingest/units.py)
    command  = { up = "boom_up", down = "boom_down", unit = "%", range = [-1000, 1000] }
    [[inputs]]               # optional exogenous inputs (engine speed, gear ...), in order
    name = "engine_rpm"
    column = "rpm"
    unit = "physical"        # physical | % (0..100 spans range) | raw (raw_range spans range)
    range = [800, 2200]
    [import]                 # defaults of the import options (CLI flags override)
    [split]                  # train/val/test assignment
    [csv]                    # delimiter, skip_rows

For ROS bags a channel names ``topic`` and ``field`` (e.g. ``field = "position[1]"``)
instead of ``column``; for two-channel commands ``up``/``down`` are field paths of ``topic``.

:func:`load_mapping` parses and checks the file and raises
:class:`~excavator_surrogate.errors.ConfigError` with a one-line message naming the file
and the key.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..config import from_dict
from ..errors import ConfigError
from ..spec import InputSpec, JointSpec, Linkage, MachineSpec
from .options import CsvOptions, ImportOptions, SplitOptions
from .run_inputs import RunInputMap, is_run_input, parse_run_input
from .units import DEG as DEG  # re-exported: the checks' degree factor
from .units import POSITION_UNITS, check_units, is_length, parse_linkage, to_si

TABLE = "table"
"""Series name of the single time base of a CSV/Parquet log."""


@dataclass(frozen=True)
class Channel:
    """One raw signal in a log: a column of a table or a field of a ROS topic."""

    series: str
    """``"table"`` for CSV/Parquet, else the ROS topic."""
    key: str
    """Column name, or field path inside the topic's message (``position[1]``)."""

    @property
    def label(self) -> str:
        """Name used in error messages: the column, or ``/topic:field``."""
        return self.key if self.series == TABLE else f"{self.series}:{self.key}"


@dataclass(frozen=True)
class AngleMap:
    """Where a joint's position (an angle, or a linear joint's stroke: the ``position`` table)
    comes from and how to convert it to SI (rad or m)."""

    column: str | None = None
    """CSV/Parquet column."""
    topic: str | None = None
    """ROS topic (instead of ``column``)."""
    field: str | None = None
    """Field path in the topic's message, e.g. ``position[1]`` or ``position[boom_joint]``."""
    unit: Literal["deg", "rad", "m", "cm", "mm"] | None = None
    """Unit of ``value * scale + offset`` (required); a length makes the joint linear."""
    scale: float = 1.0
    """Multiplier applied to the raw value first."""
    offset: float = 0.0
    """Added after ``scale``, in ``unit``."""


@dataclass(frozen=True)
class VelocityMap:
    """Where a measured joint velocity comes from (optional) and how to convert it to SI."""

    column: str | None = None
    topic: str | None = None
    field: str | None = None
    unit: Literal["deg/s", "rad/s", "m/s", "cm/s", "mm/s"] | None = None
    """Unit of ``value * scale + offset`` (required)."""
    scale: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class CommandMap:
    """Where a joint command comes from and how it maps onto the joint's command range.

    Either one signed channel (``column`` or ``topic``+``field``) or two one-way channels
    ``up``/``down`` (columns, or field paths of ``topic``) combined as ``up - down``.
    """

    column: str | None = None
    up: str | None = None
    down: str | None = None
    topic: str | None = None
    field: str | None = None
    unit: Literal["%", "raw", "physical"] | None = None
    """``%``: -100..100 (signed) spans ``range``; ``raw``: ``raw_range`` spans ``range``;
    ``physical``: the value already is the command in ``physical_unit`` (required)."""
    range: tuple[float, float] = (-1000.0, 1000.0)
    """Stored command range ``[u_min, u_max]`` of the joint."""
    raw_range: tuple[float, float] | None = None
    """For ``unit = "raw"``: the signed raw span mapped linearly onto ``range``."""
    physical_unit: str = "physical"
    """For ``unit = "physical"``: the unit name stored in the spec (``Nm``, ``bar`` ...)."""
    scale: float = 1.0
    """Multiplier applied to each raw channel first."""
    offset: float = 0.0
    """Added to each channel after ``scale``."""

    @property
    def two_channel(self) -> bool:
        """True for ``up``/``down`` channels."""
        return self.up is not None or self.down is not None


@dataclass(frozen=True)
class JointMap:
    """One joint: its spec and its channels."""

    name: str
    periodic: bool = False
    """No end stops (swing): angle unwrapped before resampling."""
    limits: tuple[float, float] | None = None
    """Joint limits in the position's ``unit`` (stored in the spec in rad or m)."""
    angle: AngleMap = field(default_factory=AngleMap)
    velocity: VelocityMap | None = None
    command: CommandMap = field(default_factory=CommandMap)
    linkage: Linkage | None = None
    """A linear joint's cylinder triangle, in SI (``linkage`` table, :mod:`.units`)."""

    @property
    def linear(self) -> bool:
        """True when the position is a length (the joint is linear)."""
        return is_length(self.angle.unit)


@dataclass(frozen=True)
class InputMap:
    """One exogenous input (``[[inputs]]``): a one-channel command that no joint owns.

    ``command`` holds its channel and conversion; a ``%`` input is stored as ``raw`` with
    ``raw_range = [0, 100]`` (0 % -> ``u_min``, 100 % -> ``u_max``, not signed as for joints).
    """

    name: str
    command: CommandMap
    unit: str = "physical"
    """Unit name stored in the spec (``physical_unit``, ``%`` or ``raw``)."""
    run: RunInputMap | None = None
    """A per-run constant (``from_name`` / ``from_metadata``, :mod:`.run_inputs`): no
    channel; ``command`` then only holds the range."""


@dataclass(frozen=True)
class MachineTable:
    """``[machine]``: the machine and the target rate."""

    name: str = "machine"
    rate_hz: float = 20.0
    """Target sample rate after resampling [Hz]."""
    condition: str = "default"
    """Operating condition label stored with each episode."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Free-form description stored in the spec."""


@dataclass(frozen=True)
class TimeMap:
    """``[time]``: the time base."""

    column: str | None = None
    """CSV/Parquet time column (required there); dSPACE: default the x-axis trace; MDF: unused."""
    unit: Literal["s", "ms", "us", "ns", "datetime"] = "s"
    """Numeric unit, or ``datetime`` for ISO-8601 strings / timestamp columns."""
    stamp: Literal["auto", "header", "log"] = "auto"
    """ROS: use ``header.stamp`` or the bag's log time (``auto``: header when present)."""


@dataclass(frozen=True)
class Mapping:
    """A parsed mapping file."""

    machine: MachineTable
    time: TimeMap
    joints: tuple[JointMap, ...]
    options: ImportOptions = field(default_factory=ImportOptions)
    split: SplitOptions = field(default_factory=SplitOptions)
    csv: CsvOptions = field(default_factory=CsvOptions)
    inputs: tuple[InputMap, ...] = ()
    """Exogenous inputs, the command columns after the joints'."""
    path: Path | None = None
    """The file it was read from (for messages)."""
    raw: dict[str, Any] = field(default_factory=dict, compare=False)
    """The TOML content as read (recorded in the dataset's config)."""

    @property
    def where(self) -> str:
        """Name used in messages."""
        return str(self.path) if self.path is not None else "mapping"

    @property
    def is_ros(self) -> bool:
        """True if channels name ROS topics."""
        return any(c.series != TABLE for c in self.channels())

    def angle_channel(self, j: JointMap) -> Channel:
        """The angle channel of joint ``j``."""
        return _channel(j.angle.topic, j.angle.column, j.angle.field)

    def velocity_channel(self, j: JointMap) -> Channel | None:
        """The measured-velocity channel of joint ``j``, if mapped."""
        if j.velocity is None:
            return None
        return _channel(j.velocity.topic, j.velocity.column, j.velocity.field)

    def command_channels(self, j: JointMap | InputMap) -> tuple[Channel, ...]:
        """``(signed,)`` or ``(up, down)`` channels of joint (or input) ``j``."""
        c = j.command
        if isinstance(j, InputMap) and j.run is not None:
            return ()  # a per-run constant reads no channel
        if c.two_channel:
            series = c.topic or TABLE
            return (Channel(series, str(c.up)), Channel(series, str(c.down)))
        return (_channel(c.topic, c.column, c.field),)

    def channels(self) -> list[Channel]:
        """Every channel the mapping reads, without duplicates, in joint order."""
        out: list[Channel] = []
        for j in self.joints:
            for ch in (self.angle_channel(j), self.velocity_channel(j), *self.command_channels(j)):
                if ch is not None and ch not in out:
                    out.append(ch)
        for i in self.inputs:
            out.extend(ch for ch in self.command_channels(i) if ch not in out)
        return out

    def u_sources(self) -> tuple[JointMap | InputMap, ...]:
        """What each command column comes from: the joints, then the inputs."""
        return (*self.joints, *self.inputs)

    def spec(self, rate_hz: float | None = None) -> MachineSpec:
        """The :class:`MachineSpec` described by the mapping, at ``rate_hz`` (default: mapping's)."""
        joints = []
        for j in self.joints:
            c = j.command
            lim = (None, None)
            if j.limits is not None:
                f = to_si(j.angle.unit)
                lim = (j.limits[0] * f, j.limits[1] * f)
            try:
                joints.append(
                    JointSpec(
                        name=j.name,
                        periodic=j.periodic,
                        u_min=float(c.range[0]),
                        u_max=float(c.range[1]),
                        theta_min=lim[0],
                        theta_max=lim[1],
                        u_unit=c.physical_unit if c.unit == "physical" else "command",
                        kind="linear" if j.linear else "revolute",
                        unit=str(j.angle.unit) if j.linear else "rad",
                        linkage=j.linkage,
                    )
                )
            except ConfigError as e:
                raise ConfigError(f"{self.where}: joint '{j.name}': {e}") from e
        rate = float(rate_hz or self.options.rate_hz or self.machine.rate_hz)
        meta = {"imported_with": "exsur import", **dict(self.machine.meta)}
        if self.path is not None:
            meta["mapping"] = self.path.name
        try:
            inputs = tuple(
                InputSpec(i.name, float(i.command.range[0]), float(i.command.range[1]), i.unit)
                for i in self.inputs
            )
            return MachineSpec(
                joints=tuple(joints), rate_hz=rate, name=self.machine.name, meta=meta, inputs=inputs
            )
        except ConfigError as e:
            raise ConfigError(f"{self.where}: {e}") from e


def _channel(topic: str | None, column: str | None, fld: str | None) -> Channel:
    if topic is not None:
        return Channel(topic, str(fld))
    return Channel(TABLE, str(column))


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
        data = tomllib.loads(path.read_text())
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
    time = from_dict(TimeMap, data.get("time"), where=f"{where}: time")
    try:
        options = from_dict(ImportOptions, data.get("import"), where=f"{where}: import")
        split = from_dict(SplitOptions, data.get("split"), where=f"{where}: split")
    except ConfigError as e:
        if str(e).startswith(where):
            raise
        raise ConfigError(f"{where}: {e}") from e
    csv = from_dict(CsvOptions, data.get("csv"), where=f"{where}: csv")
    raw_joints = data.get("joints")
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
    kinds = {c.series == TABLE for c in m.channels()}
    if len(kinds) > 1:
        raise ConfigError(
            f"{where}: mixes table columns and ROS topics; map either columns or topic+field"
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
    command = from_dict(CommandMap, raw["command"], where=f"{jw}: command")
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
    linkage = parse_linkage(raw.get("linkage"), angle.unit, jw)
    _check_command(command, f"{jw}: command")
    if base.limits is not None and not base.limits[1] > base.limits[0]:
        raise ConfigError(f"{jw}: limits {list(base.limits)} must be [low, high] with high > low")
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


def _check_command(c: CommandMap, where: str) -> None:
    if c.two_channel:
        if c.up is None or c.down is None:
            raise ConfigError(f"{where}: two-channel commands need both up and down")
        if c.column is not None or c.field is not None:
            raise ConfigError(
                f"{where}: give either up + down or one signed column/field, not both"
            )
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
