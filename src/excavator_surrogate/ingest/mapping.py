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
    [csv]                    # delimiter, decimal, thousands, encoding, skip_rows(_after_header), format

For ROS bags a channel names ``topic`` and ``field`` (e.g. ``field = "position[1]"``)
instead of ``column``; for two-channel commands ``up``/``down`` are field paths of ``topic``,
or each its own ``{ topic = ..., field = ... }`` where the two directions are two topics.

These are the parsed mapping's types; :func:`~.mapping_toml.load_mapping` reads and checks
the file and raises :class:`~excavator_surrogate.errors.ConfigError` with a one-line message
naming the file and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..errors import ConfigError
from ..spec import InputSpec, JointSpec, Linkage, MachineSpec
from .options import CsvOptions, ImportOptions, SplitOptions
from .run_inputs import RunInputMap
from .units import DEG as DEG  # re-exported: the checks' degree factor
from .units import is_length, to_si

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
    ``up``/``down`` (columns, or field paths of ``topic``, or of ``up_topic`` and
    ``down_topic``) combined as ``up - down``.
    """

    column: str | None = None
    """CSV/Parquet column of a signed command."""
    up: str | None = None
    """The one-way channel whose value raises the command: a column or a field path."""
    down: str | None = None
    """The one-way channel whose value lowers the command: a column or a field path."""
    topic: str | None = None
    """ROS topic of ``field``, or of ``up`` and ``down``."""
    field: str | None = None
    """Field path of a signed command in ``topic``'s message."""
    up_topic: str | None = None
    """ROS topic of ``up`` where it is not ``topic`` (``up = { topic = ..., field = ... }``)."""
    down_topic: str | None = None
    """ROS topic of ``down`` where it is not ``topic`` (``down = { topic = ..., field = ... }``)."""
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


TIME_UNIT_S: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
"""A numeric ``[time] unit`` -> seconds per unit."""


@dataclass(frozen=True)
class TimeMap:
    """``[time]``: the time base."""

    column: str | None = None
    """CSV/Parquet time column (required there); dSPACE: default the x-axis trace; MDF: unused."""
    unit: Literal["s", "ms", "us", "ns", "datetime"] = "s"
    """Numeric unit, or ``datetime`` for ISO-8601 strings / timestamp columns."""
    stamp: Literal["auto", "header", "log"] = "auto"
    """ROS: use ``header.stamp`` or the bag's log time (``auto``: header when present)."""
    format: str | None = None
    """With ``unit = "datetime"``: the text's form as a ``strptime`` format, e.g.
    ``"%d.%m.%Y %H:%M:%S,%f"``, or ``"%H:%M:%S.%f"`` for a time of day; None: ISO-8601."""

    def __post_init__(self) -> None:
        if self.format is not None and self.unit != "datetime":
            raise ConfigError(
                f'[time] format is for date-time text: set unit = "datetime" (unit is {self.unit!r})'
            )
        if self.format is not None and "%" not in self.format:
            raise ConfigError(
                f'[time] format {self.format!r} has no % directive (e.g. "%d.%m.%Y %H:%M:%S.%f")'
            )


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
        """``(signed,)`` or ``(up, down)`` channels of joint (or input) ``j`` (a ROS command's
        up and down may lie on two topics)."""
        c = j.command
        if isinstance(j, InputMap) and j.run is not None:
            return ()  # a per-run constant reads no channel
        if c.two_channel:
            return (
                Channel(c.up_topic or c.topic or TABLE, str(c.up)),
                Channel(c.down_topic or c.topic or TABLE, str(c.down)),
            )
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
