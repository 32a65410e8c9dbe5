"""Issue 25: the data contract rejects angles and velocities no joint and no sensor produce."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import read_episode, validate_episode, write_episode
from excavator_surrogate.data.plausible import MAX_TURNS
from excavator_surrogate.errors import DataError
from excavator_surrogate.spec import EXCAVATOR
from tests.data.test_contract import make_episode


def _poison(role: str, joint: str, rows: slice, value: float):
    ep = make_episode(n=400)
    k = EXCAVATOR.names.index(joint)
    arr = getattr(ep, role).copy()
    arr[rows, k] = value
    return ep.replace(**{role: arr})


POISONED = {
    # a 36000-degree burst smeared by the resampler: the import of old stored -3604..22450 deg
    "smeared 36000 deg": ("theta", "boom", slice(100, 110), np.deg2rad(22450.0), "theta_boom"),
    "1e308 median": ("theta", "arm", slice(0, 400), 2.8e106, "theta_arm"),
    "level far off the rest": (
        "theta",
        "bucket",
        slice(200, 203),
        np.deg2rad(900.0),
        "theta_bucket",
    ),
    "periodic beyond 1e4 turns": ("theta", "swing", slice(5, 9), 1e6, "theta_swing"),
    "velocity": ("omega", "boom", slice(50, 54), 1e5, "omega_boom"),
}


@pytest.mark.parametrize("case", sorted(POISONED))
def test_validate_rejects_impossible_values(tmp_path: Path, capsys, case: str) -> None:
    role, joint, rows, value, column = POISONED[case]
    path = tmp_path / "ep.parquet"
    write_episode(path, _poison(role, joint, rows, value), validate=False)
    with pytest.raises(DataError) as err:
        read_episode(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg
    assert f"column '{column}', row {rows.start}" in msg and "impossible" in msg
    assert "re-import the log" in msg
    assert main(["validate", str(path)]) == 2
    out = capsys.readouterr().err
    assert out.startswith("exsur: error: ") and out.count("\n") == 1


def test_legitimate_motion_passes() -> None:
    """Unwrapped swing over many turns, end-stopped joints across their whole range, a 0.35 rad
    simulated sensor offset: all plausible."""
    n = 4000
    ep = make_episode(n=n)
    t = np.arange(n) * EXCAVATOR.dt
    theta = ep.theta.copy()
    theta[:, 0] = 1.2 * t  # the swing turns 1.2 rad/s for 200 s: ~38 turns, unwrapped
    theta[:, 1] = np.clip(2.0 * np.sin(0.2 * t), -0.75, 0.85)  # hits both end stops
    theta[:, 2] = 0.55 + 0.05 * np.sin(t)
    theta[1000:1012, 2] += 0.35  # a sensor offset as the Stage II simulation makes them
    omega = np.vstack([np.zeros((1, 4)), np.diff(theta, axis=0) / EXCAVATOR.dt])
    assert abs(theta[:, 0]).max() > 2 * np.pi * MAX_TURNS  # beyond the end-stopped bound
    validate_episode(ep.replace(theta=theta, omega=omega, theta_true=None, omega_true=None))


def test_simulated_sensor_faults_pass() -> None:
    """Stage II sensor spikes and offsets (up to 0.35 rad, 10x the default rates) are data the
    cleaning stage must see, not impossible values."""
    from excavator_surrogate.simulate.sensors import SensorConfig, apply_sensors_episode

    ep = make_episode(n=4000)
    cfg = SensorConfig(spike_rate=0.5, offset_rate=0.3)
    for seed in range(3):
        noisy = apply_sensors_episode(ep, config=cfg, rng=np.random.default_rng(seed))
        assert len(noisy.extra["sensor"]["jump_runs"]) > 50
        validate_episode(noisy)
