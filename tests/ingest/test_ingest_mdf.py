"""ASAM MDF4 logs (asammdf): one or several channel groups, and every error."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.ingest import convert_log, parse_mapping
from tests.helpers import arm3_plant
from tests.helpers.ingest import import_fails

asammdf = pytest.importorskip("asammdf")

MAPPING = arm3_plant.MAPPING_TOML.replace('[time]\ncolumn = "t_ms"\nunit = "ms"\n', "")
"""The test arm's mapping without [time]: MDF channels carry their group's master time."""


def _signals(
    cols: dict[str, np.ndarray],
    names: list[str],
    keep: np.ndarray | None = None,
    units: dict[str, str] | None = None,
):
    t = cols["t_ms"] * 1e-3
    sel = slice(None) if keep is None else keep
    units = units or {}
    return [asammdf.Signal(cols[n][sel], t[sel], name=n, unit=units.get(n, "")) for n in names]


def write_mdf(
    path: Path,
    cols: dict[str, np.ndarray],
    *,
    split_bucket: bool = False,
    version: str = "4.10",
    units: dict[str, str] | None = None,
) -> Path:
    """The test arm's log as MDF4 (or another MDF ``version``); ``split_bucket``: bucket
    channels in a second channel group that covers 2 s .. 25 s only; ``units``: the
    channels' own units (none by default)."""
    names = [c for c in arm3_plant.LOG_COLUMNS if c != "t_ms"]
    mdf = asammdf.MDF(version=version)
    bucket = [n for n in names if n.startswith("bucket")] if split_bucket else []
    main = [n for n in names if n not in bucket]
    mdf.append(_signals(cols, main, units=units), comment="main raster")
    if bucket:
        t = cols["t_ms"] * 1e-3
        mdf.append(_signals(cols, bucket, (t >= 2.0) & (t <= 25.0)), comment="slow raster")
    saved = Path(mdf.save(path, overwrite=True))
    mdf.close()
    if saved != path:  # asammdf names an MDF 3 file .mdf: give it the name asked for
        saved.replace(path)
    return path


def _mapping(tmp_path: Path, text: str = MAPPING):
    (tmp_path / "mdf.toml").write_text(text)
    return parse_mapping(tomllib.loads(text), path=tmp_path / "mdf.toml")


def _csv_reference(tmp_path: Path, cols: dict[str, np.ndarray], keep: np.ndarray | None = None):
    sel = {k: v if keep is None else v[keep] for k, v in cols.items()}
    log = arm3_plant.write_csv(tmp_path / "ref.csv", sel)
    return convert_log(log, parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML))).episodes[0]


def test_mdf_matches_csv(cli, tmp_path, short_cols):
    """API and CLI: an MDF4 log gives the episode the CSV of the same data gives."""
    log = write_mdf(tmp_path / "run01.mf4", short_cols)
    mapping = _mapping(tmp_path)
    res = convert_log(log, mapping)
    assert res.entry["kind"] == "mdf" and res.entry["origin"].startswith("20")
    ep, ref = res.episodes[0], _csv_reference(tmp_path, short_cols)
    assert ep.name == "run01" and ep.n_step == ref.n_step
    np.testing.assert_allclose(ep.theta, ref.theta, atol=1e-5)  # CSV: 6 digits
    np.testing.assert_allclose(ep.u, ref.u, atol=1e-2)
    rc, text, err = cli("import", log, "--mapping", tmp_path / "mdf.toml", "--dry-run", "--quiet")
    assert rc == 0, err
    assert "run01.mf4" in text


