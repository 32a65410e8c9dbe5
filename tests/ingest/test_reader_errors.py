"""The table readers' errors (empty, damaged or over-long CSV files, corrupt Parquet data),
episode names made unique across files, and measured velocities with ``--velocity kalman``."""

from __future__ import annotations

import gzip
import json
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from excavator_surrogate.data import load_dataset
from excavator_surrogate.ingest import convert_log, kalman_velocity, parse_mapping, tables
from excavator_surrogate.ingest.velocity import kalman_fuse
from tests.helpers import arm3_plant
from tests.helpers.ingest import import_fails, write_lines


def _fail(cli, work: Path, log: Path, mapping: str = "arm3.toml") -> str:
    return import_fails(cli, log, work / mapping, work / "ds")


def test_csv_files_without_data(cli, work):
    """An empty file, a header alone, a header and fewer lines than [csv]
    skip_rows_after_header skips."""
    header = ",".join(arm3_plant.LOG_COLUMNS) + "\n"
    (work / "empty.csv").write_text("")
    err = _fail(cli, work, work / "empty.csv")
    assert "empty.csv: empty file or no header line (the first line (after [csv] skip_rows)" in err
    (work / "header.csv").write_text(header)
    err = _fail(cli, work, work / "header.csv")
    assert "header.csv: the log has no data rows (remove the file or record data)" in err
    (work / "units.toml").write_text(
        arm3_plant.MAPPING_TOML + "[csv]\nskip_rows_after_header = 2\n"
    )
    (work / "units.csv").write_text(header + "ms,deg,%,%,deg,%,%,deg,%,%\n")
    err = _fail(cli, work, work / "units.csv", "units.toml")
    assert (
        "units.csv: the log has no data rows: it ends within the 2 line(s) under the header" in err
    )
    assert "check skip_rows_after_header in" in err and "units.toml" in err


def test_an_over_long_header_is_refused(cli, work, monkeypatch):
    """A first line past the bound without a line end (here lowered to 1 MB) is no CSV header."""
    monkeypatch.setattr(tables, "MAX_LINE_BYTES", 1024**2)
    (work / "long.csv").write_text("t_ms," + "x" * 1024**2)
    err = _fail(cli, work, work / "long.csv")
    assert "long.csv: the header (line 1) is longer than 1 MB" in err
    assert "the file is not a CSV log (or its line ends are not \\n)" in err


def test_nul_bytes_left_by_a_crash(cli, work, short_cols):
    """A file of NUL bytes (pre-allocated, never written) and a log whose tail is NUL bytes:
    no traceback from the csv module's field limit, the line named."""
    (work / "zeros.csv").write_bytes(bytes(200_000) + b"\n")
    err = _fail(cli, work, work / "zeros.csv")
    assert "zeros.csv: cannot split the header (line 1) into column names (field larger" in err
    assert "NUL bytes left by a crash" in err
    log = write_lines(work / "tail.csv", short_cols)
    log.write_bytes(log.read_bytes() + bytes(200_000))
    err = _fail(cli, work, log)
    assert "tail.csv, row 1000: line 1002 of the file cannot be split into fields (field" in err
    assert "repair or cut the damaged line (a crash can leave a tail of NUL bytes)" in err


def test_a_ragged_row_is_found_past_a_stray_byte(cli, work, short_cols):
    """A code-page byte in an unmapped column does not hide the ragged row that follows."""
    text = write_lines(work / "tmp.csv", short_cols).read_text().splitlines()
    lines = [text[0] + ",note"] + [x + ",Prüfung" for x in text[1:]]
    lines[41] += ",9"
    log = work / "note.csv"
    log.write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    err = _fail(cli, work, log)
    assert "note.csv, row 40: ragged rows: line 42 of the file has 12 fields, the header 11" in err


def test_ragged_row_leaves_a_truncated_gzip_to_the_caller(work, short_cols):
    """The search for a ragged row stops at a gzip stream cut short (the reader names it)."""
    blob = gzip.compress(write_lines(work / "a.csv", short_cols).read_bytes())
    (work / "cut.csv.gz").write_bytes(blob[: len(blob) // 2])
    opts = parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML)).csv
    assert tables.ragged_row(work / "cut.csv.gz", opts, len(arm3_plant.LOG_COLUMNS)) is None


