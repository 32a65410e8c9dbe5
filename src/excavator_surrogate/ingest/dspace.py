"""dSPACE ControlDesk CSV exports: metadata rows, then one ``trace_values`` row per sample.

The layout, as ControlDesk 7 writes it (``,`` or ``;`` between cells)::

    descriptions,General,User,...          free-form metadata rows (may hold non-UTF-8 text)
    trace_size,<number of samples>
    trace_names,,In1,In1,Boom_up_duty,...  one cell per trace after the label cell
    path,,Model Root/Sensors/Boom_ang,...  the model path of each trace
    ...                                    trace_types, trace_units, raster, min, max ...
    trace_values,0,1.5,0,...               the first sample; later rows leave the label empty
    ,0.01,1.6,0,...

Trace 0 is the x axis (time in s; ``[time] column`` defaults to it, and it answers to
``"time"`` when it has no name).  A ``[time] column`` that names no other trace is the x
axis too, read in seconds whatever ``[time] unit`` says, so one mapping reads a rig's plain
CSV logs (time column ``t_ms``, unit ``ms``) and its exports.  Most ``trace_names`` are the generic port name of the
recorded block (``In1``, ``Out1``) or empty, so such a trace is named by the last segment
of its ``path``; a specific trace name is used as it is.  A mapping may also give the full
name (``<path>/<trace name>``, or the ``path`` of a generically named trace).  A name that
fits two traces is refused with the full names to use instead.  All traces share the
x axis (one time base).
"""

from __future__ import annotations

import csv
import dataclasses
import gzip
import io
import re
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from ..errors import DataError
from .columns import numeric_column, parse_time
from .limits import TooBig, bounded_open, memory_limit, too_big
from .mapping import TABLE, Mapping
from .sources import CSV_SUFFIXES, RawLog, Reader, Series, first_ragged_row, missing_channel

SUFFIXES = (".dspace.csv.gz", ".dspace.csv")
GENERIC = re.compile(r"(?:In|Out)\d*", re.IGNORECASE)
"""Trace names that say nothing (the port of the recorded block)."""
LABELS = ("descriptions", "trace_size", "trace_types", "trace_names", "trace_units", "path")
"""First cells of the rows before the samples (the first one identifies the format)."""
X_AXIS = "time"
"""Name of trace 0 (the x axis) when the export gives it none."""
_VALUES = re.compile(rb"(?:^|\n)trace_values([,;\t])")


@dataclass(frozen=True)
class Trace:
    """One recorded signal of the export."""

    index: int
    """Position among the traces (0 = the x axis); its cell is ``index + 1`` of a row."""
    name: str
    """The ``trace_names`` entry (often ``In1``)."""
    path: str
    """The ``path`` entry (``Model Root/Subsystem/Signal``)."""
    unit: str = ""
    """The ``trace_units`` entry ("" where the export gives none)."""

    @property
    def specific(self) -> bool:
        """True if the trace name says what the signal is."""
        return bool(self.name) and not GENERIC.fullmatch(self.name)

    @property
    def short(self) -> str:
        """The channel name: a specific trace name, else the last segment of the path."""
        if self.specific:
            return self.name
        seg = self.path.rstrip("/").rsplit("/", 1)[-1]
        return seg or self.name or (X_AXIS if self.index == 0 else "")

    @property
    def full(self) -> str:
        """The unambiguous name: ``path/name`` (specific name) or the path."""
        if self.specific and self.path:
            return f"{self.path.rstrip('/')}/{self.name}"
        return self.path or self.short

    def aliases(self) -> set[str]:
        """Every name a mapping may use for this trace."""
        return {
            a for a in (self.short, self.full, self.path, self.name if self.specific else "") if a
        }


def is_dspace(path: Path, csv_format: str) -> bool:
    """True for a CSV file that is (or is forced to be read as) a ControlDesk export."""
    name = path.name.lower()
    if path.is_dir() or not name.endswith(CSV_SUFFIXES) or csv_format == "plain":
        return False
    if csv_format == "dspace" or name.endswith(SUFFIXES):
        return True
    try:
        opener = gzip.open if name.endswith(".gz") else open
        with opener(path, "rb") as f:
            first = f.read(4096).split(b"\n", 1)[0]
    except (OSError, EOFError, zlib.error):
        return False  # the CSV reader reports the damage
    cell = re.split(rb"[,;\t]", first, maxsplit=1)[0].strip().removeprefix(b"\xef\xbb\xbf")
    return cell.decode("latin-1") in (*LABELS, "trace_values")


