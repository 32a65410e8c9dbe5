"""dSPACE ControlDesk CSV exports: names from the path row, detection, forcing, every error.

The exports are synthetic: the test arm's log written in the ControlDesk layout with
made-up model paths (metadata rows, generic ``In1`` trace names, a ``path`` row).
"""

from __future__ import annotations

import gzip
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.ingest import convert_log, parse_mapping
from excavator_surrogate.ingest.readers import log_kind
from tests.helpers import arm3_plant
from tests.helpers.ingest import import_fails

SENSORS = "Model Root/Sensors"
VALVES = "Model Root/Valve commands"


def dspace_traces(cols: dict[str, np.ndarray]) -> list[tuple[str, str, np.ndarray]]:
    """``(trace name, path, values)`` of the test arm's log as a rig would record it."""
    out = [("", "", cols["t_ms"] * 1e-3)]  # the x axis: no name, no path
    rng = np.random.default_rng(3)
    out.append(("Out1", "Model Root/Hydraulics/p_pump", rng.uniform(100, 200, cols["t_ms"].size)))
    for j in arm3_plant.JOINTS:
        out.append(("In1", f"{SENSORS}/{j}_deg", cols[f"{j}_deg"]))
        for d in ("up", "down"):
            out.append((f"{j}_{d}_pct", VALVES, cols[f"{j}_{d}_pct"]))
    return out


def write_dspace(
    path: Path,
    traces: list[tuple[str, str, np.ndarray]],
    *,
    delimiter: str = ",",
    preamble: bool = True,
    cut_bytes: int = 0,
    units: dict[str, str] | None = None,
) -> Path:
    """Write ``traces`` in the ControlDesk CSV layout (gzip if ``.gz``); ``cut_bytes`` truncates."""
    d = delimiter
    n = traces[0][2].size

    def row(label: str, cells: list[str]) -> bytes:
        return (d.join([label, *cells]) + "\r\n").encode()

    head = b""
    if preamble:
        head += row("descriptions", ["General", "User", "tester"])
        head += (
            d.join(["", "General", "DateTime", "2025-01-01 \xbf\xc0\xc8\xc4 1:00:00"]).encode(
                "latin-1"
            )
            + b"\r\n"
        )  # a date in a local code page: not UTF-8
        head += row("", ["General", "Origin", '"line one\nline two, with a comma"'])
        head += b"\r\n"
    head += row("trace_size", [str(n)])
    head += row("trace_types", ["5"] + ["4"] * (len(traces) - 1))
    head += row("trace_names", [t[0] for t in traces])
    units = units or {}
    head += row("trace_units", [units.get(t[1].rsplit("/", 1)[-1] or t[0], "") for t in traces])
    head += row("path", [t[1] for t in traces])
    head += row("flags", ["2"] * len(traces))
    data = np.column_stack([t[2] for t in traces])
    body = b"".join(
        row("trace_values" if k == 0 else "", [f"{v:.10g}" for v in r]) for k, r in enumerate(data)
    )
    blob = head + body
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.name.endswith(".gz"):
        blob = gzip.compress(blob)
    path.write_bytes(blob[: len(blob) - cut_bytes] if cut_bytes else blob)
    return path


def dspace_mapping_toml() -> str:
    """The test arm's mapping for the exports: short names, two full names, no [time]."""
    text = arm3_plant.MAPPING_TOML.replace('[time]\ncolumn = "t_ms"\nunit = "ms"\n', "")
    text = text.replace('"bucket_deg"', f'"{SENSORS}/bucket_deg"')
    return text.replace('down = "bucket_down_pct"', f'down = "{VALVES}/bucket_down_pct"')


@pytest.fixture
def dsp(tmp_path: Path, short_cols) -> Path:
    """A folder with the exports' mapping ``dspace.toml``."""
    (tmp_path / "dspace.toml").write_text(dspace_mapping_toml())
    return tmp_path


def _fail(cli, work: Path, log: Path, mapping: str = "dspace.toml") -> str:
    return import_fails(cli, log, work / mapping, work / "ds")


