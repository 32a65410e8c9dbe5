"""Good logs: round trip of the 3-joint arm, a 6-joint machine, gaps, NaN fill, splits, formats."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_surrogate.data import load_dataset, read_manifest
from excavator_surrogate.ingest import convert_log, load_mapping, parse_mapping
from tests.helpers import arm3_plant
from tests.helpers.ingest import assert_nothing_written, write_lines


def _truth(cols: dict[str, np.ndarray], joint: str, t: np.ndarray) -> np.ndarray:
    return np.radians(np.interp(t, cols["t_ms"] * 1e-3, cols[f"{joint}_true_deg"]))


def test_round_trip_arm3(cli, arm3_dir, tmp_path):
    out = tmp_path / "ds"
    rc, text, err = cli(
        "import", arm3_dir / "logs", "--mapping", arm3_dir / "arm3.toml", "--out", out
    )
    assert rc == 0, err
    assert "# exsur import: arm3" in text and "run04.csv.gz" in text
    ds = load_dataset(out, min_steps=40)
    assert ds.spec.names == ("boom", "arm", "bucket") and ds.spec.rate_hz == 20.0
    assert ds.spec.joints[0].theta_min == pytest.approx(math.radians(-40.0))
    eps = ds.train + ds.val + ds.test
    assert sorted(e.name for e in eps) == ["run01", "run02", "run03", "run04"]
    assert all(len(ds.split(s)) >= 1 for s in ("train", "val", "test"))
    for ep in eps:
        seed = int(ep.name[-2:]) - 1
        cols = arm3_plant.simulate(duration_s=30.0, seed=seed)
        assert ep.n_step == 598 and np.allclose(np.diff(ep.time), 0.05)
        # the angle sample k is the angle at t_k (noise filtered, no delay)
        for i, j in enumerate(arm3_plant.JOINTS):
            err_rms = np.sqrt(np.mean((ep.theta[:, i] - _truth(cols, j, ep.time)) ** 2))
            assert err_rms < math.radians(0.05), (ep.name, j, err_rms)
        # omega[k] is the mean velocity over [t_{k-1}, t_k]: the backward difference
        np.testing.assert_allclose(ep.omega[1:], np.diff(ep.theta, axis=0) / ep.dt, atol=1e-9)
        # u[k] is the mean of the held command over [t_k, t_{k+1})
        k = 100
        t_fine = np.linspace(ep.time[k], ep.time[k] + ep.dt, 2001)[:-1]
        t_log = cols["t_ms"] * 1e-3
        idx = np.searchsorted(t_log, t_fine, side="right") - 1
        duty = cols["boom_up_pct"][idx] - cols["boom_down_pct"][idx]
        assert ep.u[k, 0] == pytest.approx(10.0 * duty.mean(), abs=2.0)
        assert ep.source == "import" and ep.extra["import"]["velocity"]["boom"] == "diff"
    rep = json.loads((out / "import_report.json").read_text())
    assert rep["totals"]["files_imported"] == 4 and rep["totals"]["rows_in"] == 12000
    assert (out / "import_report.md").read_text() == text
    manifest = read_manifest(out)
    assert manifest["source"] == "import" and manifest["spec"]["name"] == "arm3"
    assert tomllib.loads((out / "config.toml").read_text())["mapping"]["machine"]["name"] == "arm3"
    # the dataset passes 'exsur validate'; a second import replaces it
    assert cli("validate", out)[0] == 0
    rc, _, err = cli(
        "import",
        arm3_dir / "logs" / "run01.csv",
        "--mapping",
        arm3_dir / "arm3.toml",
        "--out",
        out,
    )
    assert rc == 0, err
    assert len(read_manifest(out)["episodes"]) == 1


def test_dry_run_writes_nothing(cli, arm3_dir, tmp_path):
    rc, text, err = cli(
        "import", arm3_dir / "logs" / "run01.csv", "--mapping", arm3_dir / "arm3.toml", "--dry-run"
    )
    assert rc == 0, err
    assert "Dry run: nothing written." in text
    rc, _, err = cli("import", arm3_dir / "logs" / "run01.csv", "--mapping", arm3_dir / "arm3.toml")
    assert rc == 2 and "--out DIR is required" in err


def test_gap_splits_episode_same_split(cli, work, arm3_dir):
    cols = arm3_plant.simulate(duration_s=30.0, seed=11)
    t = cols["t_ms"] * 1e-3
    keep = (t < 12.0) | (t > 14.0)
    write_lines(work / "logs" / "gappy.csv", {k: v[keep] for k, v in cols.items()})
    for i in range(3):
        write_lines(
            work / "logs" / f"plain{i}.csv", arm3_plant.simulate(duration_s=10.0, seed=20 + i)
        )
    out = work / "ds"
    rc, text, err = cli(
        "import",
        work / "logs",
        "--mapping",
        work / "arm3.toml",
        "--out",
        out,
        "--fractions",
        "0.25,0.25,0.5",
    )
    assert rc == 0, err
    manifest = read_manifest(out)
    by_name = {Path(e["file"]).stem: e for e in manifest["episodes"]}
    assert {"gappy_s0", "gappy_s1"} <= set(by_name)
    assert by_name["gappy_s0"]["split"] == by_name["gappy_s1"]["split"]
    ds = load_dataset(out)
    eps = {e.name: e for s in ("train", "val", "test") for e in ds.split(s)}
    assert eps["gappy_s0"].time[-1] <= 12.0 and eps["gappy_s1"].time[0] >= 14.0
    rep = json.loads((out / "import_report.json").read_text())
    gappy = next(f for f in rep["files"] if f["file"].endswith("gappy.csv"))
    assert any("gap of 2" in n and "split" in n for n in gappy["notes"])
    assert "1 gap split(s)" in text


def test_nan_fill_reports(cli, work, short_cols):
    cols = {k: v.copy() for k, v in short_cols.items()}
    cols["boom_deg"][[100, 101, 500]] = np.nan
    cols["arm_up_pct"][0] = np.nan  # at the start: held from the next value
    log = write_lines(work / "a.csv", cols)
    out = work / "ds"
    rc, _, err = cli(
        "import", log, "--mapping", work / "arm3.toml", "--out", out, "--nan", "fill", "--quiet"
    )
    assert rc == 0, err
    f = json.loads((out / "import_report.json").read_text())["files"][0]
    assert f["filled"] == {
        "boom_deg": {"values": 3, "runs": 2},
        "arm_up_pct": {"values": 1, "runs": 1},
    }


def test_nan_fill_takes_a_periodic_angle_the_short_way_through_its_wrap(tmp_path):
    """A swing's samples missing where it crosses +-180 deg are filled on its unwrapped angle
    (179.96, 179.98, 180.0 deg), not straight across the wrap (89.96, -0.02, -90 deg: a
    turn backwards in 30 ms that the burst screen then refused; audit 1, D2)."""
    t = np.arange(1000) * 0.01
    a = (170.0 + 2.0 * t + 180.0) % 360.0 - 180.0  # 2 deg/s, wraps at t = 5 s
    a[498:501] = np.nan
    log = tmp_path / "sw.csv"
    np.savetxt(
        log,
        np.column_stack([t, a, np.full_like(t, 10.0)]),
        delimiter=",",
        fmt="%.6f",
        header="t,a,u",
        comments="",
    )
    text = (
        '[machine]\nname = "m"\n[time]\ncolumn = "t"\nunit = "s"\n[import]\nnan = "fill"\n'
        'min_steps = 10\n[[joints]]\nname = "swing"\nperiodic = true\n'
        'angle = { column = "a", unit = "deg" }\ncommand = { column = "u", unit = "%" }\n'
    )
    res = convert_log(log, parse_mapping(tomllib.loads(text)))
    assert res.entry["filled"] == {"a": {"values": 3, "runs": 1}} and not res.entry["outliers"]
    (ep,) = res.episodes
    np.testing.assert_allclose(np.rad2deg(ep.theta[:, 0]), 170.0 + 2.0 * ep.time, atol=1e-3)


def test_datetime_time_column(work, short_cols):
    t0 = np.datetime64("2024-05-01T12:00:00", "us")
    stamps = [str(t0 + np.timedelta64(round(x * 1e3), "us")) + "Z" for x in short_cols["t_ms"]]
    cols = dict(short_cols)
    cols["stamp"] = np.zeros(len(stamps))
    log = write_lines(work / "a.csv", cols, columns=("stamp", *arm3_plant.LOG_COLUMNS[1:]))
    lines = log.read_text().splitlines()
    log.write_text(
        "\n".join([lines[0]] + [s + ln[ln.index(",") :] for s, ln in zip(stamps, lines[1:])]) + "\n"
    )
    text = (
        (work / "arm3.toml")
        .read_text()
        .replace('column = "t_ms"\nunit = "ms"', 'column = "stamp"\nunit = "datetime"')
    )
    mapping = parse_mapping(tomllib.loads(text), path=work / "dt.toml")
    res = convert_log(log, mapping)
    assert len(res.episodes) == 1 and res.episodes[0].n_step == 198
    assert res.entry["origin"].startswith("2024-05-01")
    ref = convert_log(
        write_lines(work / "b.csv", short_cols), load_mapping(work / "arm3.toml")
    ).episodes[0]
    np.testing.assert_allclose(res.episodes[0].theta, ref.theta, atol=1e-9)


@pytest.mark.parametrize("unit", ["ms", "datetime"])
def test_a_duration_time_column_is_read_in_its_own_unit(work, short_cols, unit):
    """pandas' Timedelta in Parquet (``duration[us]``): relative time whatever ``unit`` says."""
    arrays = {c: pa.array(short_cols[c]) for c in arm3_plant.LOG_COLUMNS}
    us = np.round(short_cols["t_ms"] * 1e3).astype(np.int64) + 7_000_000  # 7 s into a run
    arrays["t_ms"] = pa.array(us, type=pa.duration("us"))
    log = work / "d.parquet"
    pq.write_table(pa.table(arrays), log)
    text = (work / "arm3.toml").read_text().replace('unit = "ms"', f'unit = "{unit}"')
    res = convert_log(log, parse_mapping(tomllib.loads(text), path=work / "d.toml"))
    assert res.entry["origin"] == "7000000000 ns (a duration)"
    ref = convert_log(
        write_lines(work / "b.csv", short_cols), load_mapping(work / "arm3.toml")
    ).episodes[0]
    np.testing.assert_allclose(res.episodes[0].time, ref.time, atol=1e-12)
    np.testing.assert_allclose(res.episodes[0].theta, ref.theta, atol=1e-5)  # CSV: 6 digits