def read_export(path: Path, limit: int) -> bytes:
    """The whole (decompressed) file; DataError past ``limit`` bytes."""
    try:
        with bounded_open(path, limit) as f:
            return f.read()
    except TooBig as e:
        raise too_big(path, "decompressing the export", e.n_read, limit, more=True) from None
    except (OSError, EOFError, zlib.error) as e:
        raise DataError(
            path,
            f"cannot read the file ({type(e).__name__}: {e})",
            fix="the file may be truncated; re-export it from ControlDesk",
        ) from e


def parse_header(
    path: Path, data: bytes, *, encoding: str = "utf-8"
) -> tuple[list[Trace], int, str, int | None]:
    """The traces, the byte offset of the ``trace_values`` row, the delimiter and ``trace_size``.

    The names and paths are decoded with ``encoding`` (bytes it cannot decode are replaced).

    Raises:
        DataError: no ``trace_values`` row, or neither ``trace_names`` nor ``path``.
    """
    m = _VALUES.search(data)
    if m is None:
        raise DataError(
            path,
            "no trace_values row: not a dSPACE ControlDesk CSV export",
            fix='export the measurement as CSV from ControlDesk, or set [csv] format = "plain"',
        )
    start = m.start() + (1 if data[m.start() : m.start() + 1] == b"\n" else 0)
    delim = m.group(1).decode()
    rows: dict[str, list[str]] = {}
    text = data[:start].decode(encoding, errors="replace")
    for row in csv.reader(io.StringIO(text, newline=""), delimiter=delim):
        if row and row[0].strip() in LABELS and row[0].strip() not in rows:
            rows[row[0].strip()] = [c.strip() for c in row[1:]]
    end = data.find(b"\n", start)
    first = data[start : end if end >= 0 else len(data)].decode(encoding, errors="replace")
    n_trace = len(next(csv.reader([first.rstrip("\r")], delimiter=delim))) - 1
    if "trace_names" not in rows and "path" not in rows:
        raise DataError(
            path,
            "no trace_names or path row before trace_values: cannot name the channels",
            fix="export the measurement again with ControlDesk's CSV export",
        )
    names = rows.get("trace_names", []) + [""] * n_trace
    paths = rows.get("path", []) + [""] * n_trace
    units = rows.get("trace_units", []) + [""] * n_trace
    traces = [Trace(i, names[i], paths[i], units[i]) for i in range(n_trace)]
    size = rows.get("trace_size", [""])[0] if rows.get("trace_size") else ""
    return traces, start, delim, int(size) if size.isdigit() else None


def metadata(data: bytes, *, encoding: str = "utf-8") -> dict[str, str]:
    """The ``descriptions`` rows before the traces: ``{"General/Description": "...", ...}``.

    Each row is ``<label or empty>,<section>,<key>,<value>``; the first reads
    ``descriptions``, the next ones leave the label empty.  Text that is not in ``encoding``
    (the mapping's ``[csv] encoding``; often a local code page) is decoded with replacement
    characters.
    """
    m = _VALUES.search(data)
    head = data[: m.start()] if m is not None else data[:65536]
    delim = m.group(1).decode() if m is not None else ","
    text = head.decode(encoding, errors="replace")
    out: dict[str, str] = {}
    inside = False
    for row in csv.reader(io.StringIO(text, newline=""), delimiter=delim):
        label = row[0].strip() if row else ""
        if label:  # a labelled row starts (descriptions) or ends the metadata
            inside = label == "descriptions"
        if inside and len(row) >= 3 and row[2].strip():
            key = f"{row[1].strip()}/{row[2].strip()}" if row[1].strip() else row[2].strip()
            out.setdefault(key, ",".join(row[3:]).strip())
    return out


def resolve(path: Path, traces: list[Trace], name: str, mapping: Mapping) -> Trace:
    """The one trace a mapping ``name`` refers to.

    Raises:
        DataError: no trace has that name, or several do (the message lists their full names).
    """
    hits = [t for t in traces if name in t.aliases()]
    if not hits:
        raise missing_channel(path, name, [t.short for t in traces if t.short], mapping)
    if len(hits) > 1:
        cands = ", ".join(f"'{t.full}'" for t in hits[:6]) + (" ..." if len(hits) > 6 else "")
        raise DataError(
            path,
            f"channel name is ambiguous: {len(hits)} traces answer to it",
            column=name,
            fix=f"map one of the full names in {mapping.where}: {cands}",
        )
    return hits[0]


