"""Machine description: which joints exist, which are periodic, command ranges, rate.

Everything downstream reads joint names and counts from a :class:`MachineSpec`; nothing
hard-codes four joints.  The default :data:`EXCAVATOR` is the paper's machine: swing
(periodic), boom, arm, bucket, with commands in [-1000, 1000] sampled at 20 Hz.

A joint is ``revolute`` (an angle, stored in rad) or ``linear`` (a cylinder stroke, stored
in m); every array holds SI values, and ``JointSpec.unit`` is only how a linear joint's
values are printed (``m``, ``cm``, ``mm``: :attr:`JointSpec.display_factor`).
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

from .errors import ConfigError

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")

SOURCE_META = "data_source"
"""Key of ``MachineSpec.meta`` under which a trained checkpoint records where its training
data came from: the episodes' ``source`` (``mujoco-ideal``, ``mujoco-hydraulic``, ``import``
...), several joined by ``+``.  Commands that run a checkpoint against a built-in plant read
it (:mod:`excavator_surrogate.env.plants`)."""

LINEAR_UNITS: dict[str, float] = {"m": 1.0, "cm": 100.0, "mm": 1000.0}
"""Display units of a linear joint -> how many of them make one metre (the stored unit)."""


@dataclass(frozen=True)
class Linkage:
    """The triangle that turns a cylinder's stroke into its joint's angle.

    The cylinder runs between two pivots at distances ``a`` and ``b`` from the joint axis;
    its pin-to-pin length is ``L = l0 + stroke = sqrt(a² + b² - 2ab cos(θ + phi))``.
    """

    a: float
    """Joint axis to the first cylinder pivot [m]."""
    b: float
    """Joint axis to the second cylinder pivot [m]."""
    phi: float = 0.0
    """Angle added to the joint angle to give the triangle's angle at the joint [rad]."""
    l0: float = 0.0
    """Pin-to-pin length of the cylinder at stroke 0 [m]."""

    def __post_init__(self) -> None:
        for key in ("a", "b", "phi", "l0"):
            v = getattr(self, key)
            if not (isinstance(v, int | float) and math.isfinite(v)):
                raise ConfigError(f"linkage {key} must be a finite number, got {v!r}")
        if not (self.a > 0 and self.b > 0):
            raise ConfigError(f"linkage a ({self.a}) and b ({self.b}) must be positive")
        if self.l0 < 0:
            raise ConfigError(f"linkage l0 ({self.l0}) must be >= 0")

    def stroke(self, theta: Any) -> Any:
        """Stroke [m] of joint angle(s) ``theta`` [rad] (scalar or array)."""
        import numpy as np

        c = np.cos(np.asarray(theta, dtype=np.float64) + self.phi)
        return np.sqrt(self.a**2 + self.b**2 - 2.0 * self.a * self.b * c) - self.l0

    @property
    def reach(self) -> tuple[float, float]:
        """The strokes [m] the triangle can give, ``(lowest, highest)``: its length runs from
        ``|a - b|`` (``θ + phi = 0``) to ``a + b`` (``θ + phi = π``), less ``l0``."""
        return abs(self.a - self.b) - self.l0, self.a + self.b - self.l0

    def misfit(self, lo: float, hi: float, unit: str, *, what: str = "strokes") -> str | None:
        """Why strokes ``lo`` .. ``hi`` [m] (``what``: a joint's limits, a log's samples) do
        not all fit the triangle, as a phrase in ``unit`` (``m``, ``cm`` or ``mm``, the
        position's) that names the likely unit slip of ``a``, ``b`` and ``l0``; None if they
        all fit."""
        if self.reachable([lo, hi]).all():
            return None
        f = LINEAR_UNITS[unit]
        r0, r1 = self.reach
        text = (
            f"the linkage reaches strokes {r0 * f:.6g} .. {r1 * f:.6g} {unit} only (its length "
            f"|a - b| .. a + b, less l0), not {what} {lo * f:.6g} .. {hi * f:.6g} {unit}"
        )
        # a slip when the lengths are out of all proportion to the strokes (a + b is at least
        # the longest stroke, and a cylinder's triangle is not 300x it) and `other` fits
        size = max(abs(lo), abs(hi), 1e-12)
        for other, n in LINEAR_UNITS.items():
            k = f / n  # a, b, l0 meant in `other` but read in `unit`: the true lengths are k x
            meant = Linkage(self.a * k, self.b * k, self.phi, self.l0 * k)
            in_proportion = [1.0 <= (x.a + x.b) / size <= 300.0 for x in (self, meant)]
            if other != unit and in_proportion == [False, True] and meant.reachable([lo, hi]).all():
                return (
                    f"{text}: its a, b and l0 look like {other}; give them in {unit}, the "
                    "position's unit"
                )
        return f"{text}: check a, b and l0 (in {unit}, the position's unit)"

    def reachable(self, stroke: Any) -> Any:
        """True where stroke(s) ``stroke`` [m] lie within :attr:`reach` (to 1e-9 of
        ``a + b``); same shape as ``stroke``."""
        import numpy as np

        r0, r1 = self.reach
        tol = 1e-9 * (self.a + self.b)
        s = np.asarray(stroke, dtype=np.float64)
        return (s >= r0 - tol) & (s <= r1 + tol)

    def angle(self, stroke: Any) -> Any:
        """Joint angle(s) [rad] of stroke(s) ``stroke`` [m]: the inverse of :meth:`stroke` on
        ``θ + phi`` in [0, π] (lengths the triangle cannot reach, outside :attr:`reach`, give
        the nearest end; :func:`~.evaluate.cbe.linkage_metrics` scores no angle for them)."""
        import numpy as np

        length = np.asarray(stroke, dtype=np.float64) + self.l0
        c = (self.a**2 + self.b**2 - length**2) / (2.0 * self.a * self.b)
        return np.arccos(np.clip(c, -1.0, 1.0)) - self.phi


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
    omega_max: float | None = None
    """Largest angular speed the joint reaches [rad/s], or None if unknown; free runs clip the
    predicted velocity to ``[-omega_max, omega_max]``."""
    kind: Literal["revolute", "linear"] = "revolute"
    """``revolute``: θ is an angle [rad]; ``linear``: θ is a stroke [m] (ω in m/s, the
    limits and ``omega_max`` in m and m/s)."""
    unit: str = "rad"
    """How θ is printed: ``rad`` for a revolute joint; ``m``, ``cm`` or ``mm`` for a linear one
    (values are stored in m whatever the unit)."""
    linkage: Linkage | None = None
    """A linear joint's cylinder geometry, to report its angle as well (None: unknown)."""

    def __post_init__(self) -> None:
        if not _NAME.match(self.name):
            raise ConfigError(
                f"joint name '{self.name}' is invalid: use lower-case letters, digits and '_'"
            )
        self._check_kind()
        self._check_finite()  # first: a NaN is named as such, not as a range that fails
        if self.omega_max is not None and not self.omega_max > 0:
            raise ConfigError(
                f"joint '{self.name}': omega_max ({self.omega_max}) must be positive or None"
            )
        if not self.u_max > self.u_min:
            raise ConfigError(
                f"joint '{self.name}': u_max ({self.u_max}) must exceed u_min ({self.u_min})"
            )
        if (
            self.theta_min is not None
            and self.theta_max is not None
            and self.theta_max < self.theta_min
        ):
            raise ConfigError(
                f"joint '{self.name}': theta_max ({self.theta_max:.6g}) is below theta_min "
                f"({self.theta_min:.6g}); give the limits as [lower, upper]"
            )

    def _check_finite(self) -> None:
        """Command ranges and limits are finite numbers (NaN or inf poison every rollout)."""
        for key in ("u_min", "u_max", "theta_min", "theta_max", "omega_max"):
            v = getattr(self, key)
            if v is not None and not math.isfinite(v):
                raise ConfigError(f"joint '{self.name}': {key} must be a finite number, got {v}")

    def _check_kind(self) -> None:
        """A linear joint has a length unit and no periodicity; a revolute one is in rad."""
        if self.kind == "linear":
            if self.periodic:
                raise ConfigError(
                    f"joint '{self.name}': a linear joint (a stroke) cannot be periodic; "
                    "set periodic = false"
                )
            if self.unit not in LINEAR_UNITS:
                raise ConfigError(
                    f"joint '{self.name}': unit '{self.unit}' is not a length; "
                    f"use one of {', '.join(LINEAR_UNITS)}"
                )
        elif self.kind == "revolute":
            if self.unit != "rad":
                raise ConfigError(
                    f"joint '{self.name}': a revolute joint is stored in rad, got unit "
                    f"'{self.unit}'; lengths need kind = \"linear\""
                )
            if self.linkage is not None:
                raise ConfigError(f"joint '{self.name}': only a linear joint has a linkage")
        else:
            raise ConfigError(
                f"joint '{self.name}': kind '{self.kind}' is unknown; use revolute or linear"
            )

    @property
    def linear(self) -> bool:
        """True for a linear joint (a stroke in m)."""
        return self.kind == "linear"

    @property
    def display_factor(self) -> float:
        """Stored value x this = value in :attr:`display_unit` (1 for rad and m, 1000 for mm)."""
        return LINEAR_UNITS[self.unit] if self.linear else 1.0

    @property
    def display_unit(self) -> str:
        """θ's printed unit (``rad``, ``m``, ``cm``, ``mm``)."""
        return self.unit

    @property
    def rate_unit(self) -> str:
        """ω's printed unit (``rad/s``, ``mm/s`` ...)."""
        return f"{self.unit}/s"

    def to_dict(self) -> dict[str, Any]:
        """JSON form; ``kind``, ``unit`` and ``linkage`` only when not the revolute default,
        so specs written before linear joints read (and hash) the same."""
        d = asdict(self)
        if not self.linear:
            for key in ("kind", "unit", "linkage"):
                d.pop(key)
        elif self.linkage is None:
            d.pop("linkage")
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> JointSpec:
        """Inverse of :meth:`to_dict` (a dict without ``kind`` is a revolute joint)."""
        d = dict(d)
        if isinstance(d.get("linkage"), dict):
            d["linkage"] = Linkage(**d["linkage"])
        return cls(**d)

    @property
    def u_scale(self) -> float:
        """Half the command span; ``u / u_scale`` lies in [-1, 1] for symmetric ranges."""
        return 0.5 * (self.u_max - self.u_min)

    @property
    def u_center(self) -> float:
        """Middle of the command range."""
        return 0.5 * (self.u_max + self.u_min)