def _six_joint(
    tmp: Path, *, swing_vel_unit: str = "deg/s"
) -> tuple[Path, Path, dict[str, np.ndarray]]:
    """A 6-joint machine logged at 200 Hz in Parquet with a timestamp column."""
    rate = 200.0
    n = 4000
    rng = np.random.default_rng(3)
    t = np.arange(n) / rate + rng.uniform(-2e-4, 2e-4, n)
    t[0] = 0.0
    truth = {
        "swing": 0.6 * t + 0.3 * np.sin(0.7 * t),  # keeps turning: periodic
        "boom": 0.3 * np.sin(0.5 * t),
        "arm": 1.2 + 0.4 * np.sin(0.8 * t + 1),
        "bucket": 0.5 * np.sin(1.1 * t),
        "wrist": -2.0 * t,  # periodic, turns the other way
        "tilt": 0.2 * np.sin(0.3 * t),
    }
    rate_swing = 0.6 + 0.21 * np.cos(0.7 * t)
    rate_boom = 0.15 * np.cos(0.5 * t)
    cmd = np.sin(0.9 * t)
    wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    stamps = np.datetime64("2024-06-01T08:00:00", "ns") + (t * 1e9).astype("int64").astype(
        "timedelta64[ns]"
    )
    table = pa.table(
        {
            "stamp": pa.array(stamps, type=pa.timestamp("ns")),
            "swing_deg": np.degrees(wrap(truth["swing"])),
            "swing_rate": np.degrees(rate_swing) if swing_vel_unit == "deg/s" else rate_swing * 1.0,
            "boom_rad": truth["boom"],
            "boom_rate": rate_boom,
            "arm_rad": truth["arm"],
            "bucket_rad": truth["bucket"],
            "wrist_rad": wrap(truth["wrist"]),
            "tilt_mdeg": np.degrees(truth["tilt"]) * 1000.0,
            "swing_pct": 80.0 * cmd,
            "boom_counts": 2048.0 + 2000.0 * cmd,
            "arm_nm": 3.0e4 * cmd,
            "bucket_up": 50.0 * np.maximum(cmd, 0),
            "bucket_down": 50.0 * np.maximum(-cmd, 0),
            "wrist_pct": -30.0 * cmd,
            "tilt_bar": 100.0 + 50.0 * cmd,
        }
    )
    log = tmp / "six.parquet"
    pq.write_table(table, log)
    mapping = tmp / "six.toml"
    mapping.write_text(f"""
[machine]
name = "six"
rate_hz = 25.0
[time]
column = "stamp"
unit = "datetime"
[import]
min_steps = 20
[[joints]]
name = "swing"
periodic = true
angle = {{ column = "swing_deg", unit = "deg" }}
velocity = {{ column = "swing_rate", unit = "{swing_vel_unit}" }}
command = {{ column = "swing_pct", unit = "%", range = [-1.0, 1.0] }}
[[joints]]
name = "boom"
angle = {{ column = "boom_rad", unit = "rad" }}
velocity = {{ column = "boom_rate", unit = "rad/s" }}
command = {{ column = "boom_counts", unit = "raw", raw_range = [0.0, 4096.0], range = [-1000.0, 1000.0] }}
[[joints]]
name = "arm"
angle = {{ column = "arm_rad", unit = "rad" }}
command = {{ column = "arm_nm", unit = "physical", physical_unit = "Nm", range = [-5.0e4, 5.0e4] }}
[[joints]]
name = "bucket"
angle = {{ column = "bucket_rad", unit = "rad" }}
command = {{ up = "bucket_up", down = "bucket_down", unit = "%" }}
[[joints]]
name = "wrist"
periodic = true
angle = {{ column = "wrist_rad", unit = "rad" }}
command = {{ column = "wrist_pct", unit = "%" }}
[[joints]]
name = "tilt"
angle = {{ column = "tilt_mdeg", unit = "deg", scale = 0.001 }}
command = {{ column = "tilt_bar", unit = "physical", physical_unit = "bar", range = [0.0, 250.0] }}
""")
    return log, mapping, {**truth, "t": t, "cmd": cmd}


