"""CSV dialects: a space after each delimiter, and ``[csv] decimal`` and ``encoding`` for logs
written with a European locale (``;`` between fields, ``1,25``, a Windows code page), as a
German spreadsheet saves them."""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import DataError
from excavator_surrogate.ingest import parse_mapping
from excavator_surrogate.ingest.columns import numeric_column
from tests.helpers import arm3_plant
from tests.helpers.ingest import assert_nothing_written, write_lines
from tests.ingest.test_ingest_dspace import dspace_mapping_toml, dspace_traces, write_dspace

LOCALE = '[csv]\ndelimiter = ";"\ndecimal = ","\n'


def _european(lines: list[str]) -> list[str]:
    """The log as a German spreadsheet writes it: fields by ``;``, decimals by ``,``."""
    return [x.replace(",", ";").replace(".", ",") for x in lines]


def _import(cli, log: Path, mapping: Path, out: Path) -> tuple[int, str]:
    rc, _, err = cli("import", log, "--mapping", mapping, "--out", out, "--quiet")
    return rc, err


def _fail(cli, log: Path, mapping: Path, out: Path) -> str:
    rc, err = _import(cli, log, mapping, out)
    assert rc == 2, err
    assert err.startswith("exsur: error: ") and err.count("\n") == 1, err
    assert_nothing_written(out)
    return err


def _mapping(work: Path, name: str, extra: str = "", *, time: str | None = None) -> Path:
    """The test arm's mapping with ``extra`` appended and ``[time] unit = "ms"`` replaced by
    ``time``, written to ``work / name``."""
    text = (work / "arm3.toml").read_text()
    if time is not None:
        text = text.replace('unit = "ms"', time)
    (work / name).write_text(text + extra)
    return work / name


def _same(cli, a: tuple[Path, Path], b: tuple[Path, Path], out: Path, *, atol: float = 0.0):
    """Logs ``a`` and ``b`` (each with its mapping) import to the same episodes (to ``atol``)."""
    assert _import(cli, *a, out / "A") == (0, "")
    assert _import(cli, *b, out / "B") == (0, "")
    ref, got = load_dataset(out / "A"), load_dataset(out / "B")
    assert ref.n_samples() == got.n_samples() > 0
    for split, eps in ref.episodes.items():
        for x, y in zip(eps, got.split(split), strict=True):
            for f in ("time", "theta", "omega", "u"):
                np.testing.assert_allclose(getattr(x, f), getattr(y, f), rtol=0, atol=atol)


def _same_as_plain(cli, work: Path, cols, log: Path, mapping: Path, *, atol: float = 0.0):
    """``log`` imports with ``mapping`` to the episodes of the plain log of ``cols``."""
    plain = write_lines(work / "plain.csv", cols)
    _same(cli, (plain, work / "arm3.toml"), (log, mapping), work / "out", atol=atol)


def test_a_decimal_comma_log_imports_as_the_plain_one(cli, work, short_cols) -> None:
    euro = write_lines(work / "euro.csv", short_cols, _european)
    assert "." not in euro.read_text()
    _same_as_plain(cli, work, short_cols, euro, _mapping(work, "euro.toml", LOCALE))


@pytest.mark.parametrize("locale", [False, True], ids=["comma", "semicolon-decimal-comma"])
def test_a_space_after_each_delimiter_imports_as_the_plain_log(
    cli, work, short_cols, locale
) -> None:
    """``t_ms, boom_deg, ...`` (numpy.savetxt's ``", "``, a hand-made log): the header's names
    are stripped and so are the numbers."""

    def spaced(lines: list[str]) -> list[str]:
        lines = _european(lines) if locale else lines
        sep = ";" if locale else ","
        return [x.replace(sep, sep + " ") for x in lines]

    log = write_lines(work / "spaced.csv", short_cols, spaced)
    assert ", " in log.read_text() or "; " in log.read_text()
    mapping = _mapping(work, "m.toml", LOCALE if locale else "")
    _same_as_plain(cli, work, short_cols, log, mapping)


