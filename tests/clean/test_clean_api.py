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
from excavator_surrogate.data import load_dataset, read_manifest
from excavator_surrogate.errors import ConfigError, DataError


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
