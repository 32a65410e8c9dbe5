"""Units of a joint's position and velocity channels: angles (deg, rad) and strokes (m, cm, mm).

A mapping gives each joint's position in one of :data:`POSITION_UNITS`; its unit decides the
joint's kind (an angle makes a revolute joint, a length a linear one, see
:class:`~excavator_surrogate.spec.JointSpec`).  Values are converted to SI on import (rad,
m; rad/s, m/s) by :func:`to_si`; a linear joint keeps the mapping's unit for printing.  An
optional ``linkage = { a, b, l0, phi }`` (lengths in the position's unit, ``phi`` in deg)
gives the cylinder triangle that turns a stroke into an angle.
"""

from __future__ import annotations

import math
from typing import Any

from ..errors import ConfigError
from ..spec import LINEAR_UNITS, Linkage

DEG = math.pi / 180.0
"""One degree [rad]."""

ANGLE_UNITS: dict[str, float] = {"deg": DEG, "rad": 1.0}
"""Angle units -> SI factor (value x factor = rad)."""
LENGTH_UNITS: dict[str, float] = {u: 1.0 / n for u, n in LINEAR_UNITS.items()}
"""Length units -> SI factor (value x factor = m)."""
POSITION_UNITS: dict[str, float] = {**ANGLE_UNITS, **LENGTH_UNITS}
"""Every position unit a mapping accepts."""
VELOCITY_UNITS: dict[str, float] = {f"{u}/s": f for u, f in POSITION_UNITS.items()}
"""Every velocity unit a mapping accepts (the position's per second)."""


def to_si(unit: str | None) -> float:
    """Factor from ``unit`` (a position or velocity unit) to SI; 1 for None (rad)."""
    if unit is None:
        return 1.0
    return {**POSITION_UNITS, **VELOCITY_UNITS}[unit]


def is_length(unit: str | None) -> bool:
    """True for a position unit (or its per-second form) that is a length."""
    return unit is not None and unit.removesuffix("/s") in LENGTH_UNITS


def check_units(position: str | None, velocity: str | None, where: str) -> None:
    """The velocity is the position's kind of unit per second (not mm with deg/s)."""
    if position is None or velocity is None:
        return
    if is_length(position) != is_length(velocity):
        want = [u for u in VELOCITY_UNITS if is_length(u) == is_length(position)]
        raise ConfigError(
            f"{where}: velocity.unit '{velocity}' does not fit the position's unit "
            f"'{position}'; use one of {want}"
        )


def parse_linkage(
    raw: Any, unit: str | None, where: str, *, limits: tuple[float, float] | None = None
) -> Linkage | None:
    """``linkage = { a, b, l0 = 0, phi = 0 }`` of a linear joint -> :class:`Linkage` in SI
    (``a``, ``b``, ``l0`` in the position's ``unit``; ``phi`` in deg).  With the joint's
    ``limits`` (in ``unit``), the triangle must reach every stroke between them
    (:meth:`Linkage.misfit`: a linkage given in m for a position in mm reaches none)."""
    if raw is None:
        return None
    if not is_length(unit):
        raise ConfigError(
            f"{where}: a linkage is only for a linear joint (position unit m, cm or mm)"
        )
    if not isinstance(raw, dict):
        raise ConfigError(
            f"{where}: linkage must be a table {{ a = ..., b = ..., l0 = ..., phi = ... }}"
        )
    unknown = sorted(set(raw) - {"a", "b", "l0", "phi"})
    if unknown or not {"a", "b"} <= set(raw):
        raise ConfigError(
            f"{where}: linkage needs a and b (and optionally l0, phi); got keys {sorted(raw)}"
        )
    bad = [
        k
        for k, v in raw.items()
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)
    ]
    if bad:
        raise ConfigError(f"{where}: linkage.{bad[0]} must be a finite number, got {raw[bad[0]]!r}")
    vals = {k: float(v) for k, v in raw.items()}
    if not (vals["a"] > 0 and vals["b"] > 0 and vals.get("l0", 0.0) >= 0):
        raise ConfigError(
            f"{where}: linkage a = {vals['a']:g} and b = {vals['b']:g} must be positive and "
            f"l0 = {vals.get('l0', 0.0):g} >= 0 (lengths in {unit})"
        )
    f = to_si(unit)
    try:
        link = Linkage(
            a=vals["a"] * f,
            b=vals["b"] * f,
            l0=vals.get("l0", 0.0) * f,
            phi=vals.get("phi", 0.0) * DEG,
        )
    except ConfigError as e:  # pragma: no cover - the values are checked above
        raise ConfigError(f"{where}: {e}") from None
    if limits is not None:
        misfit = link.misfit(limits[0] * f, limits[1] * f, str(unit), what="the limits")
        if misfit is not None:
            raise ConfigError(f"{where}: {misfit}")
    return link