def test_decimal_commas_without_the_option_name_the_fix(cli, work, short_cols) -> None:
    euro = write_lines(work / "a.csv", short_cols, _european)
    err = _fail(cli, euro, _mapping(work, "semi.toml", '[csv]\ndelimiter = ";"\n'), work / "X")
    assert f"{euro}, column 't_ms', row 0: non-numeric value '0,000'" in err
    assert 'decimal commas: set [csv] decimal = "," in the mapping' in err


def test_a_first_row_of_decimal_commas_is_not_taken_for_units(cli, work, short_cols) -> None:
    """Row 0 without an integer cell (``0,000;10,0058;0,55;...``): no number with a decimal
    point anywhere, yet the fix is the decimal mark, not a units row."""

    def edit(lines: list[str]) -> list[str]:
        lines = _european(lines)
        lines[1] = ";".join(x if "," in x else x + ",5" for x in lines[1].split(";"))
        return lines

    log = write_lines(work / "a.csv", short_cols, edit)
    err = _fail(cli, log, _mapping(work, "semi.toml", '[csv]\ndelimiter = ";"\n'), work / "X")
    assert all("," in x for x in log.read_text().splitlines()[1].split(";"))
    assert f"{log}, column 't_ms', row 0: non-numeric value '0,000'" in err
    assert 'decimal commas: set [csv] decimal = ","' in err


def test_one_bad_cell_of_a_decimal_comma_log_is_named(cli, work, short_cols) -> None:
    def edit(lines: list[str]) -> list[str]:
        lines = _european(lines)
        cells = lines[301].split(";")
        cells[arm3_plant.LOG_COLUMNS.index("arm_deg")] = "1.234,5"  # a thousands separator
        lines[301] = ";".join(cells)
        return lines

    log = write_lines(work / "a.csv", short_cols, edit)
    err = _fail(cli, log, _mapping(work, "euro.toml", LOCALE), work / "X")
    assert f"{log}, column 'arm_deg', row 300: non-numeric value '1.234,5'" in err
    assert """the log groups thousands with '.': set [csv] thousands = "." in the mapping""" in err


def _grouped(dec: str, th: str, sep: str) -> Callable[[list[str]], list[str]]:
    """The log with the integer digits of every number grouped in threes by ``th``, the
    decimal mark ``dec`` and fields split by ``sep`` (the header keeps its names)."""

    def cell(x: str) -> str:
        sign, body = ("-", x[1:]) if x.startswith("-") else ("", x)
        whole, _, frac = body.partition(".")
        if not whole.isdigit():
            return x
        groups = []
        while len(whole) > 3:
            whole, groups = whole[:-3], [whole[-3:], *groups]
        return sign + th.join([whole, *groups]) + (dec + frac if frac else "")

    def edit(lines: list[str]) -> list[str]:
        return [lines[0].replace(",", sep)] + [
            sep.join(cell(x) for x in line.split(",")) for line in lines[1:]
        ]

    return edit


@pytest.mark.parametrize(
    ("dec", "th", "sep"),
    [(",", ".", ";"), (".", ",", ";"), (",", " ", ";"), (".", "'", ",")],
    ids=["de", "en", "fr", "ch"],
)
def test_a_log_with_thousands_separators_imports_as_the_plain_one(
    cli, work, short_cols, dec, th, sep
) -> None:
    """``-1.000,5`` (German Excel with separators), ``1,000.5``, ``1 000,5``, ``1'000.5``:
    with ``[csv] thousands`` (and ``decimal``) the same episodes as the plain log, bit for
    bit, time column included; without it, the first such cell names the setting."""
    log = write_lines(work / "grouped.csv", short_cols, _grouped(dec, th, sep))
    assert f"1{th}0" in log.read_text()  # milliseconds past 1 s are grouped
    extra = f'[csv]\ndelimiter = "{sep}"\ndecimal = "{dec}"\nthousands = "{th}"\n'
    _same_as_plain(cli, work, short_cols, log, _mapping(work, "grouped.toml", extra))
    bare = _mapping(work, "bare.toml", f'[csv]\ndelimiter = "{sep}"\ndecimal = "{dec}"\n')
    err = _fail(cli, log, bare, work / "X")
    assert f"""set [csv] thousands = "{th}" in the mapping""" in err