def test_mdf3_dat_matches_mdf4(cli, tmp_path, short_cols):
    """An MDF 3 log saved as ``.dat`` (CANape, INCA) gives the MDF4 log's episode; a folder's
    other ``.dat`` files are left out, and one given by name is refused in one line."""
    mapping = _mapping(tmp_path)
    logs = tmp_path / "logs"
    logs.mkdir()
    dat = write_mdf(logs / "run01.dat", short_cols, version="3.30")
    assert dat.read_bytes()[:8] == b"MDF     "
    (logs / "notes.dat").write_text("operator: A. N. Other\n")
    ref = convert_log(write_mdf(tmp_path / "run01.mf4", short_cols), mapping).episodes[0]
    res = convert_log(dat, mapping)
    ep = res.episodes[0]
    assert res.entry["kind"] == "mdf" and ep.name == "run01" and ep.n_step == ref.n_step
    np.testing.assert_allclose(ep.theta, ref.theta, atol=1e-7)
    np.testing.assert_allclose(ep.u, ref.u, atol=1e-4)
    rc, text, err = cli("import", logs, "--mapping", tmp_path / "mdf.toml", "--dry-run")
    assert rc == 0, err
    assert "run01.dat" in text and "notes.dat" not in text
    err = _fail(cli, tmp_path, logs / "notes.dat")
    assert "notes.dat: a .dat file that is not an ASAM MDF log" in err


def test_mdf_channel_units_against_the_mapping(cli, tmp_path, short_cols):
    """The units an MDF log gives its channels are checked against the mapping: the same
    unit under another label passes; an angle the log says is in rad, mapped as deg, is one
    line naming both; a length mapped as an angle says to map a linear joint; ``--log-units
    ignore`` (a log whose labels are wrong) imports it."""
    _mapping(tmp_path)
    same = {"boom_deg": "°", "arm_deg": "Degrees", "boom_up_pct": "rad"}  # a command: unchecked
    log = write_mdf(tmp_path / "same.mf4", short_cols, units=same)
    rc, _, err = cli("import", log, "--mapping", tmp_path / "mdf.toml", "--dry-run", "--quiet")
    assert rc == 0, err
    write_mdf(tmp_path / "rad.mf4", short_cols, units={"arm_deg": "rad"})
    err = _fail(cli, tmp_path, tmp_path / "rad.mf4")
    assert "column 'arm_deg': the log gives this channel the unit 'rad', the mapping 'deg'" in err
    assert "set unit = \"rad\" in the angle of joint 'arm'" in err
    assert '[import] log_units = "ignore"' in err
    write_mdf(tmp_path / "mm.mf4", short_cols, units={"boom_deg": "mm"})
    err = _fail(cli, tmp_path, tmp_path / "mm.mf4")
    assert "the log measures a length: map the position of joint 'boom' as a linear joint" in err
    rc, _, err = cli(
        "import",
        tmp_path / "rad.mf4",
        "--mapping",
        tmp_path / "mdf.toml",
        "--dry-run",
        "--quiet",
        "--log-units",
        "ignore",
    )
    assert rc == 0, err


@pytest.mark.parametrize("limits", ["", "limits = [0.25, 2.03]\n"])
def test_a_stroke_labelled_mm_mapped_as_m_names_both_units(cli, tmp_path, short_cols, limits):
    """A log whose stroke channel says mm, mapped in m: the one line names both units and
    the fix, with or without limits (the values, 1000x the metres, had been screened first:
    'impossible' or 'outside the declared limits', 'set outliers = "drop" or "clip"')."""
    boom = (
        '[[joints]]\nname = "boom"\n'
        + limits
        + 'position = { column = "boom_deg", unit = "m" }\n'
        + 'command = { up = "boom_up_pct", down = "boom_down_pct", unit = "%", '
        + "range = [-1000.0, 1000.0] }\n"
    )
    start = MAPPING.index('[[joints]]\nname = "boom"')
    end = MAPPING.index('[[joints]]\nname = "arm"')
    _mapping(tmp_path, MAPPING[:start] + boom + "\n" + MAPPING[end:])
    cols = {k: v.copy() for k, v in short_cols.items()}
    cols["boom_deg"] = 1000.0 + 10.0 * cols["boom_deg"]  # a stroke in mm
    log = write_mdf(tmp_path / "mm.mf4", cols, units={"boom_deg": "mm"})
    err = _fail(cli, tmp_path, log)
    assert (
        "mm.mf4, column 'boom_deg': the log gives this channel the unit 'mm', the mapping 'm' "
        "(set unit = \"mm\" in the position of joint 'boom' in mdf.toml; if the log's label "
        'is wrong, set [import] log_units = "ignore")'
    ) in err, err


