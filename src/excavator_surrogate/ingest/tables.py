"""The table readers: CSV (plain or .gz) and Parquet, one :class:`~.sources.Series` per file
(``"table"``); their columns are converted by :mod:`.columns`.  Values are raw (no unit
conversion); missing cells are NaN; rows are counted from 0, header not counted.
"""

from __future__ import annotations

import csv as _csv
import gzip
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from ..errors import ConfigError, DataError
from .columns import is_number, numeric_column, parse_time
from .limits import TooBig, bounded_open, memory_limit, too_big
from .mapping import TABLE, CsvOptions, Mapping
from .sources import (
    CSV_SUFFIXES,
    PARQUET_SUFFIXES,
    RawLog,
    Reader,
    Series,
    first_ragged_row,
    has_suffix,
    missing_channel,
)

MAX_CSV_COLUMNS = 100_000
"""A CSV header with more columns than this is refused (no logger writes that many)."""
MAX_LINE_BYTES = 64 * 1024**2
"""A header or skipped line longer than this is refused."""


def csv_header(path: Path, opts: CsvOptions) -> list[str]:
    """The header's names, stripped. Only the header line is decoded (in an encoding whose
    line ends are ASCII's), so a stray byte in a column no mapping reads cannot stop it."""
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    try:
        if "\n".encode(opts.encoding) == b"\n":
            with opener(path, "rb") as fb:
                for _ in range(opts.skip_rows):
                    fb.readline(MAX_LINE_BYTES)
                raw = fb.readline(MAX_LINE_BYTES)
            line = raw.decode(opts.text_encoding)
            if "\r" in line.rstrip("\r\n"):  # a file whose lines end in \r alone
                line = line.split("\r", 1)[0] + "\n"
        else:  # UTF-16 and the like
            with opener(path, "rt", encoding=opts.text_encoding, newline="") as f:
                for _ in range(opts.skip_rows):
                    f.readline(MAX_LINE_BYTES)
                line = f.readline(MAX_LINE_BYTES)
    except (OSError, UnicodeDecodeError, EOFError) as e:
        fix = (
            'check that it is a UTF-8 CSV file (gzip if .gz), or set [csv] encoding (e.g. "cp1252" '
            "for a Windows export)"
            if opts.is_utf8
            else f"check that it is a {opts.encoding} CSV file (gzip if .gz), or set [csv] encoding"
        )
        if isinstance(e, UnicodeDecodeError) and bytes(e.object[:2]) in (b"\xff\xfe", b"\xfe\xff"):
            fix = 'the file is UTF-16 (it starts with its byte-order mark): set [csv] encoding = "utf-16"'
        raise DataError(path, f"cannot read the header ({type(e).__name__}: {e})", fix=fix) from e
    if not line.strip():
        raise DataError(
            path,
            "empty file or no header line",
            fix="the first line (after [csv] skip_rows) must hold the column names",
        )
    if len(line) >= MAX_LINE_BYTES and not line.endswith("\n"):
        raise DataError(
            path,
            f"the header (line {opts.skip_rows + 1}) is longer than {MAX_LINE_BYTES // 1024**2} MB",
            fix="the file is not a CSV log (or its line ends are not \\n); re-export it",
        )
    try:
        names = [c.strip() for c in next(_csv.reader([line], delimiter=opts.delimiter))]
    except _csv.Error as e:  # a name past the csv module's size limit
        raise DataError(
            path,
            f"cannot split the header (line {opts.skip_rows + 1}) into column names ({e})",
            fix="the file is not a CSV log or is damaged (e.g. NUL bytes left by a crash); "
            "re-export it",
        ) from None
    if len(names) > MAX_CSV_COLUMNS:
        raise DataError(
            path,
            f"the header (line {opts.skip_rows + 1}) has {len(names)} columns: too many "
            f"(more than {MAX_CSV_COLUMNS})",
            fix="export only the channels the mapping needs, or check [csv] delimiter",
        )
    return names