def test_each_error_names_the_next_setting_a_grouped_log_needs() -> None:
    """A cell that one setting would read names it, the decimal mark first (``0,5``), then a
    grouping of threes; a cell no setting reads gets the general advice."""
    from excavator_surrogate.ingest.columns import _number_fix

    assert (
        _number_fix("0,5", ".")
        == 'the log writes decimal commas: set [csv] decimal = "," in the mapping'
    )
    assert _number_fix("-1.234,5", ".").endswith(
        """with '.': set [csv] decimal = "," and thousands = "." in the mapping"""
    )
    assert _number_fix("1,234,567.5", ".").endswith("""set [csv] thousands = "," in the mapping""")
    assert _number_fix("12 345,5", ",").endswith("""set [csv] thousands = " " in the mapping""")
    for cell in ("1.23,4", "abc", "1.2.3"):  # not a grouping of threes
        assert _number_fix(cell, ",").startswith("replace it with a number")


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (
            '[csv]\ndecimal = ","\nthousands = ","\ndelimiter = ";"\n',
            "thousands and decimal are both ','",
        ),
        ('[csv]\nthousands = ","\n', "thousands and delimiter are both ','"),
        ('[csv]\nthousands = "_"\n', "thousands"),
    ],
    ids=["as-decimal", "as-delimiter", "unknown-mark"],
)
def test_a_thousands_mark_that_cannot_work_is_a_config_error(
    cli, work, short_cols, extra, match
) -> None:
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, log, _mapping(work, "bad.toml", extra), work / "X")
    assert match in err


def test_decimal_and_delimiter_alike_is_a_config_error(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, log, _mapping(work, "same.toml", '[csv]\ndecimal = ","\n'), work / "X")
    assert "same.toml: [csv] decimal and delimiter are both ','" in err


def test_a_decimal_comma_dspace_export_imports_as_the_plain_one(cli, tmp_path, short_cols) -> None:
    traces = dspace_traces(short_cols)
    plain = write_dspace(tmp_path / "p" / "run.dspace.csv", traces)
    euro = tmp_path / "e" / "run.dspace.csv"
    euro.parent.mkdir()
    head, sep, body = plain.read_bytes().partition(b"trace_values")
    euro.write_bytes(head.replace(b",", b";") + sep + body.replace(b",", b";").replace(b".", b","))
    text = dspace_mapping_toml()
    (tmp_path / "p.toml").write_text(text)
    (tmp_path / "e.toml").write_text(text + '[csv]\ndecimal = ","\n')
    err = _fail(cli, plain, tmp_path / "e.toml", tmp_path / "X")
    assert f"{plain}: the export separates its fields by ','" in err
    assert "remove [csv] decimal from" in err
    _same(cli, (plain, tmp_path / "p.toml"), (euro, tmp_path / "e.toml"), tmp_path)


def test_numeric_column_reads_either_mark() -> None:
    col = pa.array(["1,5", None, "-2,25e-1", "3"])
    np.testing.assert_array_equal(
        numeric_column(Path("x.csv"), col, "c", decimal=","), [1.5, np.nan, -0.225, 3.0]
    )
    with pytest.raises(DataError, match=r"row 0: non-numeric value '1,5'.*decimal commas"):
        numeric_column(Path("x.csv"), col, "c")
    with pytest.raises(DataError, match=r"row 1: non-numeric value '2.5'.*writes decimal points"):
        numeric_column(Path("x.csv"), pa.array(["1,5", "2.5"]), "c", decimal=",")


