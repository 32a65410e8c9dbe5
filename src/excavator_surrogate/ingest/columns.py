"""The column converters of the table readers: a column of numbers or of text as float64
(:func:`numeric_column`), and a time column as seconds since its first row
(:func:`parse_time`). Shared by the CSV/Parquet reader (:mod:`.tables`) and the dSPACE one;
a bad cell is a :class:`~excavator_surrogate.errors.DataError` naming its column and row.
"""

from __future__ import annotations

import re
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import DataError
from .mapping import TimeMap

_UNIT_NS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}


def numeric_column(
    path: Path,
    col: pa.ChunkedArray | pa.Array,
    name: str,
    *,
    decimal: str = ".",
    thousands: str = "",
) -> np.ndarray:
    """Column as float64 (nulls -> NaN); DataError at the first non-numeric cell.

    ``decimal`` is the decimal mark of a text column: with ``","``, ``1,25`` reads 1.25 and a
    cell holding a ``.`` is refused (it may be a thousands separator), as pyarrow does.
    ``thousands`` ("" for none) is removed from a text column's cells first: with ``"."``
    and ``decimal = ","``, ``-1.000,5`` reads -1000.5 (the grouping is not checked).
    """
    t = col.type
    if (
        pa.types.is_floating(t)
        or pa.types.is_integer(t)
        or pa.types.is_boolean(t)
        or pa.types.is_null(t)
    ):
        return np.asarray(
            pc.cast(col, pa.float64()).to_numpy(zero_copy_only=False), dtype=np.float64
        )
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        raw = col
        if thousands:
            col = pc.replace_substring(col, thousands, "")
        if decimal == "." or not pc.any(pc.match_substring(col, ".")).as_py():
            dotted = col if decimal == "." else pc.replace_substring(col, decimal, ".")
            try:
                return np.asarray(
                    pc.cast(dotted, pa.float64()).to_numpy(zero_copy_only=False), dtype=np.float64
                )
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
                pass
        arr = col.to_numpy(zero_copy_only=False)
        for i, v in enumerate(arr):
            if v is None:
                continue
            if is_number(v, decimal):
                continue
            cell = raw[i].as_py()
            raise DataError(
                path,
                f"non-numeric value {cell!r}",
                column=name,
                row=i,
                fix=_number_fix(cell, decimal, thousands),
            )
    raise DataError(
        path, f"values are of type {t}, not numbers", column=name, fix="map a numeric column"
    )


def is_number(text: str, decimal: str) -> bool:
    """Whether ``text`` is a number written with the decimal mark ``decimal``."""
    if decimal != "." and "." in text:
        return False
    try:
        float(text.replace(decimal, "."))
    except ValueError:
        return False
    return True


def _grouped(text: str, thousands: str, decimal: str) -> bool:
    """Whether ``text`` is a number whose integer digits are grouped in threes by
    ``thousands`` (``-1.234.567,5`` with ``"."`` and ``","``)."""
    th, dec = re.escape(thousands), re.escape(decimal)
    return (
        re.fullmatch(rf"[+-]?\d{{1,3}}({th}\d{{3}})+({dec}\d*)?([eE][+-]?\d+)?", text) is not None
    )


def _number_fix(text: str, decimal: str, thousands: str = "") -> str:
    """What to do about the cell ``text`` that is not a number with the marks ``decimal`` and
    ``thousands``: the setting that reads it, if one does."""
    if not thousands:
        other = "," if decimal == "." else "."
        if decimal == "." and is_number(text, ","):
            return 'the log writes decimal commas: set [csv] decimal = "," in the mapping'
        if decimal != "." and is_number(text, "."):
            return (
                f"[csv] decimal is {decimal!r}, but this cell has a decimal point: if the log "
                'writes decimal points, set [csv] decimal = "." in the mapping'
            )
        for dec, change in ((decimal, ""), (other, f'decimal = "{other}" and ')):
            for mark in (".", ",", " ", "'"):
                if mark != dec and _grouped(text, mark, dec):
                    return (
                        f"the log groups thousands with {mark!r}: set [csv] {change}"
                        f'thousands = "{mark}" in the mapping'
                    )
    return "replace it with a number or leave the cell empty (see --nan)"


