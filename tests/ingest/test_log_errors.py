"""Malformed logs the other error tests do not reach: odd column types, time stamps that
cannot be used, a mapping for another kind of log, and unit checks of measured velocities
and periodic angles. Each is one line naming the file, the column (and row) and the fix;
exit code 2, nothing written."""

from __future__ import annotations

import json
from collections.abc import Callable
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import DataError
from excavator_surrogate.ingest.columns import numeric_column, parse_time
from excavator_surrogate.ingest.mapping import TimeMap
from tests.helpers import arm3_plant
from tests.helpers.ingest import import_fails, set_cell, write_lines


def _fail(cli, work: Path, log: Path, mapping: Path, *extra: str) -> str:
    return import_fails(cli, log, mapping, work / "ds", *extra)


def _with(work: Path, name: str, old: str, new: str) -> Path:
    """The test arm's mapping with ``old`` replaced by ``new``, as ``work / name``."""
    text = (work / "arm3.toml").read_text()
    assert old in text
    (work / name).write_text(text.replace(old, new))
    return work / name


def _parquet(path: Path, cols: dict[str, np.ndarray], **replace: pa.Array) -> Path:
    """The log as Parquet, with the columns in ``replace`` swapped for other Arrow arrays."""
    data = {c: replace.get(c, pa.array(cols[c])) for c in arm3_plant.LOG_COLUMNS}
    pq.write_table(pa.table(data), path)
    return path


def _episodes(folder: Path) -> list:
    ds = load_dataset(folder)
    return [*ds.train, *ds.val, *ds.test]


# --------------------------------------------------------------------------------------
# cells and columns


def test_a_log_of_one_sample(cli, work, short_cols):
    log = write_lines(work / "a.csv", {k: v[:1] for k, v in short_cols.items()})
    err = _fail(cli, work, log, work / "arm3.toml")
    assert f"{log}, column 't_ms': only 1 sample(s) (a log needs many samples" in err


def test_an_empty_column_is_not_filled(cli, work, short_cols):
    """--nan fill interpolates gaps; a column without any value is a mapping mistake."""

    def empty(lines: list[str]) -> list[str]:
        for r in range(len(lines) - 1):
            set_cell(lines, r, "arm_deg", "")
        return lines

    log = write_lines(work / "a.csv", short_cols, empty)
    err = _fail(cli, work, log, work / "arm3.toml", "--nan", "fill")
    assert f"{log}, column 'arm_deg': every value is missing (map a column that holds data)" in err


def test_a_bad_cell_after_an_empty_one_is_named(cli, work, short_cols):
    def edit(lines: list[str]) -> list[str]:
        return set_cell(set_cell(lines, 5, "arm_deg", ""), 9, "arm_deg", "abc")

    log = write_lines(work / "a.csv", short_cols, edit)
    err = _fail(cli, work, log, work / "arm3.toml")
    assert "column 'arm_deg', row 9: non-numeric value 'abc'" in err
    text = pa.chunked_array([["1.5", None, "x"]])
    with pytest.raises(DataError, match=r"column 'c', row 2: non-numeric value 'x'"):
        numeric_column(Path("a.csv"), text, "c")


def test_a_column_that_holds_no_numbers(cli, work, short_cols):
    n = len(short_cols["t_ms"])
    log = _parquet(work / "a.parquet", short_cols, boom_deg=pa.array([b"\x00"] * n))
    err = _fail(cli, work, log, work / "arm3.toml")
    assert f"{log}, column 'boom_deg': values are of type binary, not numbers" in err
    assert "(map a numeric column)" in err


# --------------------------------------------------------------------------------------
# time stamps


def test_timestamps_with_a_numeric_unit(cli, work, short_cols):
    stamps = pa.array((short_cols["t_ms"] * 1e3).astype(np.int64)).cast(pa.timestamp("us"))
    log = _parquet(work / "a.parquet", short_cols, t_ms=stamps)
    err = _fail(cli, work, log, work / "arm3.toml")
    assert f"{log}, column 't_ms': time column holds timestamps, but unit is numeric" in err
    assert '(set [time] unit = "datetime")' in err


def test_numbers_with_the_datetime_unit(cli, work, short_cols):
    log = _parquet(work / "a.parquet", short_cols)
    mapping = _with(work, "dt.toml", 'unit = "ms"', 'unit = "datetime"')
    err = _fail(cli, work, log, mapping)
    assert "column 't_ms': time values are of type double, not ISO-8601 text" in err
    assert "(use a numeric unit (s, ms, us, ns) for numeric time stamps)" in err