def test_the_options_round_trip_through_the_mapping() -> None:
    m = parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML + LOCALE + 'encoding = "CP1252"\n'))
    assert (m.csv.delimiter, m.csv.decimal, m.csv.encoding) == (";", ",", "CP1252")
    assert not m.csv.is_utf8 and m.csv.text_encoding == "CP1252"
    default = parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML)).csv
    assert (default.decimal, default.is_utf8, default.text_encoding) == (".", True, "utf-8-sig")


def _excel(work: Path, cols: dict[str, np.ndarray]) -> tuple[Path, Path]:
    """The log as a German Excel saves "CSV (Trennzeichen-getrennt)": ``;``, ``1,25`` and
    cp1252 (the boom's column named ``Ausleger_°``); and its mapping without ``[csv]``."""
    text = write_lines(work / "tmp.csv", cols, _european).read_text()
    log = work / "excel.csv"
    log.write_bytes(text.replace("boom_deg", "Ausleger_°").encode("cp1252"))
    mapping = work / "excel.toml"
    mapping.write_text((work / "arm3.toml").read_text().replace("boom_deg", "Ausleger_°"))
    return log, mapping


def test_a_windows_excel_export_imports_as_the_plain_one(cli, work, short_cols) -> None:
    log, mapping = _excel(work, short_cols)
    err = _fail(cli, log, mapping, work / "X")
    assert f"{log}: cannot read the header (UnicodeDecodeError" in err
    assert 'set [csv] encoding (e.g. "cp1252" for a Windows export)' in err
    mapping.write_text(mapping.read_text() + LOCALE + 'encoding = "cp1252"\n')
    _same_as_plain(cli, work, short_cols, log, mapping)


def test_an_unknown_encoding_is_a_config_error(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, log, _mapping(work, "enc.toml", '[csv]\nencoding = "cp9999"\n'), work / "X")
    assert "enc.toml: " in err and "[csv] encoding 'cp9999' is not a known text encoding" in err


def test_a_dspace_export_in_a_code_page_names_its_traces(cli, tmp_path, short_cols) -> None:
    traces = [
        (name, path.replace("boom_deg", "Auslegerwinkel_°"), values)
        for name, path, values in dspace_traces(short_cols)
    ]
    plain = write_dspace(tmp_path / "p" / "run.dspace.csv", dspace_traces(short_cols))
    coded = tmp_path / "e" / "run.dspace.csv"
    coded.parent.mkdir()
    blob = write_dspace(tmp_path / "u" / "run.dspace.csv", traces, preamble=False).read_bytes()
    coded.write_bytes(blob.decode("utf-8").encode("cp1252"))
    text = dspace_mapping_toml()
    (tmp_path / "p.toml").write_text(text)
    coded_map = text.replace('"boom_deg"', '"Auslegerwinkel_°"') + '[csv]\nencoding = "cp1252"\n'
    (tmp_path / "e.toml").write_text(coded_map)
    _same(cli, (plain, tmp_path / "p.toml"), (coded, tmp_path / "e.toml"), tmp_path)


def test_a_units_row_is_named_and_skipped(cli, work, short_cols) -> None:
    units = ",".join(
        "ms" if c == "t_ms" else "deg" if "deg" in c else "%" for c in arm3_plant.LOG_COLUMNS
    )
    log = write_lines(work / "u.csv", short_cols, lambda ls: [ls[0], units, *ls[1:]])
    err = _fail(cli, log, work / "arm3.toml", work / "X")
    assert f"{log}, row 0: no mapped column holds a number ('ms', 'deg', '%', '%', ...)" in err
    assert "a row of units under the header? (set [csv] skip_rows_after_header = 1 in" in err
    mapping = _mapping(work, "units.toml", "[csv]\nskip_rows_after_header = 1\n")
    _same_as_plain(cli, work, short_cols, log, mapping)