def test_dspace_import_matches_plain_csv(cli, dsp, arm3_dir):
    """Both detections (suffix, content) give the episodes the plain CSV of the same data gives."""
    logs = dsp / "logs"
    for i, name in enumerate(("run01.dspace.csv.gz", "run02.csv")):
        cols = arm3_plant.simulate(duration_s=30.0, seed=i)
        write_dspace(logs / name, dspace_traces(cols), delimiter=";" if i else ",")
    assert log_kind(logs / "run01.dspace.csv.gz") == "dspace"
    assert log_kind(logs / "run02.csv") == "dspace"
    assert log_kind(arm3_dir / "logs" / "run01.csv") == "csv"
    rc, text, err = cli("import", logs, "--mapping", dsp / "dspace.toml", "--out", dsp / "ds")
    assert rc == 0, err
    assert "run01.dspace.csv.gz" in text
    eps = {e.name: e for e in _episodes(dsp / "ds")}
    assert sorted(eps) == ["run01", "run02"]
    for i, name in enumerate(("run01", "run02")):
        ref = convert_log(
            arm3_dir / "logs" / f"run0{i + 1}.csv",
            parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML)),
        ).episodes[0]
        ep = eps[name]
        assert ep.n_step == ref.n_step
        np.testing.assert_allclose(ep.time, ref.time, atol=1e-9)
        np.testing.assert_allclose(ep.theta, ref.theta, atol=1e-5)  # CSV: 6 digits
        np.testing.assert_allclose(ep.u, ref.u, atol=1e-2)
        assert ep.extra["import"]["file"].endswith((".dspace.csv.gz", ".csv"))


def _episodes(out: Path) -> list:
    from excavator_surrogate.data import load_dataset

    ds = load_dataset(out, min_steps=40)
    return ds.train + ds.val + ds.test


def test_dspace_forced_by_the_mapping(dsp, short_cols):
    """A preamble-less export is found by its trace rows; ``[csv] format`` forces either way."""
    log = write_dspace(dsp / "bare.csv", dspace_traces(short_cols), preamble=False)
    odd = dsp / "odd.csv"
    odd.write_bytes(b"exported by a script\r\n" + log.read_bytes())
    data = tomllib.loads(dspace_mapping_toml())
    auto = parse_mapping(data, path=dsp / "m.toml")
    assert convert_log(log, auto).entry["kind"] == "dspace"
    with pytest.raises(ConfigError, match="time.column is required for CSV/Parquet logs"):
        convert_log(odd, auto)  # not recognised: read as a plain CSV
    forced = parse_mapping({**data, "csv": {"format": "dspace"}}, path=dsp / "m.toml")
    res = convert_log(odd, forced)
    assert res.entry["kind"] == "dspace" and res.episodes[0].n_step == 198
    plain = parse_mapping(
        {**data, "csv": {"format": "plain"}, "time": {"column": "t_ms"}}, path=dsp / "m.toml"
    )
    with pytest.raises(DataError, match="mapped column is missing"):
        convert_log(log, plain)
    # the x axis answers to "time", or to its name in [time] column
    named = parse_mapping({**data, "time": {"column": "time"}}, path=dsp / "m.toml")
    np.testing.assert_array_equal(convert_log(log, named).episodes[0].theta, res.episodes[0].theta)


def test_dspace_missing_channel(cli, dsp, short_cols):
    traces = [t for t in dspace_traces(short_cols) if not t[1].endswith("/arm_deg")]
    err = _fail(cli, dsp, write_dspace(dsp / "a.dspace.csv", traces))
    assert "column 'arm_deg': mapped column is missing" in err
    assert "fix the channel name in" in err and "the log has: time, p_pump, boom_deg" in err
    (dsp / "typo.toml").write_text(dspace_mapping_toml().replace('"arm_deg"', '"arm_degs"'))
    log = write_dspace(dsp / "b.dspace.csv", dspace_traces(short_cols))
    err = _fail(cli, dsp, log, "typo.toml")
    assert "column 'arm_degs': mapped column is missing (did you mean 'arm_deg'?" in err