def test_a_timestamp_too_far_from_the_first(cli, work, short_cols):
    def edit(lines: list[str]) -> list[str]:
        return set_cell(set_cell(lines, 0, "t_ms", "-1e308"), 3, "t_ms", "1e308")

    log = write_lines(work / "a.csv", short_cols, edit)
    err = _fail(cli, work, log, work / "arm3.toml")
    assert "column 't_ms', row 3: timestamp 1e+308 is out of range (row 0 reads -1e+308)" in err
    assert "(drop rows without a valid time stamp)" in err


def test_integer_milliseconds_import_as_the_float_ones(cli, work, short_cols):
    cols = dict(short_cols, t_ms=np.round(short_cols["t_ms"]))
    ints = _parquet(work / "i.parquet", cols, t_ms=pa.array(cols["t_ms"].astype(np.int64)))
    floats = write_lines(work / "f.csv", cols)
    for log, out in ((ints, work / "di"), (floats, work / "df")):
        rc, _, err = cli("import", log, "--mapping", work / "arm3.toml", "--out", out, "--quiet")
        assert rc == 0, err
    rep = json.loads((work / "di" / "import_report.json").read_text())
    assert rep["files"][0]["origin"] == f"{int(cols['t_ms'][0])} ms"
    a, b = (_episodes(work / d) for d in ("di", "df"))
    assert len(a) == len(b) == 1
    np.testing.assert_allclose(a[0].time, b[0].time, atol=1e-12)
    np.testing.assert_allclose(a[0].theta, b[0].theta, atol=1e-5)  # the CSV: 6 digits


def test_date_times_with_utc_offsets_are_taken_to_utc():
    """A ``%z`` format (a logger that writes its local offset): times across an offset
    change are compared in UTC."""
    col = pa.chunked_array([["01.05.2024 23:59:55.000000+0200", "02.05.2024 01:00:00.500000+0300"]])
    tm = TimeMap(column="t", unit="datetime", format="%d.%m.%Y %H:%M:%S.%f%z")
    t, _ = parse_time(Path("a.csv"), col, tm)
    np.testing.assert_allclose(t, [0.0, 5.5], atol=1e-9)


def test_date_times_keep_every_microsecond_and_nanosecond():
    """Date-time text through a strptime format is exact: to the microsecond on 6 digits (a
    float's seconds lost one on about 1 % of stamps), to the nanosecond on 7 to 9 (which
    ``%f`` alone refuses); a fraction of 10 digits is still refused."""
    rng = np.random.default_rng(0)
    us = np.sort(rng.integers(0, 10**15, size=1000))  # 1970 to 2001, microseconds
    t0 = datetime(1970, 1, 1)
    text = [(t0 + timedelta(microseconds=int(x))).strftime("%d.%m.%Y %H:%M:%S.%f") for x in us]
    tm = TimeMap(column="t", unit="datetime", format="%d.%m.%Y %H:%M:%S.%f")
    t, _ = parse_time(Path("a.csv"), pa.chunked_array([text]), tm)
    np.testing.assert_array_equal(np.round((t - t[0]) * 1e6), (us - us[0]).astype(float))
    nine = [
        "01.05.2024 12:00:00.000000001",
        "01.05.2024 12:00:00.05000001",
        "01.05.2024 12:00:00.1",
    ]
    t, _ = parse_time(Path("a.csv"), pa.chunked_array([nine]), tm)
    np.testing.assert_allclose(t, [0.0, 0.050000009, 0.099999999], rtol=0, atol=1e-12)
    with pytest.raises(DataError, match="row 1: time value '01.05.2024 12:00:00.0500000100'"):
        parse_time(Path("a.csv"), pa.chunked_array([[nine[0], nine[1] + "00"]]), tm)


# --------------------------------------------------------------------------------------
# a mapping for another kind of log


def test_a_table_log_with_a_ros_mapping(cli, work, short_cols):
    from tests.ingest.test_ingest_ros_resample import ROS_MAPPING

    (work / "ros.toml").write_text(ROS_MAPPING)
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, work, log, work / "ros.toml")
    assert f"{log}: this is a csv log but the mapping maps ROS topics" in err
    assert "(map columns (column = ...) for CSV/Parquet/dSPACE/MDF logs)" in err


# --------------------------------------------------------------------------------------
# measured velocities and periodic angles (the six-joint machine of test_ingest_import)