def ragged_row(path: Path, opts: CsvOptions, n_header: int) -> DataError | None:
    """The first data row whose field count differs from the header's, or that cannot be
    split into fields (:func:`~.sources.first_ragged_row`); streamed, bytes the encoding
    cannot decode replaced (only fields are counted)."""
    first_line = opts.skip_rows + 2 + opts.skip_rows_after_header  # of the first sample, from 1
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    try:
        with opener(path, "rt", encoding=opts.text_encoding, errors="replace", newline="") as f:
            for _ in range(opts.skip_rows + 1 + opts.skip_rows_after_header):
                f.readline()
            bad = first_ragged_row(f, opts.delimiter, n_header)
    except (OSError, EOFError):  # the caller reports the file's damage
        return None
    if bad is None:
        return None
    row, got = bad
    if isinstance(got, str):
        return DataError(
            path,
            f"line {first_line + row} of the file cannot be split into fields ({got})",
            row=row,
            fix="repair or cut the damaged line (a crash can leave a tail of NUL bytes)",
        )
    what = "too many" if got > n_header else "too few"
    return DataError(
        path,
        f"ragged rows: line {first_line + row} of the file has {got} fields, "
        f"the header {n_header} ({what})",
        row=row,
        fix="repair or cut the damaged line, or check [csv] delimiter",
    )


def _check_columns(path: Path, names: list[str], needed: list[str], mapping: Mapping) -> None:
    dup = [c for c in needed if names.count(c) > 1]
    if dup:
        raise DataError(
            path,
            "mapped column appears more than once in the header",
            column=dup[0],
            fix="rename one of the duplicates in the log, so the mapping is unambiguous",
        )
    for c in needed:
        if c not in names:
            delim = _other_delimiter(names, c, mapping.csv.delimiter)
            if delim is not None:
                raise DataError(
                    path,
                    f"column '{c}' is in the header, but separated by {delim!r}, "
                    f"not by {mapping.csv.delimiter!r}",
                    fix=f"set [csv] delimiter = {_toml_str(delim)} in {mapping.where}",
                )
            raise missing_channel(path, c, names, mapping, what="column")


def _other_delimiter(names: list[str], column: str, current: str) -> str | None:
    """The delimiter that makes ``column`` a field of the header ``names`` split by ``current``."""
    for d in (";", "\t", ",", "|", " "):
        if d != current and any(column in (x.strip() for x in n.split(d)) for n in names):
            return d
    return None


