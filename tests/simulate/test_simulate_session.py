"""The continuous-log and sessions cases: the dig_session operator, the engine throttle input,
the split in time, separate sessions."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from excavator_surrogate.config import load_preset
from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.simulate.config import SimulateConfig
from excavator_surrogate.simulate.excitation import ExcitationConfig
from excavator_surrogate.simulate.generate import simulate_dataset
from excavator_surrogate.simulate.hydraulics import HydraulicConfig, HydraulicTransform
from excavator_surrogate.simulate.session import SessionParams
from excavator_surrogate.simulate.soil import SoilConfig
from excavator_surrogate.spec import EXCAVATOR


def _config(**session) -> SimulateConfig:
    """A short shift (2 min at 20 Hz) with breaks after every cycle, cut 10 s | 10 s in time."""
    params = SessionParams(
        p_break=1.0, idle_min_s=1.0, idle_max_s=2.0, free_min_s=3.0, free_max_s=5.0, **session
    )
    return SimulateConfig(
        n_train=1,
        n_val=0,
        n_test=0,
        steps_train=2400,
        train_signals=("dig_session",),
        excitation=dataclasses.replace(ExcitationConfig(), dig_session=params),
        val_s=10.0,
        test_s=10.0,
        inputs=("throttle",),
        rate_hz=20.0,
        plant="hydraulic",
        soil=SoilConfig(enabled=True),
    )


def test_one_shift_is_split_in_time_and_records_the_throttle(tmp_path):
    cfg = _config(p_throttle=1.0, throttle_levels=(0.5,))
    ds = load_dataset(simulate_dataset(cfg, out=tmp_path / "ds"))
    assert [e.n_step for e in ds.train + ds.val + ds.test] == [2000, 200, 200]
    # what `exsur run --dry-run` plans from, before anything is simulated
    assert cfg.episode_lengths() == {
        s: [e.n_step for e in ds.split(s)] for s in ("train", "val", "test")
    }
    assert [i.name for i in ds.spec.inputs] == ["throttle"]
    whole = np.concatenate([e.u for e in ds.train + ds.val + ds.test])
    assert whole.shape == (2400, EXCAVATOR.n_joint + 1)
    # the operator digs, then takes a break at which the throttle drops to 0.5
    op = ds.train[0].generator["plant"]["operator"]
    kinds = [ph for _, ph in op["phases"]]
    assert op["cycles"] >= 1 and "drag" in kinds
    assert {"idle", "free"} & set(kinds)
    throttle = whole[:, -1]
    assert throttle[0] == 1.0 and set(np.unique(throttle)) == {0.5, 1.0}
    first_break = next(k for k, ph in op["phases"] if ph in ("idle", "free"))
    assert np.all(throttle[:first_break] == 1.0) and throttle[first_break] == 0.5
    # the parts are consecutive pieces of one run: the angles continue across the cuts
    th = np.concatenate([e.theta for e in ds.train + ds.val + ds.test])
    step = np.abs(np.diff(th[:, 1:], axis=0)).max()
    assert step < 0.1  # rad per 50 ms: no jump at a cut (a new episode would start elsewhere)


def test_without_inputs_there_is_no_throttle_column(tmp_path):
    cfg = dataclasses.replace(_config(), inputs=(), steps_train=800)
    ds = load_dataset(simulate_dataset(cfg, out=tmp_path / "ds"))
    assert ds.spec.inputs == () and ds.train[0].u.shape[1] == EXCAVATOR.n_joint


def test_the_throttle_scales_the_pump():
    """Full boom and arm together need 1400 L/min of the 1000: half the throttle halves the flow."""
    cfg = HydraulicConfig.ideal(flow_sharing=True)
    u = np.zeros((1, 5, EXCAVATOR.n_joint))
    u[..., 1:3] = 1000.0
    out = []
    for scale in (1.0, 0.5):
        t = HydraulicTransform(cfg, spec=EXCAVATOR)
        t.reset(n_batch=1, substeps=1, timestep=EXCAVATOR.dt)
        t.pump_scale = scale
        out.append(t(u))
    np.testing.assert_allclose(out[1], 0.5 * out[0], rtol=1e-12)
    assert out[0][0, -1, 1] < 1000.0  # already pump-limited at full throttle


def test_sessions_are_separate_runs_each_with_its_own_oil_temperature(tmp_path):
    preset = SimulateConfig.from_preset(load_preset("sessions-dig"))
    assert (preset.n_train, preset.n_val, preset.n_test) == (12, 2, 1)
    assert (preset.val_s, preset.test_s) == (0.0, 0.0)  # not cut in time
    assert preset.hydraulics.drift and preset.soil.enabled
    # three short sessions of the same preset
    cfg = dataclasses.replace(
        preset, n_train=2, n_val=0, steps_train=200, steps_test=200, workers=1
    )
    ds = load_dataset(simulate_dataset(cfg, out=tmp_path / "ds"))
    eps = ds.train + ds.test
    assert [e.n_step for e in eps] == [200, 200, 200]
    amps = [e.generator["plant"]["drift_amplitude"] for e in eps]
    assert len(set(amps)) == 3 and all(0 <= a < preset.hydraulics.drift_amplitude for a in amps)
    starts = np.array([e.theta[0] for e in eps])
    assert np.ptp(starts[:, 1:], axis=0).max() > 0.05  # each session starts somewhere else


def _days_preset() -> SimulateConfig:
    return SimulateConfig.from_preset(load_preset("sessions-days"))


def test_sessions_of_one_day_share_its_slow_down(tmp_path):
    preset = _days_preset()
    assert preset.days == (3, 3, 3, 3, 3) and preset.hydraulics.day_slowdown == 0.2
    assert sum(preset.days) == preset.n_train + preset.n_val + preset.n_test
    # four short sessions in two days: the day's draw is shared, the oil's is each session's
    cfg = dataclasses.replace(
        preset, n_train=2, n_val=1, days=(2, 2), steps_train=60, steps_val=60, steps_test=60
    )
    ds = load_dataset(simulate_dataset(cfg, out=tmp_path / "ds"))
    plant = [e.generator["plant"] for e in ds.train + ds.val + ds.test]
    assert [p["day"] for p in plant] == [0, 0, 1, 1]
    slow = [p["day_slowdown"] for p in plant]
    assert slow[0] == slow[1] != slow[2] == slow[3]
    assert all(0 <= s < 0.2 for s in slow)
    assert len({p["drift_amplitude"] for p in plant}) == 4
    # the test session alone, on its day: the same draws, so the same session
    alone = dataclasses.replace(cfg, n_train=0, n_val=0, days=(0, 1))
    (test,) = load_dataset(simulate_dataset(alone, out=tmp_path / "alone")).test
    assert test.generator["plant"] == plant[-1]
    np.testing.assert_array_equal(test.theta, ds.test[0].theta)
    # the same session on the other day runs at that day's speed
    other = dataclasses.replace(alone, days=(1, 0))
    (moved,) = load_dataset(simulate_dataset(other, out=tmp_path / "other")).test
    assert moved.generator["plant"]["day_slowdown"] == slow[0]
    assert not np.array_equal(moved.theta, test.theta)


def test_days_must_count_every_session_once():
    with pytest.raises(ConfigError, match=r"simulate.days \[3, 3\] must count each of the 15"):
        dataclasses.replace(_days_preset(), days=(3, 3))
    with pytest.raises(ConfigError, match="no day below 0"):
        dataclasses.replace(_days_preset(), days=(16, -1))
    with pytest.raises(ConfigError, match="plant = 'hydraulic'"):
        dataclasses.replace(_days_preset(), plant="ideal")


def test_the_preset_is_one_long_log_cut_in_time():
    cfg = SimulateConfig.from_preset(load_preset("continuous-dig"))
    assert (cfg.n_train, cfg.n_val, cfg.n_test) == (1, 0, 0)
    assert cfg.train_signals == ("dig_session",) and cfg.inputs == ("throttle",)
    assert cfg.steps_train / cfg.rate_hz - cfg.val_s - cfg.test_s >= 300.0


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"inputs": ("rpm",)}, "unknown input"),
        ({"val_s": -1.0}, "val_s must be >= 0"),
        ({"test_s": float("nan")}, "test_s must be >= 0"),
    ],
)
def test_bad_options_are_one_line(change, match):
    with pytest.raises(ConfigError, match=match):
        dataclasses.replace(_config(), **change)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"p_break": 1.5}, "p_break"),
        ({"throttle_levels": (0.0,)}, "throttle_levels"),
        ({"idle_min_s": 5.0, "idle_max_s": 1.0}, "idle_min_s"),
    ],
)
def test_bad_session_params_are_one_line(change, match):
    with pytest.raises(ConfigError, match=match):
        SessionParams(**change)