def test_dspace_ambiguous_channel(cli, dsp, short_cols):
    """Two traces end in ``boom_deg``: refused, with the full names to choose from."""
    traces = dspace_traces(short_cols)
    traces.append(("In1", "Model Root/Diagnostics/boom_deg", traces[2][2] + 1.0))
    err = _fail(cli, dsp, write_dspace(dsp / "a.dspace.csv", traces))
    assert "column 'boom_deg': channel name is ambiguous: 2 traces answer to it" in err
    assert f"'{SENSORS}/boom_deg', 'Model Root/Diagnostics/boom_deg'" in err
    # a path shared by several specific traces is ambiguous too
    text = dspace_mapping_toml().replace('down = "arm_down_pct"', f'down = "{VALVES}"')
    (dsp / "shared.toml").write_text(text)
    err = _fail(
        cli, dsp, write_dspace(dsp / "b.dspace.csv", dspace_traces(short_cols)), "shared.toml"
    )
    assert f"column '{VALVES}': channel name is ambiguous: 6 traces" in err
    assert f"'{VALVES}/boom_up_pct'" in err


@pytest.mark.parametrize(
    ("name", "cut", "expect"),
    [
        ("gz.dspace.csv.gz", 200, "cannot read the file (EOFError"),
        ("mid.dspace.csv", 30, "row 999: sample row has"),
        ("rows.dspace.csv", 0, "999 sample rows, but trace_size says 1000: the file is truncated"),
    ],
)
def test_dspace_truncated(cli, dsp, short_cols, name, cut, expect):
    log = write_dspace(dsp / name, dspace_traces(short_cols), cut_bytes=cut)
    if cut == 0:  # cut one whole sample row
        lines = log.read_bytes().split(b"\r\n")
        log.write_bytes(b"\r\n".join([*lines[:-2], b""]))
    err = _fail(cli, dsp, log)
    assert expect in err and "re-export" in err


def test_dspace_bad_cells(cli, dsp, short_cols):
    log = write_dspace(dsp / "a.dspace.csv", dspace_traces(short_cols))
    lines = log.read_bytes().split(b"\r\n")
    first = next(i for i, ln in enumerate(lines) if ln.startswith(b"trace_values"))
    cells = lines[first + 40].split(b",")
    cells[3] = b"oops"  # boom_deg of sample row 40
    lines[first + 40] = b",".join(cells)
    log.write_bytes(b"\r\n".join(lines))
    err = _fail(cli, dsp, log)
    assert "column 'boom_deg', row 40: non-numeric value 'oops'" in err
    no_values = dsp / "b.dspace.csv"
    no_values.write_bytes(b"\r\n".join(ln for ln in lines if not ln.startswith((b"trace_v", b","))))
    err = _fail(cli, dsp, no_values)
    assert "no trace_values row: not a dSPACE ControlDesk CSV export" in err


def test_dspace_trace_units_against_the_mapping(cli, dsp, short_cols):
    """The export's trace_units row is checked as an MDF channel's unit: "deg" passes, a
    "rad" for a degree-mapped angle is one line; exsur info shows the units."""
    traces = dspace_traces(short_cols)
    ok = write_dspace(dsp / "ok" / "a.dspace.csv", traces, units={"boom_deg": "deg"})
    rc, out, err = cli("info", ok, "--json")
    assert rc == 0, err
    assert {c["name"]: c["unit"] for c in json.loads(out)["channels"]}["boom_deg"] == "deg"
    rc, _, err = cli("import", ok, "--mapping", dsp / "dspace.toml", "--dry-run", "--quiet")
    assert rc == 0, err
    bad = write_dspace(dsp / "bad" / "a.dspace.csv", traces, units={"arm_deg": "rad"})
    err = _fail(cli, dsp, bad)
    assert "column 'arm_deg': the log gives this channel the unit 'rad', the mapping 'deg'" in err


def test_a_damaged_gzip_is_named_not_taken_for_a_plain_csv(cli, dsp, short_cols):
    """Content detection cannot read a .csv.gz that is not gzip: the CSV reader names the
    damage (not the missing [time] column the exports' mapping leaves out)."""
    blob = write_dspace(dsp / "a.dspace.csv", dspace_traces(short_cols)).read_bytes()
    (dsp / "run.csv.gz").write_bytes(blob)  # gzip by its name only
    err = _fail(cli, dsp, dsp / "run.csv.gz")
    assert "run.csv.gz: cannot read the header (BadGzipFile" in err and "gzip if .gz" in err


