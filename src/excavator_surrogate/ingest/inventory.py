"""What a raw log holds, before any mapping: its channels, units, rates and ranges.

A mapping names the log's channels and their units.  For a binary log (MDF, Parquet, a ROS
bag) the names are not readable with a text editor, and the ranges are what tell degrees
from radians and percent from raw counts.  :func:`summarize_log` reads every channel of one
log (``exsur info LOG`` prints it):

- **CSV** (plain): the header's names (the delimiter sniffed among ``, ; tab |``), and per
  column its number range; a column of decimal commas is read as numbers and says so.
- **dSPACE ControlDesk exports**: the traces' names (what a mapping gives) and paths, the
  x axis as the time base.
- **Parquet** (a raw table, not an exsur episode): the columns, their ranges and the file's
  key-value metadata.
- **ASAM MDF** (4 and 3): every channel of every channel group with its unit, samples, rate
  (from the group's master) and range, and the header's properties.
- **ROS** (rosbag2, MCAP, ROS 1): per topic its message type, count and rate, and every
  numeric field path of its messages (``position[1]``, ``pose.position.x``) with the range
  over its first messages (:mod:`.inventory_ros`).

Nothing is converted or resampled: the values are the log's raw ones.
"""

from __future__ import annotations

import csv as csv_module
import dataclasses
import gzip
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import DataError
from .columns import numeric_column
from .limits import memory_limit
from .options import CsvOptions
from .readers import reader_for
from .summary import ChannelSummary, LogSummary, sample_rate, value_range


def summarize_log(
    path: str | Path, *, csv: CsvOptions | None = None, max_memory_mb: float | None = None
) -> LogSummary:
    """Every channel of the raw log at ``path`` (see the module doc).

    Args:
        path: a log file (or a rosbag2 folder) that ``exsur import`` reads.
        csv: how to read a CSV log or a dSPACE export (a mapping's ``[csv]``: preamble lines,
            a units row, the encoding, the marks); None: a plain CSV's delimiter is sniffed
            among ``, ; tab |`` and decimal commas are recognised.
        max_memory_mb: the most a table may take in memory (default: a share of the free
            memory, as the import's).

    Raises:
        DataError: not a log exsur reads, or a damaged one (one line naming the file).
        ConfigError: the optional reader package (asammdf, rosbags) is missing.
    """
    path = Path(path)
    reader = reader_for(path, csv_format=csv.format if csv is not None else "auto")
    if reader is None:
        raise DataError(path, "not a log exsur imports", fix="give a CSV, Parquet, MDF or ROS log")
    limit = memory_limit(max_memory_mb)
    kind = reader.kind
    if kind == "csv":
        channels, notes = _csv_table(path, limit, csv)
        return LogSummary(path, kind, reader.label, channels, notes=notes)
    if kind == "dspace":
        return _dspace(path, limit, reader.label, csv or CsvOptions())
    if kind == "parquet":
        return _parquet(path, limit, reader.label)
    if kind == "mdf":
        return _mdf(path, reader.label)
    from .inventory_ros import summarize_ros

    if reader.whole_folder and not path.is_dir():  # a storage file stands for its bag folder
        path = path.parent
    return summarize_ros(path, kind, reader.label)


def _column(
    name: str, col: pa.ChunkedArray, *, csv: CsvOptions | None = None, **kw: Any
) -> ChannelSummary:
    """A table column's summary: numbers, text read as numbers with ``csv``'s marks as
    :func:`~.columns.numeric_column` reads them (None: with decimal commas, said in the
    note), or text."""
    t = col.type
    if pa.types.is_floating(t) or pa.types.is_integer(t) or pa.types.is_boolean(t):
        vals = np.asarray(pc.cast(col, pa.float64()).to_numpy(zero_copy_only=False), np.float64)
        lo, hi, miss = value_range(vals)
        return ChannelSummary(name, n_sample=len(col), lo=lo, hi=hi, n_missing=miss, **kw)
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        # read as the import reads a text column, with the [csv] marks (without them: as
        # decimal commas, the one mark pyarrow's own parse leaves as text)
        marks = (
            {"decimal": ","}
            if csv is None
            else {"decimal": csv.decimal, "thousands": csv.thousands}
        )
        try:
            arr = numeric_column(Path(name), col, name, **marks)
        except DataError:
            first = next((v for v in col.to_pylist() if v), "")
            first = first if len(first) <= 24 else first[:21] + "..."
            return ChannelSummary(
                name,
                n_sample=len(col),
                n_missing=col.null_count,
                note=f"text, e.g. {first!r}",
                **kw,
            )
        lo, hi, miss = value_range(arr)
        return ChannelSummary(
            name,
            n_sample=len(col),
            lo=lo,
            hi=hi,
            n_missing=miss,
            note='decimal commas: [csv] decimal = ","' if csv is None else "",
            **kw,
        )
    return ChannelSummary(name, n_sample=len(col), note=str(t), **kw)


# ---- tables -----------------------------------------------------------------------------------


def _sniff(path: Path) -> str:
    """The delimiter of a CSV file's header line among ``, ; tab |`` (default ``,``)."""
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    try:
        with opener(path, "rt", encoding="utf-8", errors="replace", newline="") as f:
            head = f.read(8192)
        return csv_module.Sniffer().sniff(head.split("\n", 1)[0], delimiters=",;\t|").delimiter
    except (OSError, EOFError, csv_module.Error):
        return ","