@dataclass(frozen=True)
class InputSpec:
    """One exogenous input: a command that is not a joint's (engine speed, throttle, gear,
    pump pressure).  The model sees it as an extra command column after the joints'; its
    name and range follow a joint command's rules, and it is scaled the same way."""

    name: str
    """Lower-case identifier used in column names (``u_<name>``)."""
    u_min: float = 0.0
    """Lowest valid value [unit]."""
    u_max: float = 1.0
    """Highest valid value [unit]."""
    unit: str = "physical"
    """Physical meaning (``rpm``, ``%``, ``bar`` ...)."""

    def __post_init__(self) -> None:
        try:  # the rules of a joint's name and command range
            JointSpec(self.name, u_min=self.u_min, u_max=self.u_max)
        except ConfigError as e:
            raise ConfigError(str(e).replace("joint", "input", 1)) from None

    u_scale = JointSpec.u_scale
    """Half the span; ``(u - u_center) / u_scale`` lies in [-1, 1]."""
    u_center = JointSpec.u_center
    """Middle of the range."""


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
    inputs: tuple[InputSpec, ...] = ()
    """Exogenous inputs, the command columns after the joints' (empty: none)."""

    def __post_init__(self) -> None:
        if len(self.joints) == 0:
            raise ConfigError("a machine needs at least one joint")
        both = [*(j.name for j in self.joints), *(i.name for i in self.inputs)]
        if self.inputs and len(set(both)) != len(both):
            raise ConfigError(f"joint and input names must be unique (u_<name>), got {both}")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ConfigError(f"joint names must be unique, got {names}")
        if not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise ConfigError(f"rate_hz must be a positive finite number, got {self.rate_hz}")

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
    def n_input(self) -> int:
        """Number of exogenous inputs."""
        return len(self.inputs)

    @property
    def n_u(self) -> int:
        """Command columns: the joints' then the inputs' (``n_joint + n_input``)."""
        return self.n_joint + self.n_input

    @property
    def u_specs(self) -> tuple[JointSpec | InputSpec, ...]:
        """The ``n_u`` command columns' specs (each has ``u_min``, ``u_max``, ``u_center``,
        ``u_scale``): the joints, then the inputs."""
        return (*self.joints, *self.inputs)

    @property
    def u_names(self) -> tuple[str, ...]:
        """Names of the ``n_u`` command columns."""
        return tuple(c.name for c in self.u_specs)

    @property
    def n_angle_feature(self) -> int:
        """Angle columns at the start of the surrogate input: 2 per periodic joint (sin, cos),
        1 per other joint; the commands follow them."""
        return sum(2 if j.periodic else 1 for j in self.joints)

    @property
    def n_feature(self) -> int:
        """Width of the surrogate input: the angle columns (:attr:`n_angle_feature`) plus the
        ``n_u`` commands (joints' and inputs')."""
        return self.n_angle_feature + self.n_u

    @property
    def input_features(self) -> slice:
        """The exogenous inputs' columns of the surrogate input: the last :attr:`n_input` of
        its :attr:`n_feature` base columns (the columns a network that ignores them holds at
        zero weight)."""
        return slice(self.n_feature - self.n_input, self.n_feature)

    @property
    def any_linear(self) -> bool:
        """True if some joint is linear (its θ a stroke in m)."""
        return any(j.linear for j in self.joints)

    def mismatch(self, other: MachineSpec) -> str | None:
        """How ``other`` differs from this machine (joints, periodic flags, kinds, command ranges, rate,
        exogenous inputs),
        as a short phrase such as ``"joints ['boom', 'arm'] vs ['swing', ...]"``; None if it fits."""
        if self.names != other.names:
            return f"joints {list(self.names)} vs {list(other.names)}"
        if not math.isclose(self.rate_hz, other.rate_hz, rel_tol=1e-9):
            return f"rate {self.rate_hz:g} Hz vs {other.rate_hz:g} Hz"
        for a, b in zip(self.joints, other.joints):
            if a.periodic != b.periodic:
                return f"joint '{a.name}' periodic {a.periodic} vs {b.periodic}"
            if a.kind != b.kind:
                return f"joint '{a.name}' {a.kind} vs {b.kind}"
            if not (math.isclose(a.u_min, b.u_min) and math.isclose(a.u_max, b.u_max)):
                return (
                    f"joint '{a.name}' command range [{a.u_min:g}, {a.u_max:g}] vs "
                    f"[{b.u_min:g}, {b.u_max:g}]"
                )
        a_in = [(i.name, i.u_min, i.u_max) for i in self.inputs]
        b_in = [(i.name, i.u_min, i.u_max) for i in other.inputs]
        if a_in != b_in:
            return f"exogenous inputs {a_in} vs {b_in}"
        return None

    def with_rate(self, rate_hz: float) -> MachineSpec:
        """Same joints at another sample rate."""
        return replace(self, rate_hz=float(rate_hz))

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (stored in Parquet metadata and checkpoints)."""
        d = {
            "name": self.name,
            "rate_hz": self.rate_hz,
            "joints": [j.to_dict() for j in self.joints],
            "meta": dict(self.meta),
        }
        if self.inputs:  # absent without inputs: specs written before inputs read the same
            d["inputs"] = [asdict(i) for i in self.inputs]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MachineSpec:
        """Inverse of :meth:`to_dict`."""
        try:
            joints = tuple(JointSpec.from_dict(j) for j in d["joints"])
            return cls(
                joints=joints,
                rate_hz=float(d["rate_hz"]),
                name=str(d.get("name", "machine")),
                meta=dict(d.get("meta", {})),
                inputs=tuple(InputSpec(**i) for i in d.get("inputs", ())),
            )
        except (KeyError, TypeError, ValueError) as e:  # ValueError: rate_hz = "fast"
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