def test_dspace_export_errors(cli, dsp, short_cols):
    """An export past the memory bound, without trace names, separated by the mapping's
    thousands mark, or ending in NUL bytes (a crash): one line each, with the fix."""
    log = write_dspace(dsp / "big.dspace.csv.gz", dspace_traces(short_cols))
    rc, _, err = cli(
        "import", log, "--mapping", dsp / "dspace.toml", "--dry-run", "--max-memory", "0.05"
    )
    assert rc == 2 and "big.dspace.csv.gz: decompressing the export needs more than" in err
    assert "--max-memory" in err
    lines = write_dspace(dsp / "a.dspace.csv", dspace_traces(short_cols)).read_bytes()
    unnamed = dsp / "unnamed.dspace.csv"
    rows = lines.split(b"\r\n")
    unnamed.write_bytes(
        b"\r\n".join(r for r in rows if not r.startswith((b"trace_names", b"path")))
    )
    err = _fail(cli, dsp, unnamed)
    assert "unnamed.dspace.csv: no trace_names or path row before trace_values" in err
    assert "export the measurement again" in err
    (dsp / "th.toml").write_text(dspace_mapping_toml() + '[csv]\nthousands = ","\n')
    err = _fail(cli, dsp, dsp / "a.dspace.csv", "th.toml")
    assert (
        "a.dspace.csv: the export separates its fields by ',', the mapping's [csv] thousands" in err
    )
    assert "remove [csv] thousands from" in err
    nul = dsp / "nul.dspace.csv"
    nul.write_bytes(lines + bytes(200_000))  # one cell past the csv module's 128 KiB limit
    err = _fail(cli, dsp, nul)
    assert "nul.dspace.csv, row 1000: sample row cannot be split into cells (field larger" in err
    assert "re-export it from ControlDesk" in err


def test_a_time_trace_named_in_the_mapping(dsp, short_cols):
    """``[time] column`` naming a recorded trace (not the x axis) takes the time from it."""
    traces = dspace_traces(short_cols)
    clock = ("In1", "Model Root/Clock/t_rig", short_cols["t_ms"] * 1e-3 + 100.0)
    traces = [(traces[0][0], traces[0][1], np.arange(traces[0][2].size) * 7.0), clock, *traces[1:]]
    log = write_dspace(dsp / "clock.dspace.csv", traces)
    data = tomllib.loads(dspace_mapping_toml())
    mapping = parse_mapping({**data, "time": {"column": "t_rig", "unit": "s"}}, path=dsp / "m.toml")
    res = convert_log(log, mapping)
    assert res.entry["series"]["table"]["rate_hz"] == pytest.approx(100.0, rel=1e-3)
    plain = write_dspace(dsp / "ref.dspace.csv", dspace_traces(short_cols))
    ref = convert_log(plain, parse_mapping(data, path=dsp / "m.toml")).episodes[0]
    assert res.episodes[0].n_step == ref.n_step
    np.testing.assert_allclose(res.episodes[0].theta, ref.theta, atol=1e-9)


def test_the_x_axis_is_in_seconds_whatever_the_time_unit(dsp, short_cols):
    """The plain CSV logs' mapping (``[time] column = "t_ms"``, ``unit = "ms"``) reads the
    exports of the same rig: the x axis answers to ``t_ms`` and stays in seconds (it was
    read in ms: 100 Hz taken for 100 kHz)."""
    log = write_dspace(dsp / "x.dspace.csv", dspace_traces(short_cols))
    res = convert_log(log, parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML)))
    assert res.entry["series"]["table"]["rate_hz"] == pytest.approx(100.0, rel=1e-3)
    ref = convert_log(log, parse_mapping(tomllib.loads(dspace_mapping_toml()))).episodes[0]
    np.testing.assert_allclose(res.episodes[0].time, ref.time, atol=1e-9)
    np.testing.assert_allclose(res.episodes[0].theta, ref.theta, atol=1e-9)