def test_six_joint_machine(cli, tmp_path):
    log, mapping, truth = _six_joint(tmp_path)
    out = tmp_path / "ds"
    rc, _, err = cli(
        "import",
        log,
        "--mapping",
        mapping,
        "--out",
        out,
        "--quiet",
        "--split-by",
        "glob",
        "--test",
        "six*",
    )
    assert rc == 0, err
    ds = load_dataset(out)
    spec = ds.spec
    assert spec.names == ("swing", "boom", "arm", "bucket", "wrist", "tilt")
    assert spec.periodic == (True, False, False, False, True, False)
    assert spec.rate_hz == 25.0 and spec.n_feature == 2 * 2 + 4 + 6
    assert [j.u_unit for j in spec.joints] == [
        "command",
        "command",
        "Nm",
        "command",
        "command",
        "bar",
    ]
    assert (spec.joints[0].u_min, spec.joints[0].u_max) == (-1.0, 1.0)
    (ep,) = ds.test
    t = ep.time
    for i, name in enumerate(spec.names):
        expect = np.interp(t, truth["t"], truth[name])
        offset = expect[0] - ep.theta[0, i]  # periodic joints: unwrapped, up to a multiple of 2π
        assert abs(offset - 2 * np.pi * round(offset / (2 * np.pi))) < 1e-3, name
        np.testing.assert_allclose(ep.theta[:, i] + offset, expect, atol=2e-3, err_msg=name)
    # no wrap jumps: the periodic angles are unwrapped
    assert np.all(np.abs(np.diff(ep.theta[:, 0])) < 0.1)
    assert ep.theta[-1, 0] > 2 * np.pi
    assert ep.theta[-1, 4] < -2 * np.pi
    # measured velocities: consistent with the angles; derived ones are exact backward differences
    diff = np.diff(ep.theta, axis=0) / ep.dt
    np.testing.assert_allclose(ep.omega[1:, :2], diff[:, :2], atol=5e-3)
    np.testing.assert_allclose(ep.omega[1:, 2:], diff[:, 2:], atol=1e-9)
    assert ep.extra["import"]["velocity"] == {
        "swing": "measured",
        "boom": "measured",
        "arm": "diff",
        "bucket": "diff",
        "wrist": "diff",
        "tilt": "diff",
    }
    cmd = np.interp(t + ep.dt / 2, truth["t"], truth["cmd"])  # mean over [t_k, t_k+1) ~ midpoint
    np.testing.assert_allclose(ep.u[:, 0], 0.8 * cmd, atol=0.01)
    np.testing.assert_allclose(ep.u[:, 1], (2048 + 2000 * cmd) / 4096 * 2000 - 1000, atol=5)
    np.testing.assert_allclose(ep.u[:, 2], 3e4 * cmd, atol=300)
    np.testing.assert_allclose(ep.u[:, 3], 500 * cmd, atol=5)
    np.testing.assert_allclose(ep.u[:, 5], 100 + 50 * cmd, atol=0.5)


