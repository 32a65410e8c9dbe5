"""Every malformed input: one-line error naming file/column/row + fix, exit code 2, nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tests.helpers import arm3_plant
from tests.helpers.ingest import import_fails, set_cell, write_lines


def _fail(cli, work: Path, log: Path, *extra: str, mapping: str = "arm3.toml") -> str:
    return import_fails(cli, log, work / mapping, work / "ds", *extra)


_set = set_cell


def test_missing_column(cli, work, short_cols):
    cols = tuple(c for c in arm3_plant.LOG_COLUMNS if c != "arm_deg")
    log = write_lines(work / "a.csv", short_cols, columns=cols)
    err = _fail(cli, work, log)
    assert f"{log}, column 'arm_deg': mapped column is missing" in err
    assert "fix the column name in" in err and "the log has: t_ms" in err
    assert "exsur info" not in err  # all 9 names are shown
    # a log of more columns than the message shows: it says how to list them all
    wide = dict(short_cols) | {f"p{k}": short_cols["t_ms"] for k in range(6)}
    log = write_lines(work / "b.csv", wide, columns=(*cols, *(f"p{k}" for k in range(6))))
    err = _fail(cli, work, log)
    assert f" ... (15 in all: exsur info {log} lists them)" in err


def test_duplicated_column(cli, work, short_cols):
    def dup(lines):
        return [
            ln.replace("t_ms,", "t_ms,arm_deg,", 1) if i == 0 else ln.replace(",", ",1.0,", 1)
            for i, ln in enumerate(lines)
        ]

    log = write_lines(work / "a.csv", short_cols, dup)
    err = _fail(cli, work, log)
    assert "column 'arm_deg': mapped column appears more than once in the header" in err
    assert "rename one of the duplicates" in err


def test_non_numeric_value(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols, lambda ls: _set(ls, 700, "bucket_up_pct", "abc"))
    err = _fail(cli, work, log)
    assert "column 'bucket_up_pct', row 700: non-numeric value 'abc'" in err
    assert "--nan" in err


def test_nan_fail_names_row(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols, lambda ls: _set(ls, 123, "boom_deg", "nan"))
    err = _fail(cli, work, log)
    assert "column 'boom_deg', row 123: missing or non-finite value" in err
    assert "--nan fill" in err


def test_nan_fill_long_run_fails(cli, work, short_cols):
    def holes(ls):
        for r in range(300, 310):
            _set(ls, r, "arm_deg", "")
        return ls

    log = write_lines(work / "a.csv", short_cols, holes)
    err = _fail(cli, work, log, "--nan", "fill", "--max-fill", "5")
    assert "column 'arm_deg', row 300: 10 consecutive missing values, more than --max-fill 5" in err


def test_inf_value(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols, lambda ls: _set(ls, 50, "arm_up_pct", "inf"))
    err = _fail(cli, work, log)
    assert "column 'arm_up_pct', row 50: missing or non-finite value (inf)" in err


def test_time_goes_backwards(cli, work, short_cols):
    def swap(ls):
        ls[401], ls[402] = ls[402], ls[401]
        return ls

    log = write_lines(work / "a.csv", short_cols, swap)
    err = _fail(cli, work, log)
    assert "column 't_ms', row 401: time goes backwards" in err and "sort the log by time" in err


def test_duplicate_timestamp(cli, work, short_cols):
    def dup(ls):
        ls.insert(202, ls[201])
        return ls

    log = write_lines(work / "a.csv", short_cols, dup)
    err = _fail(cli, work, log)
    assert (
        "column 't_ms', row 201: duplicate timestamp" in err and "drop the duplicated rows" in err
    )


def test_missing_timestamp(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols, lambda ls: _set(ls, 10, "t_ms", ""))
    err = _fail(cli, work, log)
    assert "column 't_ms', row 10: missing timestamp" in err


def test_degrees_in_rad_column(cli, work, short_cols):
    text = (
        (work / "arm3.toml")
        .read_text()
        .replace('column = "arm_deg", unit = "deg"', 'column = "arm_deg", unit = "rad"')
    )
    (work / "rad.toml").write_text(text)
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, work, log, mapping="rad.toml")
    assert "column 'arm_deg', row 0: angle" in err and "looks like degrees" in err
    assert "set unit = \"deg\" in the angle of joint 'arm' in rad.toml" in err


def test_time_unit_mistake(cli, work, short_cols):
    text = (work / "arm3.toml").read_text().replace('unit = "ms"', 'unit = "s"')
    (work / "s.toml").write_text(text)
    err = _fail(cli, work, write_lines(work / "a.csv", short_cols), mapping="s.toml")
    assert "column 't_ms': typical time step" in err and 'set [time] unit = "ms"' in err


def test_command_out_of_range_and_clip(cli, work, short_cols):
    log = write_lines(
        work / "a.csv",
        short_cols,
        lambda ls: _set(_set(ls, 555, "boom_up_pct", "130"), 555, "boom_down_pct", "0"),
    )
    err = _fail(cli, work, log)
    assert "column 'boom_up_pct - boom_down_pct', row 555: command 1300 (log value 130 %)" in err
    assert "outside [-1000, 1000] after scaling" in err and "--clip-commands" in err
    rc, out, err = cli(
        "import",
        log,
        "--mapping",
        work / "arm3.toml",
        "--out",
        work / "ds",
        "--clip-commands",
    )
    assert rc == 0, err
    rep = json.loads((work / "ds" / "import_report.json").read_text())
    assert rep["files"][0]["clipped"] == {"boom": 1}
    assert "clipped: boom 1" in out


def test_negative_one_way_channel(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols, lambda ls: _set(ls, 9, "arm_down_pct", "-5"))
    err = _fail(cli, work, log)
    assert "column 'arm_down_pct', row 9: one-way command channel is negative (-5)" in err


def test_input_out_of_range_is_named_in_its_own_unit(cli, work, short_cols):
    """An ``[[inputs]]`` channel in % (stored as raw 0..100) is reported in % (it said
    'raw'; audit 1, D11)."""
    cols = dict(short_cols) | {"rpm": np.full(short_cols["t_ms"].shape, 50.0)}
    cols["rpm"][800] = 120.0
    log = write_lines(work / "a.csv", cols, columns=(*arm3_plant.LOG_COLUMNS, "rpm"))
    (work / "inp.toml").write_text(
        (work / "arm3.toml").read_text()
        + '\n[[inputs]]\nname = "rpm"\ncolumn = "rpm"\nunit = "%"\nrange = [800, 2200]\n'
    )
    err = _fail(cli, work, log, mapping="inp.toml")
    assert "column 'rpm', row 800: command 2480 (log value 120 %) is outside [800, 2200]" in err


def test_clip_commands_counts_negative_one_way_channels(cli, work, short_cols):
    """``--clip-commands`` clamps a negative one-way channel at 0 and counts its rows (it
    clamped them and reported nothing clipped; audit 1, D10)."""

    def negative(lines):
        for r in range(600, 610):
            lines = _set(lines, r, "arm_down_pct", "-3")
        return lines

    log = write_lines(work / "a.csv", short_cols, negative)
    rc, out, err = cli(
        "import", log, "--mapping", work / "arm3.toml", "--out", work / "ds", "--clip-commands"
    )
    assert rc == 0, err
    rep = json.loads((work / "ds" / "import_report.json").read_text())
    assert rep["files"][0]["clipped"] == {"arm": 10}
    assert "clipped: arm 10" in out


def test_too_short_everything_dropped(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, work, log, "--min-steps", "500")
    assert "nothing to import: every episode was dropped" in err
    assert "< min_steps 500" in err and "lower --min-steps" in err


def test_short_file_dropped_with_reason(cli, work, short_cols, arm3_dir):
    short = {k: v[:150] for k, v in short_cols.items()}  # 1.5 s -> 28 samples < 40
    write_lines(work / "logs" / "tiny.csv", short)
    rc, out, err = cli(
        "import",
        arm3_dir / "logs" / "run01.csv",
        work / "logs" / "tiny.csv",
        "--mapping",
        work / "arm3.toml",
        "--out",
        work / "ds",
    )
    assert rc == 0, err
    rep = json.loads((work / "ds" / "import_report.json").read_text())
    assert rep["totals"]["files_dropped"] == 1 and rep["totals"]["segments_dropped"] == 1
    assert "< min_steps 40" in rep["dropped"][0]["reason"]
    assert "Dropped:" in out and "tiny" in out


def test_on_error_skip(cli, work, short_cols, arm3_dir):
    bad = write_lines(work / "bad.csv", short_cols, lambda ls: _set(ls, 3, "boom_deg", "x"))
    rc, out, err = cli(
        "import",
        arm3_dir / "logs" / "run01.csv",
        bad,
        "--mapping",
        work / "arm3.toml",
        "--out",
        work / "ds",
        "--on-error",
        "skip",
    )
    assert rc == 0, err
    assert "skipped" in err and "FAILED" in out
    rep = json.loads((work / "ds" / "import_report.json").read_text())
    assert (
        rep["totals"]["files_failed"] == 1 and "non-numeric value 'x'" in rep["files"][1]["error"]
    )


def test_bad_csv_structure(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols, lambda ls: [*ls[:100], "1,2,3", *ls[100:]])
    err = _fail(cli, work, log)
    assert "row 99: ragged rows: line 101 of the file has 3 fields, the header 10 (too few)" in err


def test_mapping_errors(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols)
    cases = {
        "typo": ('unit = "deg" }', 'unit = "deg", sacle = 2 }', "unknown key(s) ['sacle']"),
        "unit": (
            'angle = { column = "boom_deg", unit = "deg" }',
            'angle = { column = "boom_deg", unit = "grad" }',
            "angle.unit: must be one of ['deg', 'rad', 'm', 'cm', 'mm']",
        ),
        "raw": (
            'unit = "%", range = [-1000.0, 1000.0] }\n\n[[joints]]\nname = "arm"',
            'unit = "raw", range = [-1000.0, 1000.0] }\n\n[[joints]]\nname = "arm"',
            "needs raw_range",
        ),
    }
    for name, (old, new, msg) in cases.items():
        text = (work / "arm3.toml").read_text()
        assert old in text, name
        (work / f"{name}.toml").write_text(text.replace(old, new, 1))
        err = _fail(cli, work, log, mapping=f"{name}.toml")
        assert f"{name}.toml" in err and msg in err, (name, err)


def test_out_must_be_a_dataset(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols)
    other = work / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    rc, _, err = cli("import", log, "--mapping", work / "arm3.toml", "--out", other)
    assert rc == 2 and "which exsur did not write" in err
    assert (other / "keep.txt").read_text() == "mine"


def test_missing_source_and_unsupported(cli, work):
    err = _fail(cli, work, work / "nope.csv")
    assert "nope.csv: file not found" in err
    (work / "x.txt").write_text("hi")
    err = _fail(cli, work, work / "x.txt")
    assert "unsupported log type" in err


def test_kalman_velocity(cli, work, short_cols):
    log = write_lines(work / "a.csv", short_cols)
    rc, _, err = cli(
        "import",
        log,
        "--mapping",
        work / "arm3.toml",
        "--out",
        work / "ds",
        "--velocity",
        "kalman",
        "--quiet",
    )
    assert rc == 0, err
    rep = json.loads((work / "ds" / "import_report.json").read_text())
    assert set(rep["files"][0]["velocity"].values()) == {"kalman"}
    # The derived velocity is the backward difference of the (fused) angle: consistent pair.
    from excavator_surrogate.data import load_dataset

    ep = load_dataset(work / "ds").train[0]
    np.testing.assert_allclose(ep.omega[1:], np.diff(ep.theta, axis=0) / ep.dt, atol=1e-9)


def test_nan_values_fail_in_every_mapped_column(cli, work, short_cols):
    """A NaN in the time column or an angle is never silently dropped."""
    cols = dict(short_cols)
    cols["bucket_deg"] = cols["bucket_deg"].copy()
    cols["bucket_deg"][-1] = np.nan
    err = _fail(cli, work, write_lines(work / "a.csv", cols))
    assert "column 'bucket_deg', row 999" in err


def test_log_unit_labels():
    """A log's unit label is read as the mapping's unit name whatever its case, brackets or
    way of writing per second; an unknown label is not compared, a known different one is
    the one-line error."""
    import pytest

    from excavator_surrogate.errors import DataError
    from excavator_surrogate.ingest.checks import check_log_unit, log_unit_name

    named = {
        "deg": "deg",
        " Degrees ": "deg",
        "[°]": "deg",
        "(RAD)": "rad",
        "Millimetres": "mm",
        "rad/s": "rad/s",
        "Rad/Sec": "rad/s",
        "deg s^-1": "deg/s",
        "°/s": "deg/s",
        "[deg/s]": "deg/s",
        "mm*s^-1": "mm/s",
        "cm s-1": "cm/s",
        "m/second": "m/s",
    }
    assert {k: log_unit_name(k) for k in named} == named
    for unknown in ("", "Grad", "ms", "%", "bar", "1/s", "/s", "[]", "rpm"):
        assert log_unit_name(unknown) is None, unknown
    where = dict(label="arm", what="the angle of joint 'arm'", where="m.toml")
    check_log_unit(Path("a.mf4"), "[Deg]", "deg", **where)
    check_log_unit(Path("a.mf4"), "Grad", "deg", **where)  # not compared
    with pytest.raises(DataError, match=r"the unit 'rad/sec', the mapping 'deg/s'"):
        check_log_unit(Path("a.mf4"), "rad/sec", "deg/s", **where)
    # a log that measures a length or an angle the mapping takes for the other kind
    stroke = dict(label="boom", what="the angle of joint 'boom'", where="m.toml")
    with pytest.raises(DataError, match=r"map the position of joint 'boom' as a linear joint"):
        check_log_unit(Path("a.mf4"), "mm", "deg", **stroke)
    with pytest.raises(DataError) as e:
        check_log_unit(Path("a.mf4"), "deg", "mm", **stroke)
    assert (
        "a.mf4, column 'boom': the log gives this channel the unit 'deg', the mapping 'mm' "
        "(the log measures an angle: set unit = \"deg\" in the angle of joint 'boom' in m.toml; "
        'if the log\'s label is wrong, set [import] log_units = "ignore")'
    ) == str(e.value)


def test_a_failed_import_leaves_no_folders(cli, tmp_path) -> None:
    """An import that fails on its log leaves none of the folders it made for ``--out``."""
    log = tmp_path / "bad.csv"
    log.write_text("t,a\n0,1\n")
    (tmp_path / "m.toml").write_text(
        '[time]\ncolumn = "t"\n[[joints]]\nname = "boom"\n'
        'angle = { column = "boom_deg", unit = "deg" }\ncommand = { column = "u", unit = "%" }\n'
    )
    rc, _, err = cli("import", log, "--mapping", tmp_path / "m.toml", "--out", tmp_path / "a" / "b")
    assert rc == 2, err
    assert not (tmp_path / "a").exists()


def test_physical_command_out_of_range_names_its_unit(cli, work, short_cols):
    """A joint command in a physical unit (here the valve's pilot pressure in bar) is
    reported in that unit, as the mapping names it (it said 'physical')."""
    log = write_lines(
        work / "a.csv",
        short_cols,
        lambda ls: _set(_set(ls, 555, "boom_up_pct", "130"), 555, "boom_down_pct", "0"),
    )
    old = 'unit = "%", range = [-1000.0, 1000.0] }'
    text = (work / "arm3.toml").read_text()
    assert old in text
    new = 'unit = "physical", physical_unit = "bar", range = [-100.0, 100.0] }'
    (work / "bar.toml").write_text(text.replace(old, new))
    err = _fail(cli, work, log, mapping="bar.toml")
    assert "row 555: command 130 (log value 130 bar) is outside [-100, 100]" in err
