"""What a raw log holds, as data: :class:`LogSummary` of :class:`ChannelSummary` rows
(:func:`~.inventory.summarize_log` builds them, ``exsur info LOG`` prints them), and the two
numbers every row takes from its samples (:func:`value_range`, :func:`sample_rate`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class ChannelSummary:
    """One channel of a raw log."""

    name: str
    """The name a mapping gives it: the column, the MDF channel, the ROS field path."""
    group: str = ""
    """Where it lives: the MDF channel group, the ROS topic, the dSPACE path ("" in a table)."""
    unit: str = ""
    """The log's own unit ("" where the log gives none)."""
    n_sample: int = 0
    """Its samples (messages of its topic)."""
    rate_hz: float | None = None
    """Median sample rate of its time base [Hz] (None where the log has no known time base)."""
    lo: float | None = None
    """Smallest finite value (None: no number)."""
    hi: float | None = None
    """Largest finite value (None: no number)."""
    n_missing: int = 0
    """Samples that are not finite numbers (empty cells, NaN)."""
    note: str = ""
    """What else to know (``text``, ``decimal commas``, ``time base``, ...)."""


@dataclass(frozen=True)
class LogSummary:
    """What one raw log holds (:func:`summarize_log`)."""

    path: Path
    kind: str
    """The reader's kind (``csv``, ``dspace``, ``parquet``, ``mdf``, ``rosbag2`` ...)."""
    label: str
    """The format, for people."""
    channels: list[ChannelSummary]
    start: str = ""
    """The absolute time of the log's start, where it records one."""
    duration_s: float | None = None
    """Span of its time bases [s] (None where it has no known time base)."""
    meta: dict[str, str] = field(default_factory=dict)
    """The log's metadata (what ``[[inputs]] from_metadata`` reads)."""
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: the path as text, the channels as dicts."""
        out = dataclasses.asdict(self)
        out["path"] = str(self.path)
        return out


def value_range(values: np.ndarray) -> tuple[float | None, float | None, int]:
    """``(lo, hi, n_missing)`` of float values (NaN / inf missing)."""
    finite = np.isfinite(values)
    if not finite.any():
        return None, None, int(values.size)
    v = values[finite]
    return float(v.min()), float(v.max()), int(values.size - v.size)


def sample_rate(t: np.ndarray) -> float | None:
    """Median sample rate [Hz] of sample times ``t`` [s] (None with < 2 distinct times)."""
    dt = np.diff(np.asarray(t, dtype=np.float64))
    dt = dt[np.isfinite(dt) & (dt > 0)]
    return float(1.0 / np.median(dt)) if dt.size else None