def test_parquet_without_rows_or_with_corrupt_data(cli, work, short_cols):
    table = pa.table({c: short_cols[c] for c in arm3_plant.LOG_COLUMNS})
    pq.write_table(table.slice(0, 0), work / "empty.parquet")
    err = _fail(cli, work, work / "empty.parquet")
    assert "empty.parquet: the log has no data rows" in err
    pq.write_table(table, work / "good.parquet")
    blob = bytearray((work / "good.parquet").read_bytes())
    at = pq.ParquetFile(work / "good.parquet").metadata.row_group(0).column(1).data_page_offset
    blob[at + 30 : at + 200] = bytes(170)  # in boom_deg's compressed page; the footer intact
    (work / "bad.parquet").write_bytes(bytes(blob))
    err = _fail(cli, work, work / "bad.parquet")
    assert (
        "bad.parquet: cannot read Parquet data (" in err
        and "the file is corrupt; re-export it" in err
    )
    (work / "cut.parquet").write_bytes(bytes(blob[: len(blob) // 2]))
    err = _fail(cli, work, work / "cut.parquet")
    assert "cut.parquet: not a readable Parquet file (" in err and "re-export the log" in err


def test_logs_of_the_same_name_get_unique_episode_names(cli, work, arm3_dir):
    """run01.csv from two folders (two recordings): the second's episode (and its report
    segment) is run01_2."""
    for sub, log in (("a", "run01.csv"), ("b", "run02.csv")):
        (work / sub).mkdir()
        shutil.copy(arm3_dir / "logs" / log, work / sub / "run01.csv")
    out = work / "ds"
    rc, _, err = cli(
        "import", work / "a", work / "b", "--mapping", work / "arm3.toml", "--out", out, "--quiet"
    )
    assert rc == 0, err
    ds = load_dataset(out)
    assert sorted(e.name for e in ds.train + ds.val + ds.test) == ["run01", "run01_2"]
    rep = json.loads((out / "import_report.json").read_text())
    episodes = [[s["episode"] for s in f["segments"]] for f in rep["files"]]
    assert episodes == [["run01"], ["run01_2"]]


def test_measured_velocities_are_kept_with_kalman(cli, work, short_cols):
    """``--velocity kalman`` derives only the joints without a velocity channel: with one for
    every joint, the episodes are those of the default import."""
    cols = dict(short_cols)
    t_s = cols["t_ms"] * 1e-3
    text = arm3_plant.MAPPING_TOML
    for j in arm3_plant.JOINTS:
        cols[f"{j}_rate"] = np.gradient(cols[f"{j}_deg"], t_s)
        angle = f'angle = {{ column = "{j}_deg", unit = "deg" }}'
        text = text.replace(angle, f'{angle}\nvelocity = {{ column = "{j}_rate", unit = "deg/s" }}')
    (work / "rates.toml").write_text(text)
    columns = (*arm3_plant.LOG_COLUMNS, *(f"{j}_rate" for j in arm3_plant.JOINTS))
    log = write_lines(work / "rates.csv", cols, columns=columns)
    runs = {}
    for velocity in ("kalman", "diff"):
        out = work / velocity
        argv = ["import", log, "--mapping", work / "rates.toml", "--out", out, "--quiet"]
        rc, _, err = cli(*argv, "--velocity", velocity)
        assert rc == 0, err
        rep = json.loads((out / "import_report.json").read_text())
        assert set(rep["files"][0]["velocity"].values()) == {"measured"}
        runs[velocity] = load_dataset(out).train[0]
    np.testing.assert_allclose(runs["kalman"].omega, runs["diff"].omega, rtol=0, atol=1e-12)
    np.testing.assert_allclose(runs["kalman"].theta, runs["diff"].theta, rtol=0, atol=1e-12)


def test_kalman_velocity_is_the_fused_angle_difference(work, short_cols):
    ep = convert_log(
        write_lines(work / "a.csv", short_cols),
        parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML)),
    ).episodes[0]
    v = kalman_velocity(ep)
    assert v.shape == (ep.n_step, ep.spec.n_joint) and v.dtype == np.float64
    fused = kalman_fuse(ep)
    np.testing.assert_allclose(v[1:], np.diff(fused.theta, axis=0) / ep.dt, atol=1e-9)
    rms = np.sqrt(np.mean((v - ep.omega) ** 2, axis=0))
    assert np.all(rms < 0.2 * np.sqrt(np.mean(ep.omega**2, axis=0)))
