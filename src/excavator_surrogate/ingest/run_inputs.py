"""Per-run constant inputs: what the user knows about a run, as an exogenous input.

Test rigs record run conditions in file names (``A-in-50-H-S``: load or engine condition
``H``) or in the log's metadata (an MDF4 header property, a dSPACE ``descriptions`` row, a
rosbag2 ``custom_data`` entry).  An ``[[inputs]]`` table with ``from_name`` or
``from_metadata`` instead of a channel turns that per-run constant into a command column
``u_<name>`` that holds one value for the whole log::

    [[inputs]]
    name = "condition"
    from_name = '-(?P<value>[HL])-[SC]$'     # regex searched in the log's file stem
    values = { H = 1.0, L = 0.0 }            # text -> number; range defaults to [min, max]

    [[inputs]]
    name = "payload"
    from_metadata = "Test/Payload"           # a metadata key (see metadata_keys)
    range = [0.0, 2000.0]                    # a numeric value: range required
    physical_unit = "kg"
    default = 0.0                            # for a log without the key (else an error)

:func:`parse_run_input` checks the table (``ConfigError``); :func:`run_input_value`
resolves it for one log (``DataError``: one line naming the file and the fix).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import ConfigError, DataError

KEYS = ("name", "from_name", "from_metadata", "values", "range", "physical_unit", "default")
"""The keys of a per-run ``[[inputs]]`` table."""


@dataclass(frozen=True)
class RunInputMap:
    """Where a per-run constant input comes from and how its text becomes a number."""

    from_name: str | None = None
    """Regex searched in the log's file stem (``run.dspace.csv.gz`` -> ``run``); the group
    ``value`` (or the only group, or the whole match) is the value's text."""
    from_metadata: str | None = None
    """Metadata key of the log (``Section/Key``; MDF4, dSPACE, ROS 2, Parquet)."""
    values: tuple[tuple[str, float], ...] = ()
    """Text -> number (``{ H = 1.0, L = 0.0 }``); empty: the text must be a number."""
    default: float | None = None
    """Value of a log whose name does not match / that lacks the key; None: an error."""

    @property
    def source(self) -> str:
        """How the mapping names the source, for messages."""
        if self.from_name is not None:
            return f"from_name = {self.from_name!r}"
        return f"from_metadata = {self.from_metadata!r}"


def is_run_input(raw: Any) -> bool:
    """True if the ``[[inputs]]`` table ``raw`` is a per-run constant (not a channel)."""
    return isinstance(raw, dict) and ("from_name" in raw or "from_metadata" in raw)


def parse_run_input(raw: dict[str, Any], iw: str) -> tuple[RunInputMap, tuple[float, float], str]:
    """Check a per-run ``[[inputs]]`` table: ``(run map, range [u_min, u_max], unit)``.

    Args:
        raw: the table as read from TOML.
        iw: ``"<mapping>: input '<name>'"`` for messages.

    Raises:
        ConfigError: one line naming the mapping, the input and the key.
    """
    unknown = sorted(set(raw) - set(KEYS))
    if unknown:
        raise ConfigError(
            f"{iw}: unknown key(s) {unknown} for a per-run input; valid: {sorted(KEYS)}"
        )
    if ("from_name" in raw) == ("from_metadata" in raw):
        raise ConfigError(f"{iw}: give either from_name or from_metadata, not both")
    pattern, key = raw.get("from_name"), raw.get("from_metadata")
    if pattern is not None:
        if not isinstance(pattern, str) or not pattern:
            raise ConfigError(f"{iw}: from_name must be a regex string, e.g. '-(?P<value>[HL])-'")
        try:
            rx = re.compile(pattern)
        except re.error as e:
            raise ConfigError(f"{iw}: from_name is not a valid regex ({e})") from e
        if rx.groups > 1 and "value" not in rx.groupindex:
            raise ConfigError(
                f"{iw}: from_name has {rx.groups} groups; name the one that holds the "
                "value (?P<value>...)"
            )
    if key is not None and (not isinstance(key, str) or not key.strip()):
        raise ConfigError(f'{iw}: from_metadata must be a key, e.g. "Engine/Mode"')
    values = _values(raw.get("values"), iw)
    rng = _range(raw.get("range"), values, iw)
    default = raw.get("default")
    if default is not None:
        if not _is_number(default):
            raise ConfigError(f"{iw}: default must be a number, got {default!r}")
        default = float(default)
        if not rng[0] <= default <= rng[1]:
            raise ConfigError(f"{iw}: default {default:g} is outside range {list(rng)}")
    unit = raw.get("physical_unit", "level" if values else "physical")
    if not isinstance(unit, str) or not unit:
        raise ConfigError(f'{iw}: physical_unit must be a unit name, e.g. "kg"')
    run = RunInputMap(from_name=pattern, from_metadata=key, values=values, default=default)
    return run, rng, unit