def test_mdf_channel_units_survive_dropped_outliers(cli, tmp_path, short_cols):
    """Rows dropped as outliers keep the log's unit labels: a channel the log says is in
    rad, mapped as deg, is the same one-line error with one spike and ``--outliers drop``
    (the rebuilt table had lost its units, and the angles were stored 57.3x too small;
    audit 1, D3)."""
    _mapping(tmp_path)
    cols = {k: v.copy() for k, v in short_cols.items()}
    cols["arm_deg"][300] = 36000.0
    log = write_mdf(tmp_path / "spike.mf4", cols, units={"arm_deg": "rad"})
    err = import_fails(cli, log, tmp_path / "mdf.toml", tmp_path / "X", "--outliers", "drop")
    assert "column 'arm_deg': the log gives this channel the unit 'rad', the mapping 'deg'" in err


def test_mdf_two_channel_groups(tmp_path, short_cols):
    """Channels in two channel groups: each group a series on its own master, the episode on
    the span both cover."""
    log = write_mdf(tmp_path / "two.mf4", short_cols, split_bucket=True)
    res = convert_log(log, _mapping(tmp_path))
    t = short_cols["t_ms"] * 1e-3
    keep = (t >= 2.0) & (t <= 25.0)
    ref = _csv_reference(tmp_path, short_cols, keep)
    ep = res.episodes[0]
    assert ep.n_step == ref.n_step
    np.testing.assert_allclose(ep.theta, ref.theta, atol=1e-5)
    np.testing.assert_allclose(ep.u, ref.u, atol=1e-2)
    assert res.entry["series"]["channel group 0"]["duration_s"] == pytest.approx(t[-1], abs=1e-3)
    assert res.entry["series"]["channel group 1"]["duration_s"] == pytest.approx(
        t[keep][-1] - t[keep][0], abs=1e-3
    )


def _fail(cli, tmp_path: Path, log: Path) -> str:
    return import_fails(cli, log, tmp_path / "mdf.toml", tmp_path / "ds")


