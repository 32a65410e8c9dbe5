"""Issue 25: impossible angle samples are found without declared limits, whatever the burst length."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.data import load_dataset
from excavator_surrogate.ingest.bursts import JUMP_SPEED, find_impossible
from tests.helpers import arm3_plant
from tests.helpers.ingest import assert_nothing_written, set_cell, write_lines


def _no_limits(work: Path, extra_import: str = "") -> Path:
    """The arm3 mapping without any ``limits`` (as most real mappings are)."""
    text = re.sub(r"limits = .*\n", "", (work / "arm3.toml").read_text())
    assert "limits" not in text
    text = text.replace("[import]\n", f"[import]\n{extra_import}\n")
    (work / "nolim.toml").write_text(text)
    return work / "nolim.toml"


def _burst(value: str, rows: range, col: str = "boom_deg"):
    def edit(lines: list[str]) -> list[str]:
        for r in rows:
            lines = set_cell(lines, r, col, value)
        return lines

    return edit


BURSTS = {
    "36000 x5": ("36000", range(300, 305)),
    "1e308 x4": ("1e308", range(300, 304)),
    "90 deg x4": ("90", range(300, 304)),
    "90 deg x40": ("90", range(300, 340)),
    "-3604 deg x6": ("-3604", range(600, 606)),
    "at the start": ("36000", range(0, 6)),
    "at the end": ("90", range(990, 1000)),
}


@pytest.mark.parametrize("case", sorted(BURSTS))
def test_burst_without_limits_is_one_line_error(cli, work, short_cols, case) -> None:
    value, rows = BURSTS[case]
    log = write_lines(work / "a.csv", short_cols, _burst(value, rows))
    out = work / "X"
    rc, _, err = cli("import", log, "--mapping", _no_limits(work), "--out", out, "--quiet")
    assert rc == 2, err
    assert err.startswith("exsur: error: ") and err.count("\n") == 1, err
    first = rows[0]
    assert f"{log}, column 'boom_deg', row {first}: joint 'boom': angle {float(value):g} deg" in err
    assert f"is impossible (rows {first}-{rows[-1]}, {len(rows)} samples)" in err
    assert '[import] outliers = "drop" or "clip"' in err
    assert_nothing_written(out)


@pytest.mark.parametrize("policy", ["drop", "clip"])
def test_bursts_are_dropped_and_reported(cli, work, short_cols, policy) -> None:
    def poison(lines: list[str]) -> list[str]:
        lines = _burst("36000", range(200, 205))(lines)
        lines = _burst("1e308", range(400, 404), "arm_deg")(lines)
        return _burst("90", range(700, 704), "bucket_deg")(lines)

    log = write_lines(work / "a.csv", short_cols, poison)
    out = work / policy
    m = _no_limits(work, f'outliers = "{policy}"')
    rc, stdout, err = cli("import", log, "--mapping", m, "--out", out)
    assert rc == 0, err
    counts = json.loads((out / "import_report.json").read_text())["files"][0]["outliers"]
    assert counts == {
        "boom": {"impossible_dropped": 5},
        "arm": {"impossible_dropped": 4},
        "bucket": {"impossible_dropped": 4},
    }
    assert "outliers boom: impossible dropped 5" in stdout
    ds = load_dataset(out)
    theta = np.concatenate([e.theta for s in ("train", "val", "test") for e in ds.split(s)])
    true = np.column_stack([short_cols[f"{j}_true_deg"] for j in arm3_plant.JOINTS])
    # nothing of the bursts reaches the dataset: it stays within the true range (+ filter ringing)
    assert np.all(np.rad2deg(theta.max(axis=0)) < true.max(axis=0) + 3.0)
    assert np.all(np.rad2deg(theta.min(axis=0)) > true.min(axis=0) - 3.0)


def test_clean_logs_have_no_false_alarms(cli, work, arm3_dir) -> None:
    """Realistic logs (fast moves, end stops, noise, jitter, a .csv.gz): nothing is flagged."""
    out = work / "ds"
    rc, _, err = cli("import", arm3_dir / "logs", "--mapping", _no_limits(work), "--out", out)
    assert rc == 0, err
    report = json.loads((out / "import_report.json").read_text())
    assert [f["outliers"] for f in report["files"]] == [{}] * 4


@pytest.mark.parametrize("seed", range(6))
def test_find_impossible_is_quiet_on_simulated_arm_logs(seed: int) -> None:
    cols = arm3_plant.simulate(duration_s=60.0, seed=100 + seed)
    t = cols["t_ms"] * 1e-3
    at_stop = 0
    for j, (lo, hi) in zip(arm3_plant.JOINTS, arm3_plant.LIMITS_DEG):
        true = cols[f"{j}_true_deg"]
        at_stop += int(np.sum((true <= lo + 1e-6) | (true >= hi - 1e-6)))
        mask, bursts = find_impossible(np.deg2rad(cols[f"{j}_deg"]), t, periodic=False)
        assert not mask.any(), (j, bursts[:3])
    assert at_stop > 0  # the logs do hit end stops


def _swing(n: int = 6000, rate: float = 100.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A periodic joint logged wrapped to ±180 deg: fast swings (2.5 rad/s), stops, noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    speed = 2.5 * np.sign(np.sin(2 * np.pi * t / 7.0)) * (np.abs(np.sin(2 * np.pi * t / 7.0)) > 0.3)
    theta = np.cumsum(speed) / rate + rng.normal(0.0, 1e-3, n)
    return t, np.angle(np.exp(1j * theta))  # wrapped at ±pi


def test_periodic_wrap_is_not_a_burst_but_a_glitch_is() -> None:
    t, th = _swing()
    assert np.sum(np.abs(np.diff(th)) > np.pi) >= 4  # it does wrap, several times
    assert not find_impossible(th, t, periodic=True)[0].any()
    bad = th.copy()
    bad[3000:3012] = np.deg2rad(90.0) + bad[2999] + 0.5  # 12 samples far from the swing
    mask, bursts = find_impossible(bad, t, periodic=True)
    assert np.flatnonzero(mask).tolist() == list(range(3000, 3012))
    assert bursts[0].reason == "jump" and bursts[0].speed > JUMP_SPEED


def test_end_stop_hit_at_full_speed_is_not_a_burst() -> None:
    """A joint driven into its end stop at 3 rad/s stops dead: no jump, nothing flagged."""
    t = np.arange(2000) / 100.0
    theta = np.clip(3.0 * (t - 2.0), 0.0, 1.2) - np.clip(3.0 * (t - 12.0), 0.0, 1.2)
    theta = theta + np.random.default_rng(1).normal(0.0, 5e-4, t.shape)
    assert not find_impossible(theta, t, periodic=False)[0].any()


def test_unit_mistake_is_still_named_as_such(cli, work, short_cols) -> None:
    """Degrees in a 'rad' column are beyond 10 turns everywhere: a unit error, not a burst."""
    text = (
        _no_limits(work).read_text().replace('"arm_deg", unit = "deg"', '"arm_deg", unit = "rad"')
    )
    (work / "rad.toml").write_text(text)
    log = write_lines(work / "a.csv", short_cols)
    rc, _, err = cli("import", log, "--mapping", work / "rad.toml", "--dry-run")
    assert rc == 2 and "looks like degrees" in err, err


def test_impossible_measured_velocity_is_found(cli, work, short_cols) -> None:
    """A 1e308 burst in a velocity channel is named in the log (it used to reach the dataset
    writer and fail there, naming a temporary file)."""
    cols = dict(short_cols)
    t = cols["t_ms"] * 1e-3
    cols["boom_rate"] = np.gradient(cols["boom_true_deg"], t)
    cols["boom_rate"][300:305] = 1e308
    columns = (*arm3_plant.LOG_COLUMNS, "boom_rate")
    log = write_lines(work / "a.csv", cols, columns=columns)
    angle = 'angle = { column = "boom_deg", unit = "deg" }'
    text = _no_limits(work).read_text()
    m = work / "vel.toml"
    m.write_text(
        text.replace(angle, angle + '\nvelocity = { column = "boom_rate", unit = "deg/s" }')
    )
    out = work / "X"
    rc, _, err = cli("import", log, "--mapping", m, "--out", out, "--quiet")
    assert rc == 2 and err.count("\n") == 1, err
    assert (
        f"{log}, column 'boom_rate', row 300: joint 'boom': velocity 1e+308 deg/s is impossible"
        in err
    )
    assert_nothing_written(out)
    rc, text, err = cli("import", log, "--mapping", m, "--dry-run", "--outliers", "drop")
    assert rc == 0 and "outliers boom: impossible velocity dropped 5" in text, err


def test_a_jittered_time_stamp_is_not_a_jump() -> None:
    """Two samples stamped 0.2 ms apart (a logger stamping on arrival) move by their normal
    step: 21 rad/s over that Δt, but no burst; half the log was flagged as one (audit 1, D1).
    A real burst in the same log is still found."""
    t = np.arange(3000) * 0.01
    theta = 0.5 * np.sin(t)  # at most 0.5 rad/s
    t[1000] = t[999] + 0.0002
    t[1800] = t[1799] + 0.0002  # two such stamps 8 s apart: the rows between are no burst
    assert not find_impossible(theta, t, periodic=False)[0].any()
    theta[2500:2504] = np.deg2rad(90.0)
    mask, bursts = find_impossible(theta, t, periodic=False)
    assert np.flatnonzero(mask).tolist() == list(range(2500, 2504))
    assert bursts[0].reason == "jump"