def _csv_table(
    path: Path, limit: int, opts: CsvOptions | None
) -> tuple[list[ChannelSummary], list[str]]:
    import pyarrow.csv as pcsv

    from .tables import csv_header, ragged_row, read_csv_body

    given = opts is not None
    if opts is None:
        opts = CsvOptions(delimiter=_sniff(path))
    delim = opts.delimiter
    names = csv_header(path, opts)
    convert = pcsv.ConvertOptions(
        strings_can_be_null=True,
        decimal_point=opts.decimal,
        column_types=dict.fromkeys(names, pa.string()) if opts.thousands else None,
    )
    try:
        table = read_csv_body(path, opts, names, limit=limit, convert=convert)
    except (pa.ArrowInvalid, OSError, EOFError, zlib.error) as e:
        ragged = ragged_row(path, opts, len(names))
        if ragged is not None and not given and ragged.problem.endswith("(too many)"):
            # more fields below the header than in it: lines of a logger's preamble?
            raise DataError(
                path,
                ragged.problem,
                row=ragged.row,
                fix="lines before the header? skip them with --set csv.skip_rows=N, as "
                "[csv] skip_rows does in a mapping",
            ) from e
        if ragged is not None:
            raise ragged from e
        raise DataError(
            path,
            f"cannot parse the CSV ({str(e).splitlines()[0]})",
            fix="check that rows have as many fields as the header"
            + ("" if given else "; lines before it? skip them with --set csv.skip_rows=N"),
        ) from e
    notes = [] if given or delim == "," else [f"fields separated by {delim!r}: set [csv] delimiter"]
    if any(n == "" for n in names):
        notes.append("a column without a name: a mapping cannot read it")
    cols = [_column(n, table.column(i), csv=opts if given else None) for i, n in enumerate(names)]
    return cols, notes


def _dspace(path: Path, limit: int, label: str, opts: CsvOptions) -> LogSummary:
    import pyarrow.csv as pcsv

    from .dspace import metadata, parse_header, read_export

    data = read_export(path, limit)
    traces, start, delim, _ = parse_header(path, data, encoding=opts.encoding)
    try:
        table = pcsv.read_csv(
            pa.BufferReader(data[start:]),
            read_options=pcsv.ReadOptions(autogenerate_column_names=True),
            parse_options=pcsv.ParseOptions(delimiter=delim),
            convert_options=pcsv.ConvertOptions(
                strings_can_be_null=True, decimal_point=opts.decimal
            ),
        )
    except pa.ArrowInvalid as e:
        raise DataError(
            path,
            f"cannot parse the samples ({str(e).splitlines()[0]})",
            fix="re-export the measurement from ControlDesk",
        ) from e
    t = table.column(1) if table.num_columns > 1 else None  # cell 0 is the row label
    numeric = t is not None and (pa.types.is_floating(t.type) or pa.types.is_integer(t.type))
    t_s = np.asarray(pc.cast(t, pa.float64()).to_numpy(zero_copy_only=False)) if numeric else None
    rate = None if t_s is None else sample_rate(t_s)
    out = []
    for tr in traces:
        col = tr.index + 1
        if col >= table.num_columns:
            continue
        note = "time base (the x axis)" if tr.index == 0 else ""
        s = _column(
            tr.short, table.column(col), csv=opts, group=tr.path, unit=tr.unit, rate_hz=rate
        )
        out.append(dataclasses.replace(s, note=", ".join(x for x in (note, s.note) if x)))
    duration = None if t_s is None or not len(t_s) else float(np.nanmax(t_s) - np.nanmin(t_s))
    meta = metadata(data, encoding=opts.encoding)
    return LogSummary(path, "dspace", label, out, duration_s=duration, meta=meta)


def _parquet(path: Path, limit: int, label: str) -> LogSummary:
    from .tables import open_parquet, parquet_meta, read_parquet

    pf = open_parquet(path)
    names = list(pf.schema_arrow.names)
    table = read_parquet(path, pf, names, limit=limit, what="reading the table")
    channels = [_column(n, table.column(n)) for n in table.column_names]
    return LogSummary(path, "parquet", label, channels, meta=parquet_meta(pf.schema_arrow.metadata))


# ---- MDF ----------------------------------------------------------------------------------------


def _mdf(path: Path, label: str) -> LogSummary:
    from .mdf import header_metadata, numeric_samples, open_mdf, read_signal

    with open_mdf(path) as mdf:
        channels, spans = [], []
        for g, grp in enumerate(mdf.groups):
            master = mdf.masters_db.get(g)
            comment = str(getattr(grp.channel_group, "comment", "") or "").strip()
            where = f"group {g}" + (f" ({comment:.40})" if comment else "")
            for i, ch in enumerate(grp.channels):
                if i == master:
                    continue
                # samples flagged invalid count as missing, as the import reads them
                sig = read_signal(path, mdf, g, i, name=ch.name)
                t = np.asarray(sig.timestamps, dtype=np.float64)
                if t.size:
                    spans.append((float(t[0]), float(t[-1])))
                samples = numeric_samples(sig)
                kw = dict(group=where, unit=str(sig.unit or ""), rate_hz=sample_rate(t))
                if samples is not None:
                    lo, hi, miss = value_range(samples)
                    channels.append(
                        ChannelSummary(ch.name, n_sample=t.size, lo=lo, hi=hi, n_missing=miss, **kw)
                    )
                else:
                    channels.append(
                        ChannelSummary(ch.name, n_sample=t.size, note="not numbers", **kw)
                    )
        start = mdf.header.start_time.isoformat()
        meta = header_metadata(mdf.header)
    names = [c.name for c in channels]
    twice = sorted({n for n in names if names.count(n) > 1})
    notes = (
        [
            f"{', '.join(twice[:5])} in several channel groups: a mapping names them "
            "<source path>.<name> (asammdf's convention)"
        ]
        if twice
        else []
    )
    duration = max(b for _, b in spans) - min(a for a, _ in spans) if spans else None
    return LogSummary(
        path, "mdf", label, channels, start=start, duration_s=duration, meta=meta, notes=notes
    )
