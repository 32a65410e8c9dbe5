"""ROS bags (rosbag2 with sqlite3 and MCAP storage, bare MCAP, ROS 1) and the anti-aliased
resampling."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.data import load_dataset
from excavator_surrogate.ingest import (
    antialias_sos,
    convert_log,
    decimation_factor,
    interval_mean,
    load_mapping,
    resample_smooth,
)
from tests.helpers import arm3_plant
from tests.helpers.ingest import assert_nothing_written, write_lines
from tests.helpers.ros_bags import write_bag

pytest.importorskip("rosbags")

ROS_MAPPING = """
[machine]
name = "arm3-ros"
rate_hz = 10.0
[time]
stamp = "auto"      # header.stamp when the message has one, else the bag time
[import]
min_steps = 20
"""
for _i, _j in enumerate(arm3_plant.JOINTS):
    ROS_MAPPING += f"""
[[joints]]
name = "{_j}"
angle = {{ topic = "/joint_states", field = "position[{_j}_joint]", unit = "rad" }}
command = {{ topic = "/valves", up = "data[{2 * _i}]", down = "data[{2 * _i + 1}]", unit = "%" }}
"""


def _write_bag(path: Path, cols: dict[str, np.ndarray], *, storage: str) -> None:
    """JointState at the log rate (joints in another order, received 2 ms after their header
    stamps) and valve duties at half rate: a rosbag2 folder (``storage`` "sqlite3" or
    "mcap") or, with "rosbag1", a ROS 1 bag file."""
    n = cols["t_ms"].size
    write_bag(
        path,
        cols,
        storage=storage,
        order=("bucket", "boom", "arm"),
        valve_rows=np.arange(0, n, 2),
        delay_ns=2_000_000,
        frame_id="arm",
    )


@pytest.fixture(scope="module")
def ros_logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray]]:
    root = tmp_path_factory.mktemp("ros")
    cols = arm3_plant.simulate(duration_s=20.0, seed=5, log_rate_hz=50.0)
    _write_bag(root / "bag_sqlite", cols, storage="sqlite3")
    _write_bag(root / "bag_mcap", cols, storage="mcap")
    _write_bag(root / "ros1.bag", cols, storage="rosbag1")
    (root / "ros.toml").write_text(ROS_MAPPING)
    return root, cols


def test_ros_bags(cli, ros_logs, tmp_path):
    """Each kind of ROS log gives the same episode from the same messages (each imported on
    its own: together they are one recording four times, refused)."""
    root, cols = ros_logs
    bare = tmp_path / "bare.mcap"
    # an MCAP file without metadata.yaml
    shutil.copy(next((root / "bag_mcap").glob("*.mcap")), bare)
    sources = {"bag_sqlite": root / "bag_sqlite", "bag_mcap": root / "bag_mcap", "bare": bare}
    sources["ros1"] = root / "ros1.bag"
    eps = {}
    for name, src in sources.items():
        out = tmp_path / f"ds_{name}"
        rc, _, err = cli("import", src, "--mapping", root / "ros.toml", "--out", out, "--quiet")
        assert rc == 0, err
        ds = load_dataset(out)
        assert ds.spec.names == arm3_plant.JOINTS and ds.spec.rate_hz == 10.0
        (eps[name],) = ds.train + ds.val + ds.test
    assert {e.name for e in eps.values()} == set(sources)
    out = tmp_path / "ds_bag_sqlite"
    ref = eps["bag_sqlite"]
    for name in ("bag_mcap", "bare", "ros1"):  # a ROS 1 bag of the same messages too
        np.testing.assert_allclose(eps[name].theta, ref.theta, atol=1e-12)
        np.testing.assert_allclose(eps[name].u, ref.u, atol=1e-9)
    t_log = cols["t_ms"] * 1e-3
    for i, j in enumerate(arm3_plant.JOINTS):  # header stamps, not the 2 ms later bag time
        truth = np.radians(np.interp(ref.time, t_log, cols[f"{j}_true_deg"]))
        assert np.sqrt(np.mean((ref.theta[:, i] - truth) ** 2)) < np.radians(0.05)
    assert np.abs(ref.u).max() > 300
    rep = json.loads((out / "import_report.json").read_text())
    f = rep["files"][0]
    assert f["series"]["/joint_states"]["rate_hz"] == pytest.approx(50, rel=0.02)
    assert f["series"]["/valves"]["rate_hz"] == pytest.approx(25, rel=0.02)
    assert f["origin"].startswith("2024-05-29")
    # the same messages in two storage formats are one recording: refused, nothing written
    both = tmp_path / "both"
    rc, _, err = cli(
        "import",
        root / "bag_sqlite",
        root / "ros1.bag",
        "--mapping",
        root / "ros.toml",
        "--out",
        both,
        "--quiet",
    )
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert f"{root / 'ros1.bag'}: holds the same samples as {root / 'bag_sqlite'}" in err
    assert not both.exists()


def test_ros_errors(cli, ros_logs, tmp_path):
    root, _ = ros_logs
    bad = tmp_path / "bad.toml"
    bad.write_text(ROS_MAPPING.replace('topic = "/valves"', 'topic = "/valve_cmd"', 1))
    rc, _, err = cli("import", root / "bag_sqlite", "--mapping", bad, "--out", tmp_path / "ds")
    assert (
        rc == 2
        and "topic '/valve_cmd' is not in the bag (topics present: /joint_states, /valves)" in err
    )
    bad.write_text(ROS_MAPPING.replace("position[arm_joint]", "position[7]"))
    rc, _, err = cli("import", root / "bag_mcap", "--mapping", bad, "--out", tmp_path / "ds")
    assert rc == 2
    assert (
        "column '/joint_states:position[7]', row 0: field path 'position[7]': index 7 out of range"
        in err
    )
    assert_nothing_written(tmp_path / "ds")
    # a mapping of table columns cannot read a bag
    (tmp_path / "arm3.toml").write_text(arm3_plant.MAPPING_TOML)
    rc, _, err = cli(
        "import", root / "bag_mcap", "--mapping", tmp_path / "arm3.toml", "--out", tmp_path / "ds"
    )
    assert rc == 2 and "this is a ROS bag but the mapping maps table columns" in err
    rc, _, err = cli(
        "import", root / "bag_mcap", "--mapping", tmp_path / "none.toml", "--out", tmp_path / "ds"
    )
    assert rc == 2 and "mapping file not found" in err


# ---------------------------------------------------------------------------------------
# resampling


def _amplitude(t: np.ndarray, x: np.ndarray, f: float) -> float:
    a = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
    coef = np.linalg.lstsq(a, x, rcond=None)[0]
    return float(np.hypot(coef[0], coef[1]))


def test_antialias_attenuates_tone_above_nyquist():
    rng = np.random.default_rng(0)
    rate_in, rate_out = 100.0, 20.0
    t_in = np.arange(3000) / rate_in + rng.uniform(-1e-3, 1e-3, 3000)  # jittered
    x = np.sin(2 * np.pi * 1.0 * t_in) + np.sin(2 * np.pi * 15.0 * t_in)  # 15 Hz > 10 Hz Nyquist
    factor = decimation_factor(rate_in, rate_out)
    assert factor == 5
    n = 580
    t_out = 0.1 + np.arange(n) / rate_out
    y = resample_smooth(
        t_in,
        x,
        t0=0.1,
        n_out=n,
        rate_hz=rate_out,
        factor=factor,
        sos=antialias_sos(rate_out, factor),
    )
    naive = np.interp(t_out, t_in, x)
    # 15 Hz sampled at 20 Hz aliases to 5 Hz
    assert _amplitude(t_out, naive, 5.0) > 0.8
    assert _amplitude(t_out, y, 5.0) < 0.01
    assert _amplitude(t_out, y, 1.0) == pytest.approx(1.0, abs=0.01)  # pass band kept, no delay:
    assert np.abs(y - np.sin(2 * np.pi * t_out)).max() < 0.02


def test_antialias_end_to_end(work):
    t = np.arange(2000) / 100.0
    cols = arm3_plant.simulate(duration_s=20.0, seed=1)
    cols["boom_deg"] = 5 * np.sin(2 * np.pi * 0.5 * t) + 1.0 * np.sin(2 * np.pi * 13.0 * t)
    cols["t_ms"] = t * 1e3
    ep = convert_log(
        write_lines(work / "tone.csv", cols), load_mapping(work / "arm3.toml")
    ).episodes[0]
    resid = np.degrees(ep.theta[:, 0]) - 5 * np.sin(2 * np.pi * 0.5 * ep.time)
    assert np.abs(resid[10:-10]).max() < 0.05  # the 13 Hz tone (1 deg) is gone
    assert np.abs(resid).max() < 0.3  # edges too


def test_interval_mean_is_exact_for_held_commands():
    rng = np.random.default_rng(2)
    t_in = np.cumsum(rng.uniform(0.005, 0.015, 400))
    x = rng.choice([-1.0, 0.0, 0.5, 1.0], 400)
    edges = t_in[3] + 0.05 * np.arange(60)
    got = interval_mean(t_in, x, edges)
    fine = np.linspace(edges[0], edges[-1], 590_001)[:-1]
    held = x[np.searchsorted(t_in, fine, side="right") - 1]
    want = held.reshape(59, -1).mean(axis=1)
    np.testing.assert_allclose(got, want, atol=1e-3)  # the reference is discretised
    assert np.allclose(interval_mean(t_in, np.full(400, 0.3), edges), 0.3)