def test_a_ragged_row_after_a_units_row_names_its_line(cli, work, short_cols) -> None:
    units = ",".join("u" for _ in arm3_plant.LOG_COLUMNS)
    log = write_lines(
        work / "u.csv", short_cols, lambda ls: [ls[0], units, *ls[1:40], ls[40] + ",9", *ls[41:]]
    )
    mapping = _mapping(work, "units.toml", "[csv]\nskip_rows_after_header = 1\n")
    err = _fail(cli, log, mapping, work / "X")
    assert "row 39: ragged rows: line 42 of the file has" in err  # header 1, units 2, row 0 on 3


def test_a_stray_byte_in_an_unmapped_column_does_not_stop_the_import(cli, work, short_cols) -> None:
    """A comment column in a code page ("Prüfung") that no mapping reads: only the header is decoded."""
    text = write_lines(work / "tmp.csv", short_cols).read_text().splitlines()
    log = work / "note.csv"
    lines = [text[0] + ",note"] + [x + ",Prüfung" for x in text[1:]]
    log.write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    _same_as_plain(cli, work, short_cols, log, work / "arm3.toml")


def test_a_utf16_log_is_named_and_read(cli, work, short_cols) -> None:
    text = write_lines(work / "tmp.csv", short_cols).read_text()
    log = work / "wide.csv"
    log.write_bytes(text.encode("utf-16"))
    err = _fail(cli, log, work / "arm3.toml", work / "X")
    assert (
        'the file is UTF-16 (it starts with its byte-order mark): set [csv] encoding = "utf-16"'
        in err
    )
    mapping = _mapping(work, "utf16.toml", '[csv]\nencoding = "utf-16"\n')
    _same_as_plain(cli, work, short_cols, log, mapping)


def test_a_negative_skip_is_a_config_error(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols)
    mapping = _mapping(work, "neg.toml", "[csv]\nskip_rows_after_header = -1\n")
    err = _fail(cli, log, mapping, work / "X")
    assert "neg.toml: [csv] skip_rows_after_header must be >= 0, got -1" in err


def _dated(cols, fmt: str) -> Callable[[list[str]], list[str]]:
    """The log's ``t_ms`` written as date-time text of ``strftime`` format ``fmt``."""
    t0 = datetime(2024, 5, 1, 23, 59, 55)

    def edit(lines: list[str]) -> list[str]:
        out = [lines[0]]
        for x in lines[1:]:
            ms, rest = x.split(",", 1)
            stamp = (t0 + timedelta(milliseconds=float(ms))).strftime(fmt)  # %f: 6 digits, exact
            out.append(f'"{stamp}",{rest}' if "," in stamp else f"{stamp},{rest}")
        return out

    return edit


@pytest.mark.parametrize(
    "fmt", ["%d.%m.%Y %H:%M:%S.%f", "%d/%m/%Y %H:%M:%S,%f"], ids=["german", "comma-seconds"]
)
def test_a_strptime_format_reads_a_logger_date(cli, work, short_cols, fmt) -> None:
    """A date the logger writes its own way, across midnight: the same episodes as ``t_ms``."""
    log = write_lines(work / "d.csv", short_cols, _dated(short_cols, fmt))
    assert "02.05.2024" in log.read_text() or "02/05/2024" in log.read_text()
    err = _fail(cli, log, _mapping(work, "iso.toml", time='unit = "datetime"'), work / "X")
    assert "column 't_ms', row 0: time value '01" in err and "is not an ISO-8601 date-time" in err
    assert 'a strptime format in the mapping, e.g. [time] format = "%d.%m.%Y %H:%M:%S.%f"' in err
    mapping = _mapping(work, "fmt.toml", time=f'unit = "datetime"\nformat = "{fmt}"')
    _same_as_plain(cli, work, short_cols, log, mapping, atol=1e-9)


