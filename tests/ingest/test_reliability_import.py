"""Issue 17 on import: poisoned logs, a column mapped twice, inputs inside --out, leftovers."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.data import load_dataset, read_episode, write_episode
from excavator_surrogate.ingest import convert_log, parse_mapping
from excavator_surrogate.ingest.outliers import SPIKE_HALF_WINDOW, SPIKE_MAD, find_spikes
from excavator_surrogate.io_utils import mark_output
from tests.helpers.ingest import assert_nothing_written, set_cell, write_lines


def _fail(cli, *argv: object) -> str:
    rc, _, err = cli(*argv)
    assert rc == 2, err
    assert err.startswith("exsur: error: ") and err.count("\n") == 1, err
    return err


def _mapping(
    work: Path, name: str, extra_import: str = "", edit: tuple[str, str] = ("", "")
) -> Path:
    text = (work / "arm3.toml").read_text().replace(*edit)
    text = text.replace("[import]\n", f"[import]\n{extra_import}\n")
    (work / name).write_text(text)
    return work / name


# --- B1: spikes and joint limits ------------------------------------------------------------


@pytest.mark.parametrize("value", ["1e308", "36000"])
def test_b1_spike_is_an_error_naming_file_row_joint(cli, work, short_cols, value) -> None:
    log = write_lines(work / "a.csv", short_cols, lambda ls: set_cell(ls, 298, "boom_deg", value))
    out = work / "X"
    err = _fail(cli, "import", log, "--mapping", work / "arm3.toml", "--out", out, "--quiet")
    assert f"{log}, column 'boom_deg', row 298: joint 'boom': angle {float(value):g} deg" in err
    assert "is a spike" in err and '[import] outliers = "drop" or "clip"' in err
    assert_nothing_written(out)


def test_b1_sustained_out_of_limits_is_an_error(cli, work, short_cols) -> None:
    def offset(lines: list[str]) -> list[str]:
        for r in range(400, 460):  # 0.6 s at 100 Hz: no spike, a bad calibration
            v = float(lines[r + 1].split(",")[4])  # arm_deg
            lines = set_cell(lines, r, "arm_deg", f"{v + 200.0:.4f}")
        return lines

    log = write_lines(work / "a.csv", short_cols, offset)
    err = _fail(cli, "import", log, "--mapping", work / "arm3.toml", "--out", work / "X")
    assert "column 'arm_deg', row 400: joint 'arm': angle" in err
    assert "outside the declared limits [30 deg, 150 deg] (+5% of the range); 60 sample(s)" in err


def test_b1_drop_and_clip_policies_are_reported(cli, work, short_cols) -> None:
    def poison(lines: list[str]) -> list[str]:
        lines = set_cell(lines, 300, "boom_deg", "36000")
        for r in range(500, 510):
            lines = set_cell(lines, r, "bucket_deg", "170")  # above 140 + 5 % of 170
        return lines

    log = write_lines(work / "a.csv", short_cols, poison)
    for policy in ("drop", "clip"):  # drop from the mapping's [import] table, clip by flag
        if policy == "drop":
            m, flag = _mapping(work, "drop.toml", 'outliers = "drop"'), []
        else:
            m, flag = work / "arm3.toml", ["--outliers", "clip"]
        out = work / policy
        rc, stdout, err = cli("import", log, "--mapping", m, "--out", out, *flag)
        assert rc == 0, err
        report = json.loads((out / "import_report.json").read_text())
        counts = report["files"][0]["outliers"]
        assert counts["boom"] == {"spikes_dropped": 1}
        key = "out_of_limits_dropped" if policy == "drop" else "clipped"
        assert counts["bucket"] == {key: 10}
        assert "outliers boom: spikes dropped 1" in stdout
        ds = load_dataset(out)
        theta = np.concatenate([e.theta for s in ("train", "val", "test") for e in ds.split(s)])
        boom_max, _, bucket_max = np.rad2deg(theta.max(axis=0))
        assert boom_max < 60.0  # the 36000-degree spike is gone, not smeared
        assert bucket_max < 150.0  # 170 degrees never reach the dataset (clip: 140 + ringing)


def test_b1_clip_keeps_a_path_through_the_margin_whole(tmp_path) -> None:
    """A boom rising at 3 deg/s through its limit 100 deg to 110 deg: ``clip`` clips its
    whole excursion beyond the limit, the samples within the 5 % margin too, so the path
    meets the limit without a step (only the samples beyond 105 deg were clipped to 100, a
    5-degree drop and -62 deg/s in a rising path; audit 1, D4)."""
    t = np.arange(1000) * 0.01
    log = tmp_path / "c.csv"
    rows = np.column_stack([t, np.minimum(90.0 + 3.0 * t, 110.0), np.full_like(t, 10.0)])
    np.savetxt(log, rows, delimiter=",", fmt="%.6f", header="t,a,u", comments="")
    text = (
        '[machine]\nname = "m"\n[time]\ncolumn = "t"\nunit = "s"\n[import]\n'
        'outliers = "clip"\nmin_steps = 10\n[[joints]]\nname = "boom"\nlimits = [0.0, 100.0]\n'
        'angle = { column = "a", unit = "deg" }\ncommand = { column = "u", unit = "%" }\n'
    )
    res = convert_log(log, parse_mapping(tomllib.loads(text)))
    (ep,) = res.episodes
    theta, omega = np.rad2deg(ep.theta[:, 0]), np.rad2deg(ep.omega[:, 0])
    assert omega.min() > -1.0 and omega.max() < 3.5  # it rises at 3 deg/s, then stays
    assert theta.max() == pytest.approx(100.0, abs=0.05)
    assert res.entry["outliers"] == {"boom": {"clipped": 666}}  # every sample above 100


def test_b1_validate_rejects_a_poisoned_dataset(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols)
    out = work / "ds"
    assert cli("import", log, "--mapping", work / "arm3.toml", "--out", out, "--quiet")[0] == 0
    rc, stdout, _ = cli("validate", out)
    assert rc == 0 and ": ok," in stdout
    f = out / "episodes" / "a.parquet"
    ep = read_episode(f)
    theta = ep.theta.copy()
    theta[100:150, 0] = np.deg2rad(5105.0)  # like the smeared 36000-degree spike
    write_episode(f, ep.replace(theta=theta), validate=False)
    err = _fail(cli, "validate", out)
    assert f"{f}, column 'theta_boom', row 100: joint 'boom': angle" in err
    assert "in 50 sample(s)" in err
    assert _fail(cli, "validate", f) == err.replace(str(out / "episodes" / "a.parquet"), str(f))


def _spikes_loop(x: np.ndarray, dt: float) -> np.ndarray:
    """Plain-loop Hampel filter (the reference of :func:`find_spikes`)."""
    k = SPIKE_HALF_WINDOW
    xp = np.concatenate([x[k:0:-1], x, x[-2 : -k - 2 : -1]])  # mirrored ends
    out = np.zeros(x.shape[0], dtype=bool)
    for i in range(x.shape[0]):
        w = xp[i : i + 2 * k + 1]
        med = np.median(w)
        mad = np.median(np.abs(w - med))
        out[i] = abs(x[i] - med) > max(SPIKE_MAD * 1.4826 * mad, 10.0 * k * dt)
    return out


def test_find_spikes_matches_a_plain_loop_and_ignores_steps() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(600) * 0.01
    x = 0.5 * np.sin(t) + 1e-3 * rng.standard_normal(600)
    x[300:] += 0.8  # a step: the joint moved and stays (not a spike)
    x[[0, 100, 101, 450, 599]] += [2.0, 5.0, 5.0, -3.0, 1.0]
    got = find_spikes(x, 0.01)
    assert (got == _spikes_loop(x, 0.01)).all()
    assert np.flatnonzero(got).tolist() == [0, 100, 101, 450, 599]


# --- B2, W1, W2: mapping and CSV errors ------------------------------------------------------


def test_b2_column_mapped_to_two_joints(cli, work, short_cols) -> None:
    m = _mapping(work, "t.toml", edit=('column = "arm_deg"', 'column = "boom_deg"'))
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, "import", log, "--mapping", m, "--out", work / "X")
    assert (
        "t.toml: boom_deg is mapped to both the angle of joint 'boom' and the angle of joint 'arm'"
        in err
    )
    assert_nothing_written(work / "X")


def test_w1_other_delimiter_is_named(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols, lambda ls: [x.replace(",", ";") for x in ls])
    err = _fail(cli, "import", log, "--mapping", work / "arm3.toml", "--out", work / "X")
    assert "column 't_ms' is in the header, but separated by ';'" in err
    assert 'set [csv] delimiter = ";" in' in err


def test_w2_infinite_rate_is_a_config_error(cli, work, short_cols) -> None:
    m = _mapping(work, "r.toml", edit=("rate_hz = 20.0", "rate_hz = inf"))
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, "import", log, "--mapping", m, "--out", work / "X")
    assert "machine.rate_hz: expected a finite number, got inf" in err


# --- B4, B3: the output folder --------------------------------------------------------------


def test_b4_mapping_inside_out_is_refused(cli, work, arm3_dir) -> None:
    x = work / "X"
    (x / "logs").mkdir(parents=True)
    shutil.copy(arm3_dir / "logs" / "run01.csv", x / "logs")
    shutil.copy(work / "arm3.toml", x / "map.toml")
    for extra in ((), ("--overwrite",)):
        err = _fail(
            cli,
            "import",
            arm3_dir / "logs" / "run02.csv",
            "--mapping",
            x / "map.toml",
            "--out",
            x,
            *extra,
        )
        assert f"{x / 'map.toml'}: this input lies inside --out {x}" in err
    assert sorted(p.name for p in x.iterdir()) == ["logs", "map.toml"]
    assert (x / "logs" / "run01.csv").is_file()


def test_b3_overwrite_replaces_a_foreign_folder(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols)
    d = work / "D"
    d.mkdir()
    (d / "precious.txt").write_text("x")
    err = _fail(cli, "import", log, "--mapping", work / "arm3.toml", "--out", d)
    assert "holds 'precious.txt'" in err and (d / "precious.txt").exists()
    rc, _, err = cli(
        "import", log, "--mapping", work / "arm3.toml", "--out", d, "--overwrite", "--quiet"
    )
    assert rc == 0, err
    assert not (d / "precious.txt").exists() and (d / "manifest.json").is_file()


# --- W4: leftovers of a killed import -------------------------------------------------------


def test_w4_killed_import_leftovers_are_removed_next_time(cli, work, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols)
    pid = int(
        subprocess.run(
            [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
        ).stdout
    )
    stale = [
        work / f".ds.{pid}-k2j4h5g6.tmp",
        work / f"..ds.{pid}-k2j4h5g6.tmp.{pid}-a1b2c3d4.tmp",  # what kill -9 left: nested temps
    ]
    live = work / f".ds.{os.getpid()}-running0.tmp"
    kept = work / ".ds.legacy12.tmp"  # no pid: not known to be exsur's
    for p in (*stale, live, kept):
        (p / "episodes").mkdir(parents=True)
    for p in stale:
        mark_output(p, "dataset")  # exsur's writers mark a temporary folder first
    rc, _, err = cli(
        "import", log, "--mapping", work / "arm3.toml", "--out", work / "ds", "--quiet"
    )
    assert rc == 0, err
    assert not any(p.exists() for p in stale) and live.exists() and kept.exists()


def test_b1_drop_everything_is_an_error(cli, work, short_cols) -> None:
    m = _mapping(
        work,
        "off.toml",
        'outliers = "drop"',
        edit=("limits = [30.0, 150.0]", "limits = [200.0, 300.0]"),
    )
    log = write_lines(work / "a.csv", short_cols)
    err = _fail(cli, "import", log, "--mapping", m, "--out", work / "X")
    assert 'rows are outliers (outliers = "drop"): nothing is left' in err
    assert_nothing_written(work / "X")


def test_an_out_under_a_file_is_named_as_the_other_commands_name_it(cli, work, short_cols) -> None:
    """``import --out afile/sub`` took the writer lock before the output-folder checks and
    said '(File exists)'; it names ``afile`` as a file, as simulate does."""
    log = write_lines(work / "a.csv", short_cols)
    (work / "afile").write_text("f")
    out = work / "afile" / "sub"
    rc, _, err = cli("import", log, "--mapping", work / "arm3.toml", "--out", out)
    assert rc == 2 and err.strip().splitlines()[-1] == (
        f"exsur: error: {out}: {work / 'afile'} is a file, not a folder; give another --out"
    )