def _toml_str(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace("\t", "\\t").replace('"', '\\"') + '"'


def _read_table(path: Path, kind: str, mapping: Mapping) -> RawLog:
    tm = mapping.time
    if tm.column is None:
        if kind == "csv":  # a damaged file (a .csv.gz that is not gzip) is named as such
            csv_header(path, mapping.csv)
        raise ConfigError(
            f'{mapping.where}: time.column is required for CSV/Parquet logs (add [time] column = "...")'
        )
    tcol = str(tm.column)
    value_cols = [c.key for c in mapping.channels()]
    needed = [tcol, *[c for c in value_cols if c != tcol]]
    meta: dict[str, str] = {}
    if kind == "csv":
        if mapping.csv.thousands == mapping.csv.delimiter:
            raise ConfigError(
                f"{mapping.where}: [csv] thousands and delimiter are both "
                f"{mapping.csv.delimiter!r}: a mark that groups digits cannot also separate "
                "the fields"
            )
        if mapping.csv.decimal == mapping.csv.delimiter:
            raise ConfigError(
                f"{mapping.where}: [csv] decimal and delimiter are both "
                f"{mapping.csv.decimal!r}: a decimal mark cannot also separate the fields "
                '(a log with decimal commas is usually separated by ";": set [csv] delimiter)'
            )
        names = csv_header(path, mapping.csv)
        _check_columns(path, names, needed, mapping)
        table = _read_csv(path, mapping, needed, value_cols, names=names)
    else:
        table, names = _read_parquet(path, needed, mapping)
        meta = parquet_meta(table.schema.metadata)
    n = table.num_rows
    if n == 0:
        raise DataError(path, "the log has no data rows", fix="remove the file or record data")
    decimal = mapping.csv.decimal if kind == "csv" else "."
    thousands = mapping.csv.thousands if kind == "csv" else ""
    time_s, origin = parse_time(path, table.column(tcol), tm, decimal=decimal, thousands=thousands)
    values: dict[str, np.ndarray] = {}
    for c in value_cols:
        values[c] = numeric_column(path, table.column(c), c, decimal=decimal, thousands=thousands)
    return RawLog(
        path=path,
        kind=kind,
        series={TABLE: Series(TABLE, time_s, values, tcol)},
        origin=origin,
        columns=list(names),
        meta=meta,
    )


def parquet_meta(raw: dict[bytes, bytes] | None) -> dict[str, str]:
    """A Parquet file's key-value metadata as text (pandas/arrow schema blobs left out)."""
    skip = {"pandas", "ARROW:schema"}
    out = {}
    for k, v in (raw or {}).items():
        key = k.decode("utf-8", errors="replace")
        if key not in skip:
            out[key] = v.decode("utf-8", errors="replace")
    return out


def read_csv_body(
    path: Path, opts: CsvOptions, names: list[str], *, limit: int, convert: Any
) -> pa.Table:
    """The rows of a CSV log under the header's ``names`` (:func:`csv_header`'s), read as the
    ``[csv]`` options ``opts`` say (the lines before and after the header skipped, the
    encoding, the delimiter) and converted by ``convert`` (``pyarrow.csv.ConvertOptions``).

    Raises:
        DataError: a plain file larger than ``limit`` bytes, or a gzipped one that
            decompresses past it (counted while it streams).
    """
    import pyarrow.csv as pcsv

    gz = path.name.lower().endswith(".gz")
    if not gz and path.stat().st_size > limit:
        raise too_big(path, "reading the log", path.stat().st_size, limit)
    # a block must hold the header line (pyarrow: "cannot infer number of columns")
    block = max(1 << 22, 2 * sum(len(c.encode()) + 1 for c in names))
    # the header's names as csv_header read them, stripped: "t, boom_deg" names "boom_deg"
    read = pcsv.ReadOptions(
        skip_rows=opts.skip_rows + 1 + opts.skip_rows_after_header,
        column_names=names,
        block_size=block,
        **({} if opts.is_utf8 else {"encoding": opts.encoding}),
    )
    parse = pcsv.ParseOptions(delimiter=opts.delimiter)
    if not gz:  # its size was checked: read it natively
        return pcsv.read_csv(path, read_options=read, parse_options=parse, convert_options=convert)
    try:
        with bounded_open(path, limit) as src:  # decompressed while counting
            return pcsv.read_csv(
                src, read_options=read, parse_options=parse, convert_options=convert
            )
    except TooBig as e:
        raise too_big(path, "decompressing the log", e.n_read, limit, more=True) from None


def _read_csv(
    path: Path, mapping: Mapping, needed: list[str], value_cols: list[str], *, names: list[str]
) -> pa.Table:
    import pyarrow.csv as pcsv

    limit = memory_limit(mapping.options.max_memory_mb)
    types: dict[str, pa.DataType] = {c: pa.float64() for c in value_cols}
    tcol = str(mapping.time.column)
    if mapping.time.unit == "datetime":
        types[tcol] = pa.string()

    def go(column_types: dict[str, pa.DataType]) -> pa.Table:
        conv = pcsv.ConvertOptions(
            include_columns=needed,
            column_types=column_types,
            strings_can_be_null=True,
            decimal_point=mapping.csv.decimal,
        )
        return read_csv_body(path, mapping.csv, names, limit=limit, convert=conv)

    try:
        return go(types)
    except (pa.ArrowInvalid, pa.ArrowKeyError) as e:
        msg = str(e)
        if "conversion error" not in msg and "CSV conversion" not in msg:
            ragged = ragged_row(path, mapping.csv, len(names)) if "columns" in msg else None
            if ragged is not None:
                raise ragged from e
            if "Could not skip initial" in msg:  # pyarrow: the file ends in the skipped lines
                n = mapping.csv.skip_rows_after_header
                raise DataError(
                    path,
                    f"the log has no data rows: it ends within the {n} line(s) under the header "
                    "that [csv] skip_rows_after_header skips",
                    fix=f"remove the file or record data, or check skip_rows_after_header in "
                    f"{mapping.where}",
                ) from None
            raise DataError(
                path,
                f"cannot parse the CSV ({msg.splitlines()[0]})",
                fix="check the delimiter ([csv] delimiter) and that rows have as many fields as the header",
            ) from e
    except (OSError, EOFError, zlib.error) as e:
        raise DataError(
            path,
            f"cannot read the file ({type(e).__name__}: {e})",
            fix="the file may be truncated; re-export it",
        ) from e
    # slow path: a value is not a number, or the inferred time type changed mid-file (int ->
    # float); read the mapped columns as text, locate a bad cell, else convert the text
    text = go({c: pa.string() for c in needed})
    numeric = [c for c in needed if not (c == tcol and mapping.time.unit == "datetime")]
    for c in numeric:
        try:
            numeric_column(
                path,
                text.column(c),
                c,
                decimal=mapping.csv.decimal,
                thousands=mapping.csv.thousands,
            )
        except DataError as e:
            units = _units_row(text, numeric) if e.row == 0 else None
            if units is None:
                raise
            more = mapping.csv.skip_rows_after_header + 1
            raise DataError(
                path,
                f"no mapped column holds a number ({', '.join(units)}): a row of units "
                "under the header?",
                row=0,
                fix=f"set [csv] skip_rows_after_header = {more} in {mapping.where}",
            ) from None
    return text


def _units_row(text: pa.Table, columns: list[str]) -> list[str] | None:
    """Row 0's cells of ``columns`` if none is a number (with either decimal mark: a log with
    decimal commas read without ``[csv] decimal`` is not a units row) and one is text."""
    text_cells = [v for v in (text.column(c)[0].as_py() for c in columns) if v]
    if not text_cells or any(is_number(v, ".") or is_number(v, ",") for v in text_cells):
        return None
    return [repr(v) for v in text_cells[:4]] + (["..."] if len(text_cells) > 4 else [])


def open_parquet(path: Path) -> Any:
    """A raw Parquet log opened, not read (a ``pyarrow.parquet.ParquetFile``).

    Raises:
        DataError: a file pyarrow cannot open, or an exsur episode (not a raw log).
    """
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(path)
        schema = pf.schema_arrow
    except Exception as e:  # pyarrow raises several types for corrupt files
        raise DataError(
            path,
            f"not a readable Parquet file ({type(e).__name__})",
            fix="re-export the log as Parquet or CSV",
        ) from e
    if schema.metadata and b"exsur" in schema.metadata:
        raise DataError(
            path,
            "this is already an exsur episode, not a raw log",
            fix="put episodes in a dataset folder (exsur validate) instead of importing them",
        )
    return pf


def read_parquet(path: Path, pf: Any, columns: list[str], *, limit: int, what: str) -> pa.Table:
    """``columns`` of the opened log ``pf`` (:func:`open_parquet`).

    Raises:
        DataError: the columns take more than ``limit`` bytes uncompressed (``what``: the
            reading, for the message), or their data is corrupt.
    """
    meta = pf.metadata
    cols = [i for i in range(meta.num_columns) if meta.schema.column(i).name in columns]
    size = sum(
        meta.row_group(g).column(i).total_uncompressed_size
        for g in range(meta.num_row_groups)
        for i in cols
    )
    if size > limit:
        raise too_big(path, what, size, limit)
    try:
        return pf.read(columns=columns)
    except Exception as e:
        raise DataError(
            path,
            f"cannot read Parquet data ({type(e).__name__}: {e})",
            fix="the file is corrupt; re-export it",
        ) from e


def _read_parquet(path: Path, needed: list[str], mapping: Mapping) -> tuple[pa.Table, list[str]]:
    pf = open_parquet(path)
    names = list(pf.schema_arrow.names)
    _check_columns(path, names, needed, mapping)
    limit = memory_limit(mapping.options.max_memory_mb)
    return read_parquet(path, pf, needed, limit=limit, what="reading the mapped columns"), names


# --------------------------------------------------------------------------------------
# the formats read here (the registry is excavator_surrogate.ingest.readers.READERS)

TABLE_READERS: tuple[Reader, ...] = (
    Reader(
        "csv",
        "CSV (.csv, .csv.gz)",
        CSV_SUFFIXES[::-1],
        has_suffix(*CSV_SUFFIXES),
        lambda path, mapping: _read_table(path, "csv", mapping),
    ),
    Reader(
        "parquet",
        "Parquet (.parquet)",
        PARQUET_SUFFIXES,
        has_suffix(*PARQUET_SUFFIXES),
        lambda path, mapping: _read_table(path, "parquet", mapping),
    ),
)
"""The table formats (CSV, Parquet); :mod:`.readers` lists every format."""