def _is_number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _values(raw: Any, iw: str) -> tuple[tuple[str, float], ...]:
    if raw is None:
        return ()
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(f"{iw}: values must be a table of text -> number, e.g. {{ H = 1.0 }}")
    bad = [k for k, v in raw.items() if not _is_number(v)]
    if bad:
        raise ConfigError(f"{iw}: values.{bad[0]} must be a finite number, got {raw[bad[0]]!r}")
    return tuple((str(k), float(v)) for k, v in raw.items())


def _range(raw: Any, values: tuple[tuple[str, float], ...], iw: str) -> tuple[float, float]:
    if raw is None:
        nums = [v for _, v in values]
        if not nums:
            raise ConfigError(
                f"{iw}: range = [lo, hi] is required for a numeric value (or give values = {{...}})"
            )
        if min(nums) == max(nums):
            raise ConfigError(f"{iw}: values all map to {nums[0]:g}; add range = [lo, hi]")
        return (min(nums), max(nums))
    if (
        not isinstance(raw, list)
        or len(raw) != 2
        or not all(_is_number(x) for x in raw)
        or not raw[1] > raw[0]
    ):
        raise ConfigError(f"{iw}: range must be [lo, hi] with hi > lo, got {raw!r}")
    rng = (float(raw[0]), float(raw[1]))
    out = [k for k, v in values if not rng[0] <= v <= rng[1]]
    if out:
        raise ConfigError(f"{iw}: values.{out[0]} is outside range {list(rng)}")
    return rng


def run_input_value(
    path: Path,
    stem: str,
    meta: dict[str, str],
    name: str,
    run: RunInputMap,
    rng: tuple[float, float],
    *,
    where: str,
) -> tuple[float, str]:
    """The value of per-run input ``name`` for one log, and where it came from.

    Args:
        path: the log (for messages).
        stem: its file stem (the name without the log suffix).
        meta: its metadata (key -> text; see each reader).
        name: the input's name; ``run``, ``rng``: its mapping.
        where: the mapping's file name, for the fix.

    Returns:
        ``(value, note)``: the number (inside ``rng``) and e.g. ``"name 'H'"``.

    Raises:
        DataError: no match / no key without a default, a text not in ``values``, a
            non-numeric text, a value outside the range.
    """
    what = f"input '{name}'"
    if run.from_name is not None:
        m = re.search(run.from_name, stem)
        if m is None:
            return _fallback(
                path, run, what, f"the file name '{stem}' does not match {run.source}", where
            )
        text = m.group("value") if "value" in m.re.groupindex else m.group(m.re.groups and 1)
        origin = "name"
    else:
        key = str(run.from_metadata)
        if key not in meta:
            shown = ", ".join(sorted(meta)[:12]) + (" ..." if len(meta) > 12 else "")
            has = f"its keys: {shown}" if meta else "it carries no metadata"
            return _fallback(path, run, what, f"no metadata key '{key}' ({has})", where)
        text = meta[key]
        origin = "metadata"
    text = (text or "").strip()
    if run.values:
        table = dict(run.values)
        if text not in table:
            raise DataError(
                path,
                f"{what}: value '{text}' ({origin}) is not one of {sorted(table)}",
                fix=f"add it to values in {where}",
            )
        value = table[text]
    else:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise DataError(
                path,
                f"{what}: value '{text}' ({origin}) is not a number",
                fix=f"map the texts to numbers with values = {{ ... }} in {where}",
            )
    if not rng[0] <= value <= rng[1]:
        raise DataError(
            path,
            f"{what}: value {value:g} ({origin} '{text}') is outside range {list(rng)}",
            fix=f"widen range in {where}, or fix the log",
        )
    return value, f"{origin} '{text}'"


def _fallback(
    path: Path, run: RunInputMap, what: str, problem: str, where: str
) -> tuple[float, str]:
    if run.default is not None:
        return run.default, "default"
    raise DataError(
        path,
        f"{what}: {problem}",
        fix=f"rename the log, fix the input in {where}, or set default = ... to allow a fallback",
    )
