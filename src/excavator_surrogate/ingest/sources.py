"""Reading raw logs: the common types (:class:`RawLog`, :class:`Series`, :class:`Reader`)
every log reader returns or registers, and the error for a mapped channel a log lacks.

Every reader returns a :class:`RawLog`: one or more :class:`Series` (a time base plus the
raw values of the channels that live on it).  A CSV/Parquet file has one series
(``"table"``); a bag has one series per topic, an MDF file one per channel group.  Values
are raw (no unit conversion); missing cells are NaN.  Rows are counted from 0, header not counted.

:data:`excavator_surrogate.ingest.readers.READERS` lists every log format (the tables, CSV
and Parquet, in :mod:`.tables`, ROS bags in :mod:`.ros`, dSPACE ControlDesk CSV in :mod:`.dspace`, ASAM MDF 4 and 3 in :mod:`.mdf`).
"""

from __future__ import annotations

import csv
import difflib
import hashlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import DataError
from .mapping import Channel, Mapping

CSV_SUFFIXES = (".csv", ".csv.gz")
PARQUET_SUFFIXES = (".parquet", ".pq")
ROS_SUFFIXES = (".mcap", ".bag", ".db3")


@dataclass
class Series:
    """One time base of a log and the raw channels sampled on it."""

    name: str
    """``"table"``, the ROS topic or the MDF channel group (``channel group 2``)."""
    time: np.ndarray
    """(n,) sample times [s] since the log's origin (unchecked: may be unsorted)."""
    values: dict[str, np.ndarray]
    """Channel key -> (n,) raw float64 values (NaN where missing)."""
    time_label: str
    """Name of the time source in messages (the column, or ``/topic header.stamp``)."""
    units: dict[str, str] = field(default_factory=dict)
    """Channel key -> the unit the log itself gives it (MDF channels, dSPACE
    ``trace_units``); absent where the log gives none."""


@dataclass
class RawLog:
    """A log file as read: its series and where its time starts."""

    path: Path
    kind: str
    """``csv``, ``parquet``, ``dspace``, ``mdf``, ``rosbag2``, ``rosbag1`` or ``mcap``."""
    series: dict[str, Series]
    origin: str
    """The absolute time of t = 0 as found in the log (number in its unit, or ISO string)."""
    columns: list[str] = field(default_factory=list)
    """All column names (tables) or topics (bags) of the file."""
    meta: dict[str, str] = field(default_factory=dict)
    """The log's metadata, key -> text (``Section/Key``): MDF4 header properties, dSPACE
    ``descriptions`` rows, rosbag2 ``custom_data``, MCAP metadata, Parquet key-value
    metadata; empty for CSV.  Read by per-run inputs (``from_metadata``)."""
    placement: dict[Channel, str] = field(default_factory=dict)
    """Mapped channel -> the series that holds it, where the mapping cannot say (an MDF
    log's channel groups: the mapping names channels, not groups); a channel not in it is on
    its :attr:`~.mapping.Channel.series`."""

    def series_name(self, ch: Channel) -> str:
        """Name of the series that holds the mapped channel ``ch``."""
        return self.placement.get(ch, ch.series)

    def series_of(self, ch: Channel) -> Series:
        """The series that holds the mapped channel ``ch``."""
        return self.series[self.series_name(ch)]

    @property
    def n_rows(self) -> int:
        """Total samples over all series."""
        return sum(int(s.time.shape[0]) for s in self.series.values())

    def digest(self) -> str:
        """A hash of the decoded samples (every series' times and mapped channels), the same
        for one recording stored twice (``.csv`` and ``.csv.gz``, a copy in another folder,
        another format): the import refuses such twins, which could land in two splits."""
        h = hashlib.blake2b(digest_size=16)
        for name in sorted(self.series):
            s = self.series[name]
            h.update(f"series {name!r} {s.time.shape[0]}\n".encode())
            h.update(np.ascontiguousarray(s.time, dtype=np.float64))
            for key in sorted(s.values):
                h.update(f"channel {key!r}\n".encode())
                h.update(np.ascontiguousarray(s.values[key], dtype=np.float64))
        return h.hexdigest()


@dataclass(frozen=True)
class Reader:
    """One log format: how to recognise a file and how to read it."""

    kind: str
    """Name stored in the report (``csv``, ``dspace``, ``mdf`` ...)."""
    label: str
    """What it reads, for messages: ``"CSV (.csv, .csv.gz)"``."""
    suffixes: tuple[str, ...]
    """File name endings (lower case), longest first; stripped to name the episodes."""
    match: Callable[[Path, str], bool]
    """``match(path, csv_format)``: True if this reader reads ``path``; ``csv_format`` is
    the mapping's ``[csv] format`` (``auto``, ``plain`` or ``dspace``)."""
    read: Callable[[Path, Mapping], RawLog]
    """Read the channels the mapping needs; raises DataError."""
    maps: Literal["columns", "topics"] = "columns"
    """What its mapping channels name: columns (channel names), or ROS topic fields."""
    whole_folder: bool = False
    """A storage file inside a folder log (rosbag2) stands for the whole folder."""


def has_suffix(*suffixes: str) -> Callable[[Path, str], bool]:
    """A ``Reader.match`` that accepts files whose name ends in one of ``suffixes``."""
    return lambda path, _fmt: not path.is_dir() and path.name.lower().endswith(suffixes)


def missing_channel(
    path: Path, name: str, names: Sequence[str], mapping: Mapping, *, what: str = "channel"
) -> DataError:
    """The error for a mapped ``what`` (channel, column) that the log lacks: the nearest name
    and the first 12 (past 12, ``exsur info`` lists them all)."""
    close = difflib.get_close_matches(name, list(names), n=1)
    hint = f"did you mean '{close[0]}'? " if close else ""
    more = f" ... ({len(names)} in all: exsur info {path} lists them)"
    shown = ", ".join(names[:12]) + (more if len(names) > 12 else "")
    return DataError(
        path,
        "mapped column is missing",
        column=name,
        fix=f"{hint}fix the {what} name in {mapping.where}; the log has: {shown}",
    )


def first_ragged_row(
    lines: Iterable[str], delimiter: str, n_fields: int
) -> tuple[int, int | str] | None:
    """The first row of the text ``lines`` (rows counted from 0, empty ones skipped) whose
    field count is not ``n_fields``: ``(row, its field count)``, or ``(row, the csv module's
    error)`` for a row it cannot split (a field past its size limit: a tail of NUL bytes left
    by a crash); None when every row holds ``n_fields``."""
    i = 0  # the rows read
    try:
        for row in csv.reader(lines, delimiter=delimiter):
            if row and len(row) != n_fields:
                return i, len(row)
            i += 1
    except csv.Error as e:
        return i, str(e)
    return None