def parse_time(
    path: Path, col: pa.ChunkedArray, tm: TimeMap, *, decimal: str = ".", thousands: str = ""
) -> tuple[np.ndarray, str]:
    """Time column -> (seconds since the first row, origin string); ``decimal`` as in
    :func:`numeric_column`. A duration column (pandas' Timedelta) is read in its own unit,
    whatever ``tm.unit`` says."""
    name = str(tm.column)
    t = col.type
    if col.null_count:
        valid = col.is_valid().to_numpy(zero_copy_only=False)
        row = int(np.flatnonzero(~valid)[0])
        raise DataError(
            path,
            "missing timestamp",
            column=name,
            row=row,
            fix="drop rows without a time stamp (time gaps are handled, missing stamps are not)",
        )
    if pa.types.is_duration(t):  # pandas' Timedelta: the type carries its unit
        ns = np.asarray(
            pc.cast(pc.cast(col, pa.duration("ns")), pa.int64()).to_numpy(zero_copy_only=False),
            dtype=np.int64,
        )
        return (ns - ns[0]).astype(np.float64) * 1e-9, f"{int(ns[0])} ns (a duration)"
    if tm.unit == "datetime":
        ns = _datetime_ns(path, col, name, fmt=tm.format)
        origin = str(pc.cast(col, pa.string())[0]) if col.num_chunks else ""
        return (ns - ns[0]).astype(np.float64) * 1e-9, origin
    if pa.types.is_timestamp(t):
        raise DataError(
            path,
            "time column holds timestamps, but unit is numeric",
            column=name,
            fix='set [time] unit = "datetime"',
        )
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        first = col[0].as_py()
        bare = first.replace(thousands, "") if isinstance(first, str) and thousands else first
        if not (isinstance(bare, str) and (is_number(bare, ".") or is_number(bare, ","))):
            raise DataError(
                path,
                f"time value {first!r} is text, not a number",
                column=name,
                row=0,
                fix='set [time] unit = "datetime" for ISO-8601 time stamps',
            )
        vals = numeric_column(path, col, name, decimal=decimal, thousands=thousands)
    elif pa.types.is_integer(t):
        ints = np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.int64)
        rel = (ints - ints[0]).astype(np.float64) * (_UNIT_NS[tm.unit] * 1e-9)
        return rel, f"{int(ints[0])} {tm.unit}"
    else:
        vals = numeric_column(path, col, name)
    row = _first_non_finite(vals)
    if row is not None:
        raise _bad_stamp(path, name, row, f"non-finite timestamp {float(vals[row]):g}")
    with np.errstate(over="ignore", invalid="ignore"):
        rel = (vals - vals[0]) * (_UNIT_NS[tm.unit] * 1e-9)
    row = _first_non_finite(rel)
    if row is not None:
        problem = (
            f"timestamp {float(vals[row]):.6g} is out of range (row 0 reads {float(vals[0]):.6g})"
        )
        raise _bad_stamp(path, name, row, problem)
    return rel, f"{float(vals[0])!r} {tm.unit}"


def _first_non_finite(x: np.ndarray) -> int | None:
    """The index of ``x``'s first NaN or infinity, or None."""
    bad = np.flatnonzero(~np.isfinite(x))
    return int(bad[0]) if bad.size else None


def _bad_stamp(path: Path, name: str, row: int, problem: str) -> DataError:
    return DataError(
        path, problem, column=name, row=row, fix="drop rows without a valid time stamp"
    )