def test_velocity_unit_mistake(cli, tmp_path):
    log, mapping, _ = _six_joint(tmp_path)
    mapping.write_text(mapping.read_text().replace('unit = "deg/s"', 'unit = "rad/s"'))
    rc, _, err = cli("import", log, "--mapping", mapping, "--out", tmp_path / "ds")
    assert rc == 2
    assert (
        "column 'swing_rate': measured velocity is 57.3x the angle's rate of change: looks like deg/s"
        in err
    )
    assert "set unit = \"deg/s\" in the velocity of joint 'swing' in six.toml" in err
    assert_nothing_written(tmp_path / "ds")


def test_split_by_glob_file_fraction(cli, arm3_dir, tmp_path):
    logs = arm3_dir / "logs"
    mp = arm3_dir / "arm3.toml"

    def splits(*args: str | Path) -> dict[str, str]:
        out = tmp_path / "ds"
        rc, _, err = cli("import", logs, "--mapping", mp, "--out", out, "--quiet", *args)
        assert rc == 0, err
        return {Path(e["file"]).stem: e["split"] for e in read_manifest(out)["episodes"]}

    got = splits("--val", "run02*", "--test", "*run04*")
    assert got == {"run01": "train", "run02": "val", "run03": "train", "run04": "test"}
    sf = tmp_path / "splits.toml"
    sf.write_text(
        'train = ["run03.csv", "run04.csv.gz"]\nval = ["run01.csv"]\ntest = ["run02.csv"]\n'
    )
    assert splits("--split-file", sf) == {
        "run01": "val",
        "run02": "test",
        "run03": "train",
        "run04": "train",
    }
    a = splits("--split-by", "fraction", "--fractions", "0.5,0.25,0.25", "--seed", "1")
    b = splits("--split-by", "fraction", "--fractions", "0.5,0.25,0.25", "--seed", "1")
    assert a == b and sorted(a.values()) == ["test", "train", "train", "val"]
    seeds = {tuple(sorted(splits("--seed", str(s)).items())) for s in range(4)}
    assert len(seeds) > 1  # the seed shuffles files
    # errors: a file in two splits, a file in none
    rc, _, err = cli(
        "import",
        logs,
        "--mapping",
        mp,
        "--out",
        tmp_path / "x",
        "--val",
        "run0[12]*",
        "--test",
        "*2.csv",
    )
    assert rc == 2 and "matches the val and test split patterns" in err
    sf.write_text('train = ["run03.csv"]\nval = ["run01.csv"]\ntest = ["run02.csv"]\n')
    rc, _, err = cli("import", logs, "--mapping", mp, "--out", tmp_path / "x", "--split-file", sf)
    assert rc == 2 and "run04.csv.gz: not listed in any split" in err
    assert_nothing_written(tmp_path / "x")