def _bad_row(path: Path, body: bytes, delim: str, n_cells: int) -> DataError | None:
    """The first sample row whose cell count differs from the ``trace_values`` row, or that
    cannot be split into cells (:func:`~.sources.first_ragged_row`)."""
    text = body.decode("utf-8", errors="replace")
    bad = first_ragged_row(io.StringIO(text, newline=""), delim, n_cells)
    if bad is None:
        return None
    row, got = bad
    problem = (
        f"sample row has {got} cells, the trace_values row {n_cells}"
        if isinstance(got, int)
        else f"sample row cannot be split into cells ({got})"
    )
    return DataError(
        path,
        problem,
        row=row,
        fix="the file is truncated or damaged; re-export it from ControlDesk",
    )


def read_dspace(path: Path, mapping: Mapping) -> RawLog:
    """Read the channels ``mapping`` needs from a ControlDesk CSV export (see the module doc).

    Raises:
        DataError: no/unnamed traces, missing or ambiguous channel, truncated file, bad values.
    """
    import pyarrow.csv as pcsv

    data = read_export(path, memory_limit(mapping.options.max_memory_mb))
    traces, start, delim, size = parse_header(path, data, encoding=mapping.csv.encoding)
    if delim == mapping.csv.thousands:
        raise DataError(
            path,
            f"the export separates its fields by {delim!r}, the mapping's [csv] thousands mark",
            fix=f"remove [csv] thousands from {mapping.where} or set another mark",
        )
    if delim == mapping.csv.decimal:
        raise DataError(
            path,
            f"the export separates its fields by {delim!r}, the mapping's [csv] decimal mark",
            fix=f"remove [csv] decimal from {mapping.where}: this export's numbers have "
            "decimal points",
        )
    tm = mapping.time
    t_trace = traces[0]  # the x axis; [time] column may name it as in the plain CSV logs
    if tm.column is not None and any(str(tm.column) in t.aliases() for t in traces[1:]):
        t_trace = resolve(path, traces, str(tm.column), mapping)
    keys = [c.key for c in mapping.channels()]
    chosen = {k: resolve(path, traces, k, mapping) for k in keys}
    wanted = sorted({t_trace.index, *(t.index for t in chosen.values())})
    names = {i: f"f{i + 1}" for i in wanted}
    body = data[start:]

    def read(column_type: pa.DataType) -> pa.Table:
        return pcsv.read_csv(
            pa.BufferReader(body),
            read_options=pcsv.ReadOptions(autogenerate_column_names=True, block_size=1 << 22),
            parse_options=pcsv.ParseOptions(delimiter=delim),
            convert_options=pcsv.ConvertOptions(
                include_columns=list(names.values()),
                column_types=dict.fromkeys(names.values(), column_type),
                strings_can_be_null=True,
                decimal_point=mapping.csv.decimal,
            ),
        )

    try:
        table = read(pa.float64())
    except pa.ArrowInvalid as e:
        if "onversion error" not in str(e):
            raise _bad_row(path, body, delim, len(traces) + 1) or DataError(
                path,
                f"cannot parse the samples ({str(e).splitlines()[0]})",
                fix="re-export the measurement from ControlDesk",
            ) from e
        table = read(pa.string())  # a cell is not a number: numeric_column names it
    if size is not None and table.num_rows < size:
        raise DataError(
            path,
            f"{table.num_rows} sample rows, but trace_size says {size}: the file is truncated",
            fix="re-export the measurement from ControlDesk",
        )
    if table.num_rows == 0:
        raise DataError(path, "the export has no samples", fix="remove the file or record data")
    tlabel = str(tm.column) if tm.column is not None else t_trace.short
    tm = dataclasses.replace(tm, column=tlabel)
    if t_trace.index == 0:  # the x axis is in seconds; [time] unit is the plain logs' column's
        tm = dataclasses.replace(tm, unit="s", format=None)
    decimal = mapping.csv.decimal
    time_s, origin = parse_time(
        path,
        table.column(names[t_trace.index]),
        tm,
        decimal=decimal,
        thousands=mapping.csv.thousands,
    )
    values: dict[str, np.ndarray] = {
        k: numeric_column(
            path,
            table.column(names[t.index]),
            k,
            decimal=decimal,
            thousands=mapping.csv.thousands,
        )
        for k, t in chosen.items()
    }
    return RawLog(
        path=path,
        kind="dspace",
        series={
            TABLE: Series(
                TABLE,
                time_s,
                values,
                tlabel,
                units={k: t.unit for k, t in chosen.items() if t.unit},
            )
        },
        origin=origin,
        columns=[t.short for t in traces if t.short],
        meta=metadata(data[:start], encoding=mapping.csv.encoding),
    )


READER = Reader(
    "dspace",
    "dSPACE ControlDesk CSV (.dspace.csv[.gz], or by content)",
    SUFFIXES,
    is_dspace,
    read_dspace,
)
