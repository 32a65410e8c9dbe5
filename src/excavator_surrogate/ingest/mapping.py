"""The import mapping: a TOML file that describes the machine and maps log channels to joints.

Layout (see ``docs/import.md`` for the full reference)::

    [machine]                # name, target rate_hz, condition
    [time]                   # column + unit (s|ms|us|ns|datetime); ROS: stamp = auto|header|log
    [[joints]]               # one table per joint, in order
    name = "boom"
    periodic = false
    angle    = { column = "boom_deg", unit = "deg", scale = 1.0, offset = 0.0 }
    velocity = { column = "boom_rate", unit = "deg/s" }                  # optional
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
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..config import from_dict
from ..errors import ConfigError
from ..spec import InputSpec, JointSpec, MachineSpec
from .run_inputs import RunInputMap, is_run_input, parse_run_input

TABLE = "table"
"""Series name of the single time base of a CSV/Parquet log."""

DEG = math.pi / 180.0


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
    """Where a joint angle comes from and how to convert it to rad."""

    column: str | None = None
    """CSV/Parquet column."""
    topic: str | None = None
    """ROS topic (instead of ``column``)."""
    field: str | None = None
    """Field path in the topic's message, e.g. ``position[1]`` or ``position[boom_joint]``."""
    unit: Literal["deg", "rad"] | None = None
    """Unit of ``value * scale + offset`` (required)."""
    scale: float = 1.0
    """Multiplier applied to the raw value first."""
    offset: float = 0.0
    """Added after ``scale``, in ``unit``."""


@dataclass(frozen=True)
class VelocityMap:
    """Where a measured joint velocity comes from (optional) and how to convert it to rad/s."""

    column: str | None = None
    topic: str | None = None
    field: str | None = None
    unit: Literal["deg/s", "rad/s"] | None = None
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
    """Joint limits in the angle's ``unit`` (stored in the spec in rad)."""
    angle: AngleMap = field(default_factory=AngleMap)
    velocity: VelocityMap | None = None
    command: CommandMap = field(default_factory=CommandMap)


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
class CsvOptions:
    """``[csv]``: how to parse CSV files."""

    delimiter: str = ","
    skip_rows: int = 0
    """Lines before the header line to skip (logger preambles)."""
    format: Literal["auto", "plain", "dspace"] = "auto"
    """``dspace``: read .csv files as dSPACE ControlDesk exports; ``plain``: never; ``auto``:
    by content (first cell ``descriptions`` or a ``trace_...`` row) or a ``.dspace.csv`` name."""


@dataclass(frozen=True)
class ImportOptions:
    """``[import]``: options of the import (CLI flags override them)."""

    rate_hz: float | None = None
    """Target rate [Hz]; None: ``[machine] rate_hz``."""
    nan: Literal["fail", "fill"] = "fail"
    """Missing/non-finite values: ``fail``, or ``fill`` runs of up to ``max_fill`` samples."""
    max_fill: int = 5
    """Longest run of missing samples (input rows) that ``nan = "fill"`` interpolates."""
    max_gap_s: float | None = None
    """Time gaps longer than this split the episode [s]; None: max(5 input steps, 2 output steps)."""
    min_steps: int = 50
    """Episodes (after resampling) shorter than this are dropped; use the model window."""
    velocity: Literal["diff", "kalman"] = "diff"
    """How to derive velocities that the log does not contain."""
    lowpass: float = 0.8
    """Anti-alias cutoff as a fraction of the output Nyquist rate; 0 disables the filter."""
    clip_commands: bool = False
    """Clip commands outside the range instead of failing (clipped samples are reported)."""
    on_error: Literal["fail", "skip"] = "fail"
    """A file that fails validation stops the import (``fail``) or is skipped and reported."""
    outliers: Literal["fail", "drop", "clip"] = "fail"
    """Angle spikes, impossible samples and angles beyond the joint limits: ``fail``, ``drop``
    the rows, or ``clip`` to the limits (spikes and impossible samples are dropped); found
    before resampling (docs/import.md)."""
    max_upsample: float = 10.0
    """The target rate may be at most this multiple of a log's own rate (higher is refused)."""
    max_memory_mb: float | None = None
    """Bound on a log's decompressed text and its resampled output [MB]; None: a quarter of
    the memory available when the import starts."""

    def __post_init__(self) -> None:
        if self.rate_hz is not None and not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise ConfigError(f"rate_hz must be positive and finite, got {self.rate_hz:.6g}")
        if not (self.max_upsample >= 1 and math.isfinite(self.max_upsample)):
            raise ConfigError(f"max_upsample must be >= 1 and finite, got {self.max_upsample:.6g}")
        if self.max_memory_mb is not None and not (
            self.max_memory_mb > 0 and math.isfinite(self.max_memory_mb)
        ):
            raise ConfigError(f"max_memory_mb must be positive, got {self.max_memory_mb:.6g}")
        if self.max_fill < 0:
            raise ConfigError(f"max_fill must be >= 0, got {self.max_fill}")
        if self.max_gap_s is not None and not self.max_gap_s > 0:
            raise ConfigError(f"max_gap_s must be positive, got {self.max_gap_s}")
        if self.min_steps < 2:
            raise ConfigError(f"min_steps must be >= 2, got {self.min_steps}")
        if not 0.0 <= self.lowpass < 1.0:
            raise ConfigError(
                f"lowpass must be in [0, 1) (fraction of the output Nyquist), got {self.lowpass}"
            )


@dataclass(frozen=True)
class SplitOptions:
    """``[split]``: how episodes are assigned to train/val/test (always by source file)."""

    by: Literal["fraction", "glob", "file"] = "fraction"
    fractions: tuple[float, float, float] = (0.7, 0.15, 0.15)
    """train/val/test shares of the samples (``by = "fraction"``)."""
    seed: int = 0
    """Shuffle seed for ``by = "fraction"``."""
    train: tuple[str, ...] = ()
    """Glob patterns (``glob``) or file names (``file``) of training files."""
    val: tuple[str, ...] = ()
    test: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ConfigError(f"split seed must be >= 0, got {self.seed}")
        f = self.fractions
        if any(x < 0 for x in f) or not math.isclose(sum(f), 1.0, abs_tol=1e-6):
            raise ConfigError(f"split fractions {list(f)} must be >= 0 and sum to 1")


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
                f = DEG if j.angle.unit == "deg" else 1.0
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
    for key in ("angle", "command"):
        if not isinstance(raw.get(key), dict):
            raise ConfigError(
                f'{jw}: \'{key}\' table is required, e.g. {key} = {{ column = "...", unit = "..." }}'
            )
    body = {k: v for k, v in raw.items() if k not in ("angle", "velocity", "command")}
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
        raise ConfigError(f'{jw}: angle.unit is required: "deg" or "rad"')
    if velocity is not None:
        _check_source(velocity.column, velocity.topic, velocity.field, f"{jw}: velocity")
        if velocity.unit is None:
            raise ConfigError(f'{jw}: velocity.unit is required: "deg/s" or "rad/s"')
    _check_command(command, f"{jw}: command")
    if base.limits is not None and not base.limits[1] > base.limits[0]:
        raise ConfigError(f"{jw}: limits {list(base.limits)} must be [low, high] with high > low")
    return dataclasses.replace(base, angle=angle, velocity=velocity, command=command)


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