def test_mdf_errors(cli, tmp_path, short_cols):
    _mapping(tmp_path)
    # a mapped channel that the file lacks
    mdf = asammdf.MDF(version="4.10")
    names = [c for c in arm3_plant.LOG_COLUMNS if c not in ("t_ms", "arm_deg")]
    mdf.append(_signals(short_cols, names))
    mdf.save(tmp_path / "missing.mf4", overwrite=True)
    mdf.close()
    err = _fail(cli, tmp_path, tmp_path / "missing.mf4")
    assert "column 'arm_deg': mapped column is missing" in err and "boom_deg" in err
    # the same name in two groups, without sources that tell them apart
    mdf = asammdf.MDF(version="4.10")
    mdf.append(_signals(short_cols, [c for c in arm3_plant.LOG_COLUMNS if c != "t_ms"]))
    mdf.append(_signals(short_cols, ["boom_deg"]))
    mdf.save(tmp_path / "twice.mf4", overwrite=True)
    mdf.close()
    err = _fail(cli, tmp_path, tmp_path / "twice.mf4")
    assert "column 'boom_deg': channel name is ambiguous: 2 channel groups hold it" in err
    assert "groups group 0, group 1; rename it" in err
    # two channel groups that share no time span (the reader had raised an IndexError)
    mdf = asammdf.MDF(version="4.10")
    t = short_cols["t_ms"] * 1e-3
    mdf.append(_signals(short_cols, [c for c in arm3_plant.LOG_COLUMNS[1:] if c != "arm_deg"]))
    mdf.append([asammdf.Signal(short_cols["arm_deg"], t + 20.0, name="arm_deg")])
    mdf.save(tmp_path / "apart.mf4", overwrite=True)
    mdf.close()
    err = _fail(cli, tmp_path, tmp_path / "apart.mf4")
    assert "the channel groups share no gap-free time span" in err
    # a truncated file
    good = write_mdf(tmp_path / "good.mf4", short_cols).read_bytes()
    (tmp_path / "cut.mf4").write_bytes(good[: len(good) // 2])
    err = _fail(cli, tmp_path, tmp_path / "cut.mf4")
    assert "cut.mf4: not a readable MDF file" in err and "truncated" in err


def test_mdf_ambiguous_names_with_sources(cli, tmp_path, short_cols):
    """Channels with a source are told apart by ``<source path>.<name>``, which the error lists."""
    from asammdf.blocks.source_utils import Source

    def src(bus: str) -> Source:
        return Source(
            name="ecu",
            path=bus,
            comment="",
            source_type=Source.SOURCE_ECU,
            bus_type=Source.BUS_TYPE_CAN,
        )

    t = short_cols["t_ms"] * 1e-3
    names = [c for c in arm3_plant.LOG_COLUMNS if c != "t_ms"]
    mdf = asammdf.MDF(version="4.10")
    mdf.append([asammdf.Signal(short_cols[n], t, name=n, source=src("CAN1")) for n in names])
    mdf.append(
        [asammdf.Signal(short_cols["boom_deg"] + 1.0, t, name="boom_deg", source=src("CAN2"))]
    )
    mdf.save(tmp_path / "src.mf4", overwrite=True)
    mdf.close()
    _mapping(tmp_path)
    err = _fail(cli, tmp_path, tmp_path / "src.mf4")
    assert "map one of 'CAN1.boom_deg', 'CAN2.boom_deg'" in err
    fixed = _mapping(tmp_path, MAPPING.replace('column = "boom_deg"', 'column = "CAN1.boom_deg"'))
    ep = convert_log(tmp_path / "src.mf4", fixed).episodes[0]
    np.testing.assert_allclose(ep.theta, _csv_reference(tmp_path, short_cols).theta, atol=1e-5)


def test_mdf_rasters_each_on_its_own_master(tmp_path, short_cols):
    """A 10 Hz group beside the 100 Hz one keeps its own times and samples (floats and
    integers); the import resamples each channel from them."""
    from excavator_surrogate.ingest.readers import read_log

    t = short_cols["t_ms"] * 1e-3
    t_slow = np.arange(0.5, 9.0, 0.1)
    gear = (np.arange(t_slow.size) // 7 % 3 + 1).astype(np.int8)
    rpm = 1000.0 + 10.0 * np.arange(t_slow.size)
    mdf = asammdf.MDF(version="4.10")
    mdf.append(_signals(short_cols, [c for c in arm3_plant.LOG_COLUMNS if c != "t_ms"]))
    mdf.append([asammdf.Signal(gear, t_slow, name="gear"), asammdf.Signal(rpm, t_slow, name="rpm")])
    mdf.save(tmp_path / "rasters.mf4", overwrite=True)
    mdf.close()
    text = MAPPING + (
        '[[inputs]]\nname = "gear"\ncolumn = "gear"\nunit = "physical"\nrange = [1.0, 3.0]\n'
        '[[inputs]]\nname = "engine_rpm"\ncolumn = "rpm"\nunit = "physical"\nrange = [800.0, 2200.0]\n'
    )
    raw = read_log(tmp_path / "rasters.mf4", _mapping(tmp_path, text))
    fast, slow = raw.series["channel group 0"], raw.series["channel group 1"]
    np.testing.assert_allclose(fast.time, t - t[0])
    np.testing.assert_array_equal(fast.values["boom_deg"], short_cols["boom_deg"])
    np.testing.assert_allclose(slow.time, t_slow - t[0])
    np.testing.assert_array_equal(slow.values["gear"], gear)
    np.testing.assert_array_equal(slow.values["rpm"], rpm)
    assert {c.key: g for c, g in raw.placement.items()}["rpm"] == "channel group 1"
    # and through the import: the inputs are u columns 3 and 4
    ep = convert_log(tmp_path / "rasters.mf4", _mapping(tmp_path, text)).episodes[0]
    assert ep.spec.u_names == (*arm3_plant.JOINTS, "gear", "engine_rpm")
    assert ep.u.shape == (ep.n_step, 5) and ep.u[:, 3].min() >= 1.0 and ep.u[:, 3].max() <= 3.0


def test_mdf_needs_asammdf(tmp_path, short_cols, monkeypatch):
    from excavator_surrogate.errors import ConfigError
    from excavator_surrogate.ingest import mdf as mdf_reader

    log = write_mdf(tmp_path / "a.mf4", short_cols)
    real = mdf_reader.importlib.util.find_spec
    monkeypatch.setattr(
        mdf_reader.importlib.util,
        "find_spec",
        lambda name, *a: None if name == "asammdf" else real(name, *a),
    )
    with pytest.raises(ConfigError, match="pip install 'excavator-surrogate\\[mdf\\]'"):
        convert_log(log, _mapping(tmp_path))


def _one_group(path: Path, cols: dict[str, np.ndarray], arm: object) -> Path:
    """An MDF4 log whose ``arm_deg`` is the Signal ``arm`` (the other channels as usual)."""
    mdf = asammdf.MDF(version="4.10")
    names = [c for c in arm3_plant.LOG_COLUMNS if c not in ("t_ms", "arm_deg")]
    mdf.append([*_signals(cols, names), arm])
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def test_mdf_channel_errors(cli, tmp_path, short_cols):
    """A text channel, a channel group without samples and damaged compressed samples: one
    line each, naming the file and the channel."""
    _mapping(tmp_path)
    t = short_cols["t_ms"] * 1e-3
    text = asammdf.Signal(np.array([b"abc"] * t.size), t, name="arm_deg", encoding="utf-8")
    err = _fail(cli, tmp_path, _one_group(tmp_path / "text.mf4", short_cols, text))
    assert "text.mf4, column 'arm_deg': values are of type |S3 (shape (1000,)), not numbers" in err
    assert "(map a numeric channel)" in err
    mdf = asammdf.MDF(version="4.10")
    mdf.append(_signals(short_cols, [c for c in arm3_plant.LOG_COLUMNS[1:] if c != "arm_deg"]))
    mdf.append([asammdf.Signal(np.zeros(0), np.zeros(0), name="arm_deg")])
    mdf.save(tmp_path / "empty.mf4", overwrite=True)
    mdf.close()
    err = _fail(cli, tmp_path, tmp_path / "empty.mf4")
    assert "empty.mf4, column 'arm_deg': the channel has no samples (map a recorded channel)" in err
    # deflated data blocks (asammdf's compression=2) with a run of zeros in the first one:
    # the file opens, its samples cannot be read
    mdf = asammdf.MDF(version="4.10")
    mdf.append(_signals(short_cols, list(arm3_plant.LOG_COLUMNS[1:])))
    mdf.save(tmp_path / "z.mf4", overwrite=True, compression=2)
    mdf.close()
    blob = bytearray((tmp_path / "z.mf4").read_bytes())
    at = blob.index(b"##DZ")
    blob[at + 80 : at + 200] = bytes(120)
    (tmp_path / "damaged.mf4").write_bytes(bytes(blob))
    err = _fail(cli, tmp_path, tmp_path / "damaged.mf4")
    assert "damaged.mf4, column 'boom_deg': cannot read the samples (" in err
    assert "record or export it again" in err


def test_mdf_invalid_samples_become_missing(cli, tmp_path, short_cols):
    """Samples flagged invalid are NaN at their rows (the log keeps its rows); the import
    names the first one and the fix."""
    from excavator_surrogate.ingest.readers import read_log

    t = short_cols["t_ms"] * 1e-3
    bad = np.zeros(t.size, dtype=bool)
    bad[100:110] = True
    arm = asammdf.Signal(short_cols["arm_deg"], t, name="arm_deg", invalidation_bits=bad)
    log = _one_group(tmp_path / "inv.mf4", short_cols, arm)
    raw = read_log(log, _mapping(tmp_path))
    values = raw.series["channel group 0"].values
    assert raw.series["channel group 0"].time.size == t.size
    np.testing.assert_array_equal(np.flatnonzero(np.isnan(values["arm_deg"])), np.arange(100, 110))
    np.testing.assert_array_equal(values["boom_deg"], short_cols["boom_deg"])
    err = _fail(cli, tmp_path, log)
    assert "inv.mf4, column 'arm_deg', row 100: missing or non-finite value" in err
    assert "--nan fill" in err


def test_mdf_invalid_samples_of_a_slower_group_stay_on_its_rows(cli, tmp_path, short_cols):
    """Invalid samples in a 50 Hz group beside the 100 Hz one are counted and filled on their
    own group's rows (5 samples pass --max-fill 5) and never reach a value: they had been
    interpolated onto the other group's master (10 rows missing at the master's row 100, and
    the garbage of the invalid samples half in their valid neighbours)."""
    from excavator_surrogate.ingest.readers import read_log

    t = short_cols["t_ms"] * 1e-3
    slow = np.arange(0, t.size, 2)
    arm = short_cols["arm_deg"][slow].copy()
    bad = np.zeros(slow.size, dtype=bool)
    bad[50:55] = True
    filled = arm.copy()  # the invalid samples filled as --nan fill does: linearly
    filled[bad] = np.interp(t[slow][bad], t[slow][~bad], arm[~bad])
    arm[bad] = -500.0  # what an invalid sample holds is garbage

    def write(name: str, arm: np.ndarray, **flags: np.ndarray) -> Path:
        mdf = asammdf.MDF(version="4.10")
        names = [c for c in arm3_plant.LOG_COLUMNS[1:] if c != "arm_deg"]
        mdf.append(_signals(short_cols, names))
        mdf.append([asammdf.Signal(arm, t[slow], name="arm_deg", **flags)])
        log = Path(mdf.save(tmp_path / name, overwrite=True))
        mdf.close()
        return log

    log = write("slow.mf4", arm, invalidation_bits=bad)
    mapping = _mapping(tmp_path)
    err = _fail(cli, tmp_path, log)
    assert "slow.mf4, column 'arm_deg', row 50: missing or non-finite value" in err
    res = convert_log(log, mapping, options=replace(mapping.options, nan="fill", max_fill=5))
    assert res.entry["filled"] == {"arm_deg": {"values": 5, "runs": 1}}
    ref = convert_log(write("filled.mf4", filled), mapping).episodes[0]
    np.testing.assert_allclose(res.episodes[0].theta, ref.theta, atol=1e-12)
    s = read_log(log, mapping).series["channel group 1"]
    np.testing.assert_array_equal(np.flatnonzero(np.isnan(s.values["arm_deg"])), np.arange(50, 55))
    np.testing.assert_array_equal(s.values["arm_deg"][~bad], arm[~bad])


def test_mdf_gap_in_a_smaller_group_splits(tmp_path, short_cols):
    """A logger pause in one channel group (the bucket's, 4-6 s) cuts the episodes there, as
    the CSV of the same samples does: it had been bridged by interpolation onto the other
    group's master, one episode with a straight line across the pause."""
    t = short_cols["t_ms"] * 1e-3
    keep = (t < 4.0) | (t >= 6.0)
    mdf = asammdf.MDF(version="4.10")
    bucket = [n for n in arm3_plant.LOG_COLUMNS if n.startswith("bucket")]
    mdf.append(_signals(short_cols, [n for n in arm3_plant.LOG_COLUMNS[1:] if n not in bucket]))
    mdf.append(_signals(short_cols, bucket, keep))
    log = Path(mdf.save(tmp_path / "gap.mf4", overwrite=True))
    mdf.close()
    res = convert_log(log, _mapping(tmp_path))
    ref = convert_log(
        arm3_plant.write_csv(tmp_path / "gap.csv", {k: v[keep] for k, v in short_cols.items()}),
        parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML)),
    )
    assert [e.name for e in res.episodes] == ["gap_s0", "gap_s1"]
    assert [e.name for e in ref.episodes] == ["gap_s0", "gap_s1"]
    assert any(
        n.startswith("channel group 1: gap of 2 s after row 400") for n in res.entry["notes"]
    )
    for ep, r in zip(res.episodes, ref.episodes):
        assert ep.n_step == r.n_step
        np.testing.assert_allclose(ep.time, r.time, atol=1e-9)
        np.testing.assert_allclose(ep.theta, r.theta, atol=1e-5)  # CSV: 6 digits
        np.testing.assert_allclose(ep.u, r.u, atol=1e-2)


def test_mdf_periodic_angle_in_a_slower_group(tmp_path):
    """A swing at 50 Hz that wraps at +-180 deg, beside a 100 Hz command: imported whole, as
    its CSV is (it had been interpolated linearly through the wrap onto the command's master,
    a 360 deg turn in 10 ms that the import refused as impossible)."""
    ta, tb = np.arange(0, 20, 0.02), np.arange(0, 20, 0.01)
    swing = (150 + 5.0 * ta + 180) % 360 - 180  # 5 deg/s, wraps at t = 6 s
    mdf = asammdf.MDF(version="4.10")
    mdf.append([asammdf.Signal(swing, ta, name="swing_deg", unit="deg")])
    mdf.append([asammdf.Signal(np.full(tb.shape, 30.0), tb, name="u", unit="%")])
    log = Path(mdf.save(tmp_path / "wrap.mf4", overwrite=True))
    mdf.close()
    text = (
        '[machine]\nname = "m"\nrate_hz = 20.0\n[time]\ncolumn = "t"\nunit = "s"\n'
        '[[joints]]\nname = "swing"\nperiodic = true\n'
        'angle = { column = "swing_deg", unit = "deg" }\ncommand = { column = "u", unit = "%" }\n'
    )
    res = convert_log(log, _mapping(tmp_path, text))
    (tmp_path / "wrap.csv").write_text(
        "t,swing_deg,u\n" + "".join(f"{x:.10g},{a:.10g},30\n" for x, a in zip(ta, swing))
    )
    ref = convert_log(tmp_path / "wrap.csv", _mapping(tmp_path, text)).episodes[0]
    (ep,) = res.episodes
    assert res.entry["outliers"] == {} and ep.n_step == ref.n_step
    np.testing.assert_allclose(ep.theta, ref.theta, atol=1e-9)
    np.testing.assert_allclose(np.diff(ep.theta[:, 0]), np.deg2rad(5.0) / 20, atol=1e-6)


def test_an_unreadable_dat_file_is_not_taken_for_mdf(cli, tmp_path, short_cols):
    """A .dat file that cannot be opened (a dangling link) is not an MDF log: a folder's is
    left out."""
    from excavator_surrogate.ingest.mdf import is_mdf

    logs = tmp_path / "logs"
    logs.mkdir()
    write_mdf(logs / "run01.mf4", short_cols)
    (logs / "gone.dat").symlink_to(tmp_path / "nowhere.dat")
    assert not is_mdf(logs / "gone.dat")
    _mapping(tmp_path)
    rc, text, err = cli("import", logs, "--mapping", tmp_path / "mdf.toml", "--dry-run")
    assert rc == 0, err
    assert "run01.mf4" in text and "gone.dat" not in text


def test_mdf_header_metadata_of_every_comment():
    """MDF 3 plain text, MDF4 XML (nested trees; unnamed and unknown elements skipped),
    and text that only looks like XML."""
    from types import SimpleNamespace

    from excavator_surrogate.ingest.mdf import header_metadata

    plain = SimpleNamespace(comment="  Rig 2, operator A \n", author="A. N. Other", project=None)
    assert header_metadata(plain) == {"comment": "Rig 2, operator A", "author": "A. N. Other"}
    assert header_metadata(SimpleNamespace(comment="<rig 2 & co")) == {"comment": "<rig 2 & co"}
    xml = (
        "<HDcomment><TX> run 7 </TX><common_properties>"
        '<e name="Mode">H</e><e>unnamed</e><li name="x">list</li>'
        '<tree name="Engine"><e name="rpm">1800</e></tree>'
        "</common_properties></HDcomment>"
    )
    got = header_metadata(SimpleNamespace(comment=xml, author="", subject="soil"))
    assert got == {"comment": "run 7", "Mode": "H", "Engine/rpm": "1800", "subject": "soil"}
    assert header_metadata(SimpleNamespace(comment="<HDcomment/>")) == {}
    assert header_metadata(SimpleNamespace(comment=" ")) == {}
