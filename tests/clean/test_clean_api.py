"""clean_episode / clean_episodes / clean_dataset / cleaning_metrics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.clean import (
    CleanConfig,
    clean_dataset,
    clean_episode,
    clean_episodes,
    cleaning_metrics,
    pooled_cleaning_metrics,
)
from excavator_surrogate.clean.api import _relative_source
from excavator_surrogate.clean.synthetic import smooth_random_motion
from excavator_surrogate.data import Episode, load_dataset, read_manifest
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.spec import JointSpec, MachineSpec


def test_clean_episode_contract(noisy_episode) -> None:
    ep = noisy_episode
    theta_before = ep.theta.copy()
    out = clean_episode(ep, config=CleanConfig())
    np.testing.assert_array_equal(ep.theta, theta_before)  # input untouched
    assert (
        out.trusted is not None
        and out.trusted.dtype == bool
        and out.trusted.shape == ep.theta.shape
    )
    np.testing.assert_array_equal(out.theta_true, ep.theta_true)
    np.testing.assert_array_equal(out.omega_true, ep.omega_true)
    np.testing.assert_allclose(out.omega[1:], np.diff(out.theta, axis=0) / ep.dt)
    stats = out.extra["cleaning"]
    assert stats["method"] == "rts" and stats["config"]["tau_cons"] == CleanConfig().tau_cons
    assert len(stats["untrusted_frac"]) == len(stats["rms_fused_minus_raw"]) == ep.spec.n_joint
    assert "sensor" in out.extra  # sensor provenance kept
    json.dumps(out.extra)  # Parquet metadata must stay JSON


def test_cleaning_metrics(noisy_episode) -> None:
    cleaned = clean_episode(noisy_episode)
    m = cleaning_metrics(noisy_episode, cleaned)
    assert list(m) == list(noisy_episode.spec.names)
    for joint in m.values():
        assert {"rmse_raw", "rmse_fused", "jump_precision", "jump_recall"} <= set(joint)
        assert joint["rmse_fused"] <= 0.5 * joint["rmse_raw"]
        assert joint["rmse_omega_fused"] < joint["rmse_omega_raw"]
        assert 0.0 <= joint["untrusted_frac"] < 0.2
    pooled = pooled_cleaning_metrics([(noisy_episode, cleaned), (noisy_episode, cleaned)])
    assert pooled["boom"]["rmse_fused"] == pytest.approx(m["boom"]["rmse_fused"])
    # no truth and no jump mask: truth-based values are None, fused-vs-raw still reported
    bare = noisy_episode.replace(theta_true=None, omega_true=None, extra={})
    mb = cleaning_metrics(bare, clean_episode(bare))
    assert mb["arm"]["rmse_raw"] is None and mb["arm"]["jump_recall"] is None
    assert mb["arm"]["rms_fused_minus_raw"] > 0
    with pytest.raises(DataError, match="does not match"):
        cleaning_metrics(noisy_episode, cleaned.slice(0, 10))


def test_periodic_joint_is_unwrapped(noisy_episode) -> None:
    ep = noisy_episode
    k = ep.spec.names.index("swing")
    assert ep.spec.joints[k].periodic
    theta = ep.theta.copy()
    shift = np.linspace(0.0, 8 * math.pi, ep.n_step)  # several full turns
    true = ep.theta_true.copy()
    true[:, k] += shift
    theta[:, k] += shift
    omega = ep.omega.copy()
    omega[1:, k] += np.diff(shift) / ep.dt
    om_true = ep.omega_true.copy()
    om_true[1:, k] += np.diff(shift) / ep.dt
    wrapped = ep.replace(
        theta=(theta + math.pi) % (2 * math.pi) - math.pi,
        omega=omega,
        theta_true=true,
        omega_true=om_true,
    )
    out = clean_episode(wrapped)
    m = cleaning_metrics(wrapped, out)["swing"]
    assert m["rmse_fused"] <= 0.5 * m["rmse_raw"]
    assert m["jump_precision"] >= 0.9
    assert np.abs(np.diff(out.theta[:, k])).max() < 0.2  # no 2*pi steps


def test_clean_episodes_batches_like_one_by_one(noisy_episode) -> None:
    a = noisy_episode.slice(0, 1200)
    b = noisy_episode.slice(100, 1100).replace(name="b")
    c = noisy_episode.slice(0, 300).replace(name="c")
    many = clean_episodes([a, b, c])
    for ep, got in zip([a, b, c], many):
        one = clean_episode(ep)
        assert got.name == ep.name
        np.testing.assert_array_equal(got.theta, one.theta)
        np.testing.assert_array_equal(got.trusted, one.trusted)


def test_clean_dataset(noisy_dataset, tmp_path) -> None:
    out = tmp_path / "clean"
    cfg = CleanConfig(method="gyro")
    clean_dataset(noisy_dataset, out, config=cfg)
    src, dst = load_dataset(noisy_dataset), load_dataset(out)
    for split in ("train", "val", "test"):
        assert [e.name for e in dst.split(split)] == [e.name for e in src.split(split)]
        for e in dst.split(split):
            assert e.trusted is not None and e.theta_true is not None
            assert e.extra["cleaning"]["method"] == "gyro"
    manifest = read_manifest(out)
    assert manifest["config"]["clean"]["method"] == "gyro"
    # recorded so that it resolves from the cleaned dataset folder, wherever the pair is moved
    assert (out / manifest["cleaned_from"]).resolve() == Path(noisy_dataset).resolve()
    assert set(manifest["cleaning"]) == set(src.spec.names)
    assert "[clean]" in (out / "config.toml").read_text()
    # re-running replaces the folder atomically; no temp folders left behind
    clean_dataset(noisy_dataset, out, config=CleanConfig(method="paper"))
    assert read_manifest(out)["config"]["clean"]["method"] == "paper"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clean", "raw"]
    with pytest.raises(ConfigError, match="another --out"):
        clean_dataset(noisy_dataset, noisy_dataset)
    with pytest.raises(DataError, match="not found"):
        clean_dataset(tmp_path / "missing", tmp_path / "x")


def test_warns_when_omega_is_derived_from_theta(noisy_episode, caplog) -> None:
    om = noisy_episode.omega.copy()
    om[1:, 2] = np.diff(noisy_episode.theta[:, 2]) / noisy_episode.dt
    clean_episode(noisy_episode.replace(omega=om))
    err = caplog.text  # a warning of the package logger
    assert "['arm']" in err and "tau_cons=inf" in err
    caplog.clear()
    clean_episode(noisy_episode.replace(omega=om), config=CleanConfig(method="paper"))
    assert caplog.text == ""


def test_cleaned_from_is_relative_for_siblings(tmp_path) -> None:
    run = tmp_path / "run"
    assert _relative_source(run / "data", run / "data_clean") == "../data"
    assert _relative_source(tmp_path / "x" / "data", run / "clean") == str(tmp_path / "x" / "data")


def _precise_stroke_episode() -> tuple[Episode, np.ndarray]:
    """A 20 Hz, 60 s episode of one stroke [m] (0.3 mm noise, a clean gyro) with 5 mm sensor
    offsets held for 0.5 s every 5 s; also returns the true stroke (n_step,)."""
    spec = MachineSpec((JointSpec("boom", kind="linear", unit="mm"),), rate_hz=20.0)
    rng = np.random.default_rng(7)
    theta, omega = smooth_random_motion(1200, 1, dt=spec.dt, rng=rng, omega_max=0.2)
    theta = 0.1 * theta  # strokes of +-0.12 m at up to 20 mm/s
    omega = 0.1 * omega
    z = theta + rng.normal(0.0, 3e-4, theta.shape)
    for start in range(40, 1200, 100):
        z[start : start + 10] += 5e-3
    ep = Episode(
        spec=spec, time=np.arange(1200) * spec.dt, u=np.zeros((1200, 1)), theta=z, omega=omega
    )
    return ep, theta[:, 0]


def test_linear_joints_filter_in_linear_m_per_rad() -> None:
    """A precise stroke sensor's 5 mm offsets pass the angle-sized thresholds read in m
    (tau_cons = 30 mm) and are half followed; with 50 mm of stroke counted as 1 rad (0.3 mm
    noise, as a 6 mrad angle sensor's), they are caught and bridged by the gyro."""
    ep, truth = _precise_stroke_episode()
    offset = np.zeros(1200, dtype=bool)
    for start in range(40, 1200, 100):
        offset[start : start + 10] = True

    as_m = clean_episode(ep, config=CleanConfig())
    scaled = clean_episode(ep, config=CleanConfig(linear_m_per_rad=0.05))
    err_m = np.abs(as_m.theta[:, 0] - truth)[offset]
    err_scaled = np.abs(scaled.theta[:, 0] - truth)[offset]
    assert as_m.trusted[offset, 0].all()  # the offsets are believed...
    assert err_m.mean() > 1e-3  # ...and followed
    assert not scaled.trusted[offset, 0].any()
    assert scaled.trusted[~offset, 0].mean() > 0.95
    assert err_scaled.mean() < 3e-4
    # the cleaned stroke stays in m, and its omega is its backward difference
    np.testing.assert_allclose(np.diff(scaled.theta[:, 0]) / ep.dt, scaled.omega[1:, 0])


def test_linear_m_per_rad_leaves_revolute_joints_alone(noisy_episode) -> None:
    a = clean_episode(noisy_episode, config=CleanConfig())
    b = clean_episode(noisy_episode, config=CleanConfig(linear_m_per_rad=0.01))
    np.testing.assert_array_equal(a.theta, b.theta)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_bad_linear_m_per_rad_is_refused(bad: float) -> None:
    with pytest.raises(ConfigError, match="linear_m_per_rad"):
        CleanConfig(linear_m_per_rad=bad)