def test_a_time_that_misses_the_format_is_named(cli, work, short_cols) -> None:
    def edit(lines: list[str]) -> list[str]:
        lines = _dated(short_cols, "%d.%m.%Y %H:%M:%S.%f")(lines)
        lines[101] = "2024-05-01 " + lines[101].split(" ", 1)[1]
        return lines

    log = write_lines(work / "d.csv", short_cols, edit)
    mapping = _mapping(work, "fmt.toml", time='unit = "datetime"\nformat = "%d.%m.%Y %H:%M:%S.%f"')
    err = _fail(cli, log, mapping, work / "X")
    assert "column 't_ms', row 100: time value '2024-05-01 " in err
    assert "does not match [time] format '%d.%m.%Y %H:%M:%S.%f'" in err


@pytest.mark.parametrize(
    ("time", "message"),
    [
        (
            'unit = "ms"\nformat = "%H:%M:%S"',
            '[time] format is for date-time text: set unit = "datetime"',
        ),
        ('unit = "datetime"\nformat = "H:M:S"', "[time] format 'H:M:S' has no % directive"),
    ],
)
def test_a_format_that_cannot_apply_is_a_config_error(cli, work, short_cols, time, message) -> None:
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, log, _mapping(work, "bad.toml", time=time), work / "X")
    assert f"bad.toml: {message}" in err


def test_a_time_of_day_across_midnight_is_refused(cli, work, short_cols) -> None:
    """``%H:%M:%S.%f`` has no date: the log starts at 23:59:55, so 5 s in it runs backwards."""
    log = write_lines(work / "d.csv", short_cols, _dated(short_cols, "%H:%M:%S.%f"))
    mapping = _mapping(work, "tod.toml", time='unit = "datetime"\nformat = "%H:%M:%S.%f"')
    err = _fail(cli, log, mapping, work / "X")
    assert "column 't_ms', row 501: time goes backwards (4.999567 s -> -86394.989077 s)" in err


def test_a_log_with_old_mac_line_ends_imports_as_the_plain_one(cli, work, short_cols) -> None:
    """Lines ending in ``\\r`` alone: the header is cut at the first one."""
    log = write_lines(work / "cr.csv", short_cols)
    log.write_bytes(log.read_bytes().replace(b"\n", b"\r"))
    _same_as_plain(cli, work, short_cols, log, work / "arm3.toml")


def test_a_utf16_log_with_a_preamble_line(cli, work, short_cols) -> None:
    text = write_lines(work / "tmp.csv", short_cols).read_text()
    log = work / "wide.csv"
    log.write_bytes(("exported by rig 2\n" + text).encode("utf-16"))
    mapping = _mapping(work, "utf16.toml", '[csv]\nencoding = "utf-16"\nskip_rows = 1\n')
    _same_as_plain(cli, work, short_cols, log, mapping)


def test_a_value_column_with_thousands_separators(cli, work, short_cols) -> None:
    """An engine speed of ``1.850,5`` rpm is read with ``[csv] thousands`` (the columns are
    read as text, then converted) as the plain log's ``1850.5``."""
    cols = {**short_cols, "rpm": 1000.0 + 5.0 * np.round(np.arange(short_cols["t_ms"].size) / 7)}
    columns = (*arm3_plant.LOG_COLUMNS, "rpm")
    inputs = '[[inputs]]\nname = "engine_rpm"\ncolumn = "rpm"\nunit = "physical"\n'
    inputs += "range = [800.0, 2200.0]\n"
    plain = write_lines(work / "plain.csv", cols, columns=columns)
    grouped = write_lines(work / "grouped.csv", cols, _grouped(",", ".", ";"), columns=columns)
    assert ";1.000\n" in grouped.read_text() and ";1.005\n" in grouped.read_text()
    extra = '[csv]\ndelimiter = ";"\ndecimal = ","\nthousands = "."\n'
    a = (plain, _mapping(work, "plain.toml", inputs))
    _same(cli, a, (grouped, _mapping(work, "grouped.toml", inputs + extra)), work / "out")
