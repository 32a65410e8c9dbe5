"""Issue 25, weak cases: resource bounds, readable numbers, clear CSV structure errors, an input
on a joint's command channel, the dSPACE example mapping, ``config show`` on a mapping."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import arm3_plant
from tests.helpers.ingest import assert_nothing_written, set_cell, write_lines
from tests.ingest.test_ingest_dspace import write_dspace

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "real_excavator.toml"


def _fail(cli, *argv: object) -> str:
    rc, _, err = cli(*argv)
    assert rc == 2, err
    assert err.startswith("exsur: error: ") and err.count("\n") == 1, err
    return err


# --- upsampling and memory bounds -----------------------------------------------------------


@pytest.mark.parametrize("rate", ["1e300", "1e6"])
def test_absurd_rate_is_refused_before_resampling(cli, work, short_cols, rate) -> None:
    log = write_lines(work / "a.csv", short_cols)
    out = work / "X"
    err = _fail(cli, "import", log, "--mapping", work / "arm3.toml", "--out", out, "--rate", rate)
    assert f"{log}, column 't_ms': target rate {float(rate):.6g} Hz is" in err
    assert "above the upsampling bound 10x" in err and "--max-upsample" in err
    assert_nothing_written(out)


def test_output_size_is_estimated_before_resampling(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols)
    m = work / "arm3.toml"
    argv = ("import", log, "--mapping", m, "--dry-run", "--quiet", "--rate", "900")
    err = _fail(cli, *argv, "--max-upsample", "20", "--max-memory", "0.5")
    assert (
        "resampling to 900 Hz (8990 samples) needs" in err
        and "above the memory bound of 0.5 MB" in err
    )
    rc, text, err = cli(*argv, "--max-upsample", "20")  # the default bound holds it
    assert rc == 0 and "upsampled to 900 Hz" in text, err


@pytest.mark.parametrize("name", ["a.csv.gz", "a.csv"])
def test_decompressed_size_is_bounded(cli, work, short_cols, name) -> None:
    log = write_lines(work / name, short_cols)
    size = len(gzip.decompress(log.read_bytes())) if name.endswith(".gz") else log.stat().st_size
    bound_mb = 0.5 * size / 1024**2
    out = work / "X"
    err = _fail(
        cli, "import", log, "--mapping", work / "arm3.toml", "--out", out, "--max-memory", bound_mb
    )
    what = (
        "decompressing the log needs more than" if name.endswith(".gz") else "reading the log needs"
    )
    assert f"{log}: {what}" in err and "--max-memory" in err
    assert_nothing_written(out)


# --- numbers and CSV structure in messages --------------------------------------------------


def test_huge_time_value_is_short(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols, lambda ls: set_cell(ls, 500, "t_ms", "1e308"))
    err = _fail(cli, "import", log, "--mapping", work / "arm3.toml", "--dry-run")
    assert "time goes backwards (1e+305 s -> 5.01" in err and len(err) < 300, err


def test_infinite_dspace_time_names_file_and_row(cli, work, short_cols) -> None:
    t = short_cols["t_ms"] * 1e-3
    t[40] = np.inf
    traces = [("", "", t)] + [
        (c, "Model Root/Signals", short_cols[c]) for c in arm3_plant.LOG_COLUMNS[1:]
    ]
    log = write_dspace(work / "a.dspace.csv", traces)
    m = work / "d.toml"
    m.write_text(arm3_plant.MAPPING_TOML.replace('[time]\ncolumn = "t_ms"\nunit = "ms"\n', ""))
    err = _fail(cli, "import", log, "--mapping", m, "--dry-run")
    assert f"{log}, column 'time', row 40: non-finite timestamp inf" in err
    assert "np.float64" not in err


def test_too_many_columns_and_ragged_rows_are_named(cli, work, short_cols) -> None:
    wide = write_lines(work / "wide.csv", short_cols)
    lines = wide.read_text().splitlines()
    extra = ",".join(f"x{i}" for i in range(100_001))
    wide.write_text("\n".join([lines[0] + "," + extra, *lines[1:]]) + "\n")
    err = _fail(cli, "import", wide, "--mapping", work / "arm3.toml", "--dry-run")
    assert f"{wide}: the header (line 1) has 100011 columns: too many" in err

    ragged = write_lines(work / "ragged.csv", short_cols)
    lines = ragged.read_text().splitlines()
    lines[50] += "," + ",".join("0" for _ in range(200_000))
    ragged.write_text("\n".join(lines) + "\n")
    err = _fail(cli, "import", ragged, "--mapping", work / "arm3.toml", "--dry-run")
    assert f"{ragged}, row 49: ragged rows: line 51 of the file has 200010 fields" in err
    assert "(too many)" in err


# --- mapping ----------------------------------------------------------------------------------


def test_input_on_a_joint_command_channel_is_refused(cli, work, short_cols) -> None:
    m = work / "inp.toml"
    m.write_text(
        (work / "arm3.toml").read_text()
        + '\n[[inputs]]\nname = "rpm"\ncolumn = "arm_up_pct"\nunit = "%"\nrange = [800, 2200]\n'
    )
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, "import", log, "--mapping", m, "--dry-run")
    assert (
        "arm_up_pct is mapped to both the command of joint 'arm' and the channel of input 'rpm'"
        in err
    )


def test_config_show_on_a_mapping_says_what_it_is(cli, work) -> None:
    err = _fail(cli, "config", "show", work / "arm3.toml")
    assert "this is an import mapping, not a preset: use `exsur import LOGS --mapping" in err


def test_example_mapping_reads_a_controldesk_export(cli, work, short_cols) -> None:
    """examples/real_excavator.toml on a synthetic export laid out like the rig's (x axis
    ``time``, generic ``In1`` angle traces named by their path, duty traces by name)."""
    names = {"boom": "Boom", "arm": "Arm", "bucket": "Bkt"}
    duty = {"boom": ("up", "dn"), "arm": ("out", "in"), "bucket": ("out", "in")}
    traces = [("", "", short_cols["t_ms"] * 1e-3)]
    for j, short in names.items():
        traces.append(("In1", f"Model Root/Sensors/{short}_ang", short_cols[f"{j}_deg"]))
        for d, src in zip(duty[j], ("up", "down")):
            traces.append((f"{short}_{d}_duty", "Model Root/Duty", short_cols[f"{j}_{src}_pct"]))
    log = write_dspace(work / "B-up-60-L-S.dspace.csv.gz", traces)
    rc, text, err = cli("import", log, "--mapping", EXAMPLE, "--dry-run", "--quiet")
    assert rc == 0, err
    assert "files: 1 (1 imported" in text


def test_parquet_columns_are_bounded(cli, work, short_cols) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    log = work / "a.parquet"
    pq.write_table(pa.table({c: short_cols[c] for c in arm3_plant.LOG_COLUMNS}), log)
    err = _fail(
        cli, "import", log, "--mapping", work / "arm3.toml", "--dry-run", "--max-memory", 0.01
    )
    assert f"{log}: reading the mapped columns needs" in err


def test_upsampling_bound_uses_the_fastest_series() -> None:
    """A slow topic (a 1 Hz engine speed next to 100 Hz joints) may be held at 20 Hz."""
    from excavator_surrogate.errors import DataError
    from excavator_surrogate.ingest.checks import check_upsampling
    from excavator_surrogate.ingest.sources import Series

    fast = Series("/joints", np.arange(100) * 0.01, {}, "/joints header.stamp")
    slow = Series("/engine", np.arange(3) * 1.0, {}, "/engine header.stamp")
    dt = {"/joints": 0.01, "/engine": 1.0}
    check_upsampling(Path("b"), [fast, slow], dt, 20.0, 10.0)
    with pytest.raises(DataError, match=r"1e\+04x the 100 Hz of its fastest topic /joints"):
        check_upsampling(Path("b"), [fast, slow], dt, 1e6, 10.0)


def test_corrupt_gzip_is_one_line(cli, work, short_cols) -> None:
    """The decompressed-size bound reads .gz in Python: a damaged stream stays one line."""
    log = write_lines(work / "a.csv.gz", short_cols)
    blob = bytearray(log.read_bytes())
    for i in range(len(blob) // 3, len(blob) // 3 + 100):
        blob[i] ^= 0x55
    log.write_bytes(bytes(blob))
    err = _fail(cli, "import", log, "--mapping", work / "arm3.toml", "--dry-run")
    assert f"{log}: cannot read the file" in err