def _datetime_ns(
    path: Path, col: pa.ChunkedArray, name: str, *, fmt: str | None = None
) -> np.ndarray:
    """Nanoseconds since 1970 (UTC where the text has an offset) of a timestamp column or of
    date-time text: ISO-8601, or the ``strptime`` format ``fmt``."""
    t = col.type
    if pa.types.is_timestamp(t) or pa.types.is_date(t):
        ts = pc.cast(col, pa.timestamp("ns", tz=getattr(t, "tz", None)))
        return np.asarray(pc.cast(ts, pa.int64()).to_numpy(zero_copy_only=False), dtype=np.int64)
    if not (pa.types.is_string(t) or pa.types.is_large_string(t)):
        raise DataError(
            path,
            f"time values are of type {t}, not ISO-8601 text",
            column=name,
            fix="use a numeric unit (s, ms, us, ns) for numeric time stamps",
        )
    if fmt is not None:
        return _parsed_ns(path, col, name, fmt=fmt)
    for target in (pa.timestamp("ns"), pa.timestamp("ns", tz="UTC")):
        try:
            ts = pc.cast(col, target)
            return np.asarray(
                pc.cast(ts, pa.int64()).to_numpy(zero_copy_only=False), dtype=np.int64
            )
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            continue
    return _parsed_ns(path, col, name, fmt=None)  # mixed or unusual forms: row by row


_LONG_FRACTION = re.compile(r"(?<=[.,])(\d{6})(\d{1,3})(?!\d)")
"""A fraction of a second of 7 to 9 digits: Python's parsers keep 6 (``%f``), the rest are ns."""


def _split_ns(text: str) -> tuple[str, int]:
    """``text`` with a fraction of a second cut to its first 6 digits, and the nanoseconds
    cut off: ``"12:00:00.123456789"`` -> ``("12:00:00.123456", 789)``; ``(text, 0)`` where
    the fraction has 6 digits or fewer (``strptime``'s ``%f`` takes at most 6)."""
    m = _LONG_FRACTION.search(text)
    if m is None:
        return text, 0
    return text[: m.start(2)] + text[m.end(2) :], int(m.group(2).ljust(3, "0"))


def _parsed_ns(path: Path, col: pa.ChunkedArray, name: str, *, fmt: str | None) -> np.ndarray:
    """Date-time text parsed row by row in Python, as nanoseconds since 1970: ISO-8601
    (``fmt`` None), or the ``strptime`` format ``fmt`` (Arrow's parser has no ``%f``; about
    10 µs a row). A fraction of a second may have up to 9 digits (:func:`_split_ns`). The
    first row that does not parse is a DataError."""
    out = np.empty(len(col), dtype=np.int64)
    epoch = datetime(1970, 1, 1)
    for i, v in enumerate(col.to_pylist()):
        text, sub_us = _split_ns(str(v).strip())
        try:
            d = datetime.fromisoformat(text) if fmt is None else datetime.strptime(text, fmt)
        except ValueError as e:
            if fmt is None:
                problem = f"time value {v!r} is not an ISO-8601 date-time"
                fix = (
                    "give their form as a strptime format in the mapping, e.g. [time] format = "
                    '"%d.%m.%Y %H:%M:%S.%f", or write times like 2024-05-01T12:00:00.125'
                )
            else:
                problem = f"time value {v!r} does not match [time] format {fmt!r} ({e})"
                fix = 'write the format with Python\'s strptime directives, e.g. "%d.%m.%Y %H:%M:%S.%f"'
            raise DataError(path, problem, column=name, row=i, fix=fix) from None
        out[i] = _ns(d, epoch) + sub_us
    return out


def _ns(d: datetime, epoch: datetime) -> int:
    """``d`` as whole microseconds since ``epoch``, in ns (an aware ``d`` is taken to UTC),
    in integers: a float's seconds would be a microsecond short on about 1 % of stamps."""
    if d.tzinfo is not None:
        d = (d - (d.utcoffset() or timedelta(0))).replace(tzinfo=None)
    return (d - epoch) // timedelta(microseconds=1) * 1000
