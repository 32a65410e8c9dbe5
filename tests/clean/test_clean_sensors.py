"""Sensor-fault model: shapes, magnitudes, jump mask, per-joint values, episode helper."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.clean.synthetic import smooth_random_motion
from excavator_surrogate.config import from_dict
from excavator_surrogate.data import Episode, read_episode, write_episode
from excavator_surrogate.data.jumps import jump_mask_of, mask_to_runs, runs_to_mask
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.simulate.sensors import SensorConfig, apply_sensors, apply_sensors_episode
from excavator_surrogate.spec import excavator_spec

DT = 0.05


def _truth(n_step: int = 4000, n_joint: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    return smooth_random_motion(n_step, n_joint, dt=DT, rng=np.random.default_rng(seed))


def test_motion_follows_data_convention() -> None:
    th, om = _truth()
    np.testing.assert_allclose(th[1:] - th[:-1], DT * om[1:], atol=1e-12)
    assert np.abs(om).max() <= 1.0 + 1e-12


def test_shapes_mask_and_runs() -> None:
    th, om = _truth()
    tm, omm, info = apply_sensors(
        th, om, dt=DT, config=SensorConfig(), rng=np.random.default_rng(1)
    )
    assert tm.shape == omm.shape == info["jump_mask"].shape == th.shape
    mask = info["jump_mask"]
    assert mask.dtype == bool and 0 < mask.mean() < 0.1
    assert not mask[0].any(), "jumps never start at row 0"
    np.testing.assert_array_equal(runs_to_mask(info["jump_runs"], *mask.shape), mask)
    assert info["jump_runs"] == mask_to_runs(mask)
    # the jump component is zero outside the mask and at least jump_min inside (unless
    # overlapping events of opposite sign cancel, which is rare)
    jump = np.abs(tm - th - info["theta_noise"])
    assert (jump[~mask] < 1e-12).all()
    assert (jump[mask] >= 0.999 * SensorConfig().jump_min).mean() > 0.95


def test_noise_magnitudes_without_jumps() -> None:
    th, om = _truth(n_step=20000, n_joint=2)
    cfg = SensorConfig(spike_rate=0.0, offset_rate=0.0, gyro_bias_walk=0.0)
    tm, omm, info = apply_sensors(th, om, dt=DT, config=cfg, rng=np.random.default_rng(2))
    assert not info["jump_mask"].any()
    env = cfg.theta_vib_std + cfg.theta_vib_gain * np.abs(om)
    expected = np.sqrt(cfg.theta_white_std**2 + np.mean(env**2, axis=0))
    np.testing.assert_allclose((tm - th).std(axis=0), expected, rtol=0.1)
    # gyro: constant bias + white noise
    bias = info["gyro_bias"]
    np.testing.assert_allclose(bias, np.broadcast_to(bias[0], bias.shape))
    np.testing.assert_allclose((omm - om - bias).std(axis=0), cfg.gyro_white_std, rtol=0.05)


def test_per_joint_values_and_reproducibility() -> None:
    th, om = _truth(n_joint=2)
    cfg = SensorConfig(
        theta_white_std=(0.0, 0.01),
        theta_vib_std=0.0,
        theta_vib_gain=0.0,
        spike_rate=(0.0, 0.5),
        offset_rate=0.0,
    )
    a = apply_sensors(th, om, dt=DT, config=cfg, rng=np.random.default_rng(5))
    b = apply_sensors(th, om, dt=DT, config=cfg, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    tm, _, info = a
    np.testing.assert_array_equal(tm[:, 0], th[:, 0])
    assert not info["jump_mask"][:, 0].any() and info["jump_mask"][:, 1].any()
    with pytest.raises(ConfigError, match="theta_white_std"):
        apply_sensors(
            th,
            om,
            dt=DT,
            config=SensorConfig(theta_white_std=(0.1, 0.2, 0.3)),
            rng=np.random.default_rng(0),
        )


def test_config_from_dict_accepts_lists_and_rejects_bad_values() -> None:
    cfg = from_dict(SensorConfig, {"theta_white_std": [0.001, 0.002], "spike_rate": 0.1})
    assert cfg.theta_white_std == (0.001, 0.002) and cfg.spike_rate == 0.1
    with pytest.raises(ConfigError, match="jump_min"):
        SensorConfig(jump_min=0.5, jump_max=0.1)
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(SensorConfig, {"noise": 1.0})


def test_apply_sensors_episode_keeps_truth_and_roundtrips(tmp_path) -> None:
    spec = excavator_spec(20.0)
    th, om = smooth_random_motion(800, spec.n_joint, dt=spec.dt, rng=np.random.default_rng(0))
    ideal = Episode(
        spec=spec, time=np.arange(800) * spec.dt, u=np.zeros((800, 4)), theta=th, omega=om
    )
    ep = apply_sensors_episode(
        ideal, config=SensorConfig(spike_rate=0.5), rng=np.random.default_rng(1)
    )
    np.testing.assert_array_equal(ep.theta_true, th)
    np.testing.assert_array_equal(ep.omega_true, om)
    assert not np.array_equal(ep.theta, th)
    assert ideal.theta_true is None and "sensor" not in ideal.extra
    mask = jump_mask_of(ep)
    assert mask is not None and mask.any()
    back = read_episode(write_episode(tmp_path / "e.parquet", ep))
    np.testing.assert_array_equal(jump_mask_of(back), mask)
    assert back.extra["sensor"]["config"]["spike_rate"] == 0.5
    # re-applying uses the stored truth, not the noisy angles
    again = apply_sensors_episode(ep, config=SensorConfig(), rng=np.random.default_rng(2))
    np.testing.assert_array_equal(again.theta_true, th)
    assert jump_mask_of(ideal) is None
