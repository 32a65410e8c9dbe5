"""Machine description: which joints exist, which are periodic, command ranges, rate.

Everything downstream reads joint names and counts from a :class:`MachineSpec`; nothing
hard-codes four joints.  The default :data:`EXCAVATOR` is the paper's machine: swing
(periodic), boom, arm, bucket, with commands in [-1000, 1000] sampled at 20 Hz.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from .errors import ConfigError

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class JointSpec:
    """One actuated joint."""

    name: str
    """Lower-case identifier used in column names (``theta_<name>``)."""
    periodic: bool = False
    """True for joints without end stops (e.g. swing): encoded as sin/cos."""
    u_min: float = -1000.0
    """Lowest valid command [command units]."""
    u_max: float = 1000.0
    """Highest valid command [command units]."""
    theta_min: float | None = None
    """Lower joint limit [rad], or None if unlimited."""
    theta_max: float | None = None
    """Upper joint limit [rad], or None if unlimited."""
    u_unit: str = "command"
    """Physical meaning of the command (``command``, ``%``, ``Nm`` ...)."""

    def __post_init__(self) -> None:
        if not _NAME.match(self.name):
            raise ConfigError(
                f"joint name '{self.name}' is invalid: use lower-case letters, digits and '_'"
            )
        if not self.u_max > self.u_min:
            raise ConfigError(
                f"joint '{self.name}': u_max ({self.u_max}) must exceed u_min ({self.u_min})"
            )

    @property
    def u_scale(self) -> float:
        """Half the command span; ``u / u_scale`` lies in [-1, 1] for symmetric ranges."""
        return 0.5 * (self.u_max - self.u_min)

    @property
    def u_center(self) -> float:
        """Middle of the command range."""
        return 0.5 * (self.u_max + self.u_min)


@dataclass(frozen=True)
class MachineSpec:
    """An articulated machine: an ordered tuple of joints and a sample rate."""

    joints: tuple[JointSpec, ...]
    """Joints in the order used by every array's last axis."""
    rate_hz: float = 20.0
    """Sample (control) rate [Hz]."""
    name: str = "machine"
    """Human-readable machine name."""
    meta: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)
    """Free-form extra description (model number, source)."""

    def __post_init__(self) -> None:
        if len(self.joints) == 0:
            raise ConfigError("a machine needs at least one joint")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ConfigError(f"joint names must be unique, got {names}")
        if not self.rate_hz > 0:
            raise ConfigError(f"rate_hz must be positive, got {self.rate_hz}")

    @property
    def n_joint(self) -> int:
        """Number of joints."""
        return len(self.joints)

    @property
    def names(self) -> tuple[str, ...]:
        """Joint names in order."""
        return tuple(j.name for j in self.joints)

    @property
    def periodic(self) -> tuple[bool, ...]:
        """Periodic flag per joint."""
        return tuple(j.periodic for j in self.joints)

    @property
    def dt(self) -> float:
        """Sample period T_s [s]."""
        return 1.0 / self.rate_hz

    @property
    def n_feature(self) -> int:
        """Width of the surrogate input: 2 per periodic joint, 1 per other joint, plus commands."""
        return sum(2 if j.periodic else 1 for j in self.joints) + self.n_joint

    def with_rate(self, rate_hz: float) -> MachineSpec:
        """Same joints at another sample rate."""
        return replace(self, rate_hz=float(rate_hz))

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (stored in Parquet metadata and checkpoints)."""
        return {
            "name": self.name,
            "rate_hz": self.rate_hz,
            "joints": [asdict(j) for j in self.joints],
            "meta": dict(self.meta),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MachineSpec:
        """Inverse of :meth:`to_dict`."""
        try:
            joints = tuple(JointSpec(**j) for j in d["joints"])
            return cls(
                joints=joints,
                rate_hz=float(d["rate_hz"]),
                name=str(d.get("name", "machine")),
                meta=dict(d.get("meta", {})),
            )
        except (KeyError, TypeError) as e:
            raise ConfigError(
                f"malformed machine spec ({e}): expected keys name, rate_hz, joints"
            ) from e


def excavator_spec(rate_hz: float = 20.0) -> MachineSpec:
    """The paper's 4-joint excavator (SY750H class): swing, boom, arm, bucket."""
    return MachineSpec(
        joints=(
            JointSpec("swing", periodic=True),
            JointSpec("boom", theta_min=-0.75, theta_max=0.85),
            JointSpec("arm", theta_min=0.55, theta_max=2.65),
            JointSpec("bucket", theta_min=-0.60, theta_max=2.50),
        ),
        rate_hz=rate_hz,
        name="excavator-75t",
        meta={"class": "SY750H-like 75 t hydraulic excavator"},
    )


EXCAVATOR: MachineSpec = excavator_spec()
"""Default machine: the paper's excavator at 20 Hz."""