def _six(
    tmp_path: Path,
    *,
    mapping: tuple[str, str] | None = None,
    **columns: Callable[[dict[str, np.ndarray]], np.ndarray],
):
    """The six-joint log and mapping, with ``mapping`` = (old, new) replaced in the mapping
    and the log's ``columns`` replaced by functions of the truth; returns (log, mapping,
    truth)."""
    from tests.ingest.test_ingest_import import _six_joint

    log, mp, truth = _six_joint(tmp_path)
    if columns:
        table = pq.read_table(log)
        for name, values in columns.items():
            i = table.schema.get_field_index(name)
            table = table.set_column(i, name, pa.array(values(truth)))
        pq.write_table(table, log)
    if mapping is not None:
        text = mp.read_text()
        assert mapping[0] in text
        mp.write_text(text.replace(*mapping))
    return log, mp, truth


def _six_fails(cli, tmp_path: Path, log: Path, mapping: Path) -> str:
    return _fail(cli, tmp_path, log, mapping, "--split-by", "glob", "--test", "six*")


MAPPED_WRONG = {
    "a velocity of the opposite sign": (
        # the log's sign is right: the mapping's scale = -1 is the mistake, so scale = 1 fixes it
        'velocity = { column = "swing_rate", unit = "deg/s" }',
        'velocity = { column = "swing_rate", unit = "deg/s", scale = -1.0 }',
        [
            "column 'swing_rate': measured velocity has the opposite sign",
            "(set scale = 1 in the velocity of joint 'swing' in six.toml)",
        ],
    ),
    "a velocity of the opposite sign, scaled": (
        'velocity = { column = "swing_rate", unit = "deg/s" }',
        'velocity = { column = "swing_rate", unit = "deg/s", scale = -0.5 }',
        ["(set scale = 0.5 in the velocity of joint 'swing' in six.toml)"],
    ),
    "a velocity in rad/s mapped as deg/s": (
        'velocity = { column = "boom_rate", unit = "rad/s" }',
        'velocity = { column = "boom_rate", unit = "deg/s" }',
        [
            "column 'boom_rate': measured velocity is 0.0175x the angle's rate of change",
            "looks like rad/s",
            "(set unit = \"rad/s\" in the velocity of joint 'boom' in six.toml)",
        ],
    ),
    "a periodic angle in degrees mapped as rad": (
        '{ column = "swing_deg", unit = "deg" }',
        '{ column = "swing_deg", unit = "rad" }',
        [
            "column 'swing_deg', row ",
            "is beyond ±2π in a rad column",
            "(set unit = \"deg\" in the angle of joint 'swing' in six.toml)",
        ],
    ),
}
"""The six-joint log with one channel mapped wrong: the mapping's text before and after,
and what the one-line error says."""


@pytest.mark.parametrize("case", list(MAPPED_WRONG))
def test_a_channel_mapped_wrong(cli, tmp_path, case):
    old, new, expected = MAPPED_WRONG[case]
    log, mp, _ = _six(tmp_path, mapping=(old, new))
    err = _six_fails(cli, tmp_path, log, mp)
    for text in expected:
        assert text in err


def test_a_reversed_velocity_channel_is_fixed_by_scale_minus_one(cli, tmp_path):
    """The log's velocity runs against its angle and the mapping has no scale: -1 fixes it."""
    log, mp, _ = _six(tmp_path, boom_rate=lambda tr: -0.15 * np.cos(0.5 * tr["t"]))
    err = _six_fails(cli, tmp_path, log, mp)
    assert "(set scale = -1 in the velocity of joint 'boom' in six.toml)" in err


def test_a_still_velocity_channel_is_not_compared(cli, tmp_path):
    """A velocity channel that reads 0 (a sensor switched off) says nothing of its unit."""
    log, mp, _ = _six(tmp_path, boom_rate=lambda tr: np.zeros_like(tr["t"]))
    rc, _, err = cli("import", log, "--mapping", mp, "--out", tmp_path / "ds", "--quiet")
    assert rc == 0, err


def test_an_unwrapped_periodic_angle_in_rad_is_kept(cli, tmp_path):
    """A turning joint logged unwrapped (beyond ±2π) at a plausible speed is not degrees."""
    log, mp, truth = _six(tmp_path, wrist_rad=lambda tr: tr["wrist"])
    assert truth["wrist"].min() < -4 * np.pi
    out = tmp_path / "ds"
    rc, _, err = cli("import", log, "--mapping", mp, "--out", out, "--quiet")
    assert rc == 0, err
    (ep,) = _episodes(out)
    expect = np.interp(ep.time, truth["t"], truth["wrist"])
    np.testing.assert_allclose(ep.theta[:, 4], expect, atol=2e-3)
