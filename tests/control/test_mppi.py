"""MPPI on a tiny exact model, the digging reference, the PI baseline."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.control.mppi import MPPI, MPPIConfig
from excavator_surrogate.control.reference import (
    dig_reference,
    horizon_window,
    reference_samples,
)
from excavator_surrogate.errors import ConfigError, ExsurError
from excavator_surrogate.spec import EXCAVATOR

GAIN = 1e-3
"""Integrator plant of the fake predictor: omega = GAIN * u [rad/s per command unit]."""


class Integrator:
    """An exact batched model of ``theta[k+1] = theta[k] + dt * GAIN * u[k]``."""

    spec = EXCAVATOR

    def __init__(self) -> None:
        self.theta = np.zeros(4)
        self.calls = 0

    def reset(self, theta0: np.ndarray) -> None:
        self.theta = np.array(theta0, dtype=float)

    def reset_history(self, theta_hist: np.ndarray, u_hist: np.ndarray) -> None:
        self.theta = np.array(theta_hist[-1], dtype=float)

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        self.theta = np.array(theta, dtype=float)

    def predict(self, u: np.ndarray) -> np.ndarray:
        self.calls += 1
        return self.theta + np.cumsum(u * GAIN * self.spec.dt, axis=1)


def _run(cfg: MPPIConfig, target: np.ndarray, n: int) -> tuple[np.ndarray, MPPI, Integrator]:
    model = Integrator()
    mppi = MPPI(model, cfg)
    theta = np.array([0.0, 0.0, 1.5, 0.5])
    mppi.reset(theta)
    ref = np.repeat(target[None], cfg.n_horizon, axis=0)
    for k in range(n):
        u = mppi.act(k, ref)
        assert u.shape == (4,) and np.all(np.abs(u) <= 1000)
        theta = theta + EXCAVATOR.dt * GAIN * u
        mppi.observe(u, theta)
    return theta, mppi, model


def test_mppi_drives_an_exact_model_to_the_target() -> None:
    target = np.array([0.3, -0.2, 1.7, 0.3])
    cfg = MPPIConfig(n_sample=64, n_horizon=10, replan=2, seed=3)
    theta, mppi, model = _run(cfg, target, 80)
    assert np.abs(theta - target).max() < 0.03
    assert model.calls == 40  # one batched call per control step (every `replan` samples)
    assert len(mppi.stats.plan_s) == 40
    # the same seed gives the same run
    theta2, _, _ = _run(cfg, target, 80)
    np.testing.assert_array_equal(theta, theta2)


def test_noise_and_cost() -> None:
    mppi = MPPI(Integrator(), MPPIConfig(n_sample=8, n_horizon=5))
    eps = mppi.noise()
    assert eps.shape == (8, 5, 4) and np.all(eps[0] == 0) and np.any(eps[1:] != 0)
    ref = np.zeros((5, 4))
    theta = np.zeros((8, 5, 4))
    theta[1, :, 0] = 2 * np.pi  # a full swing turn is no error (periodic joint)
    theta[2, :, 1] = 0.1
    c = mppi.cost(theta, ref, np.zeros((8, 5, 4)))
    assert c[0] == 0 and c[1] == pytest.approx(0, abs=1e-20) and c[2] == pytest.approx(0.01)


def test_config_errors() -> None:
    with pytest.raises(ConfigError, match="replan"):
        MPPIConfig(n_horizon=4, replan=5)
    with pytest.raises(ConfigError, match="joint_weights"):
        MPPI(Integrator(), MPPIConfig(joint_weights=(1.0, 2.0)))


@pytest.mark.parametrize("smooth", [float("nan"), float("inf"), -5.0])
def test_smooth_must_be_finite_and_non_negative(smooth: float) -> None:
    """NaN made every command NaN; a negative weight rewarded jerky commands."""
    with pytest.raises(ConfigError, match="mppi.smooth"):
        MPPIConfig(smooth=smooth)


def test_joint_weights_must_be_finite() -> None:
    """A NaN weight made every command NaN."""
    with pytest.raises(ConfigError, match=r"mppi.joint_weights.*finite"):
        MPPI(Integrator(), MPPIConfig(joint_weights=(float("nan"), 1.0, 1.0, 1.0)))


def test_a_gap_in_the_reference_is_refused_by_row_and_joint() -> None:
    """One NaN sample 0.45 s ahead made every command NaN, then kept the plan NaN for good
    (the next plan's error blamed a gap in a log); now the step is refused and the plan is
    kept, so the next step with a clean reference plans as usual."""
    mppi = MPPI(Integrator(), MPPIConfig(n_sample=16, n_horizon=10))
    theta0 = np.array([0.0, 0.1, 1.2, 0.8])
    mppi.reset(theta0)
    ref = np.repeat(theta0[None], 12, axis=0)
    ref[9, 1] = np.nan
    with pytest.raises(ConfigError, match=r"row 9 \(machine sample 10\), joint 1 \(boom\) is nan"):
        mppi.act(0, ref)
    with pytest.raises(ConfigError, match=r"row 9, joint 1 \(boom\)"):
        mppi.plan(ref[:10])
    assert np.all(mppi.mean == 0)
    u = mppi.act(0, np.repeat(theta0[None], 12, axis=0))
    assert np.all(np.isfinite(u))


@pytest.mark.parametrize("shape", [(10, 3), (5, 4), (10,)])
def test_a_reference_of_the_wrong_shape_is_one_line(shape: tuple[int, ...]) -> None:
    """A bare numpy broadcasting ValueError before."""
    mppi = MPPI(Integrator(), MPPIConfig(n_sample=16, n_horizon=10))
    mppi.reset(np.zeros(4))
    with pytest.raises(ConfigError, match=r"n_horizon = 10, n_joint = 4"):
        mppi.act(0, np.zeros(shape))


class NaNModel(Integrator):
    """A model whose every prediction is NaN."""

    def predict(self, u: np.ndarray) -> np.ndarray:
        return np.full(u.shape, np.nan)


def test_no_finite_candidate_raises_and_keeps_the_plan() -> None:
    mppi = MPPI(NaNModel(), MPPIConfig(n_sample=8, n_horizon=5))
    mppi.reset(np.zeros(4))
    with pytest.raises(ExsurError, match="no candidate has a finite cost"):
        mppi.act(0, np.zeros((5, 4)))
    assert np.all(mppi.mean == 0) and np.all(mppi.u_prev == 0)


def test_dig_reference() -> None:
    theta, t, phases = dig_reference(EXCAVATOR)
    assert theta.shape == (len(t), 4) and t[1] == pytest.approx(EXCAVATOR.dt)
    np.testing.assert_array_equal(theta[0], theta[-1])  # one cycle back to the start
    assert [p for p, _ in phases][1:] == [
        "approach",
        "penetrate",
        "curl",
        "lift",
        "swing",
        "dump",
        "return",
    ]
    for k, j in enumerate(EXCAVATOR.joints):
        if not j.periodic:
            assert j.theta_min < theta[:, k].min() and theta[:, k].max() < j.theta_max
    speed = np.abs(np.diff(theta, axis=0)).max(axis=0) / EXCAVATOR.dt
    top = np.array([0.68, 0.45 * 0.8, 0.55 * 0.85, 1.0 * 0.85])  # hydraulic plant [rad/s]
    assert np.all(speed < 0.7 * top)  # feasible: smooth segments within the joints' speeds
    slow, _, _ = dig_reference(EXCAVATOR, time_scale=2.0)
    assert len(slow) > 1.9 * len(theta) - 40
    win = horizon_window(theta, len(theta) - 2, 5)
    np.testing.assert_array_equal(win, np.repeat(theta[-1:], 5, axis=0))
    with pytest.raises(ConfigError, match="time_scale"):
        dig_reference(EXCAVATOR, time_scale=0.0)
    assert reference_samples(EXCAVATOR, time_scale=2.0) == len(slow)
    assert reference_samples(EXCAVATOR) == len(theta)


def test_mppi_takes_over_mid_motion() -> None:
    """After a recorded history the predictor starts at its last angle and the smoothness
    cost from its last command (in half ranges), and MPPI still reaches the target."""
    model = Integrator()
    cfg = MPPIConfig(n_sample=64, n_horizon=10, seed=0)
    mppi = MPPI(model, cfg)
    theta_hist = np.array([[0.0, 0.0, 1.5, 0.5], [0.01, 0.0, 1.5, 0.5]])
    mppi.reset_history(theta_hist, np.array([[500.0, 0.0, -1000.0, 0.0]]))
    np.testing.assert_array_equal(model.theta, theta_hist[-1])
    np.testing.assert_allclose(mppi.u_prev, [0.5, 0.0, -1.0, 0.0])
    target = np.array([0.3, 0.2, 1.3, 0.7])
    theta = theta_hist[-1]
    ref = np.repeat(target[None], cfg.n_horizon, axis=0)
    for k in range(150):
        u = mppi.act(k, ref)
        theta = theta + EXCAVATOR.dt * GAIN * u
        mppi.observe(u, theta)
    assert np.abs(theta - target).max() < 0.05


@pytest.mark.parametrize(("lo", "rest"), [(-1000.0, 0.0), (-200.0, 0.0), (100.0, 100.0)])
def test_the_plan_after_reset_is_the_rest_command(lo: float, rest: float) -> None:
    """The plan started at the range's centre: on [-200, 1000] every joint was commanded
    about 300 (25 % of full scale) while asked to hold still; it starts at rest (0 clipped
    into the range), also after ``reset_history``, and holds still with small commands."""
    from dataclasses import replace

    spec = replace(EXCAVATOR, joints=tuple(replace(j, u_min=lo) for j in EXCAVATOR.joints))
    model = Integrator()
    model.spec = spec
    mppi = MPPI(model, MPPIConfig(seed=0))
    theta0 = np.array([0.0, 0.1, 1.2, 0.8])
    mppi.reset_history(np.stack([theta0, theta0]), np.array([[900.0, 900.0, 900.0, 900.0]]))
    np.testing.assert_allclose(mppi.mean * mppi.u_scale + mppi.u_center, rest, atol=1e-9)
    mppi.reset(theta0)
    np.testing.assert_allclose(mppi.mean * mppi.u_scale + mppi.u_center, rest, atol=1e-9)
    np.testing.assert_allclose(mppi.u_prev * mppi.u_scale + mppi.u_center, rest, atol=1e-9)
    u = mppi.act(0, np.repeat(theta0[None], 20, axis=0))
    assert np.abs(u - rest).max() < 100  # was 192-346 on [-200, 1000]


def test_a_huge_time_scale_is_refused_before_allocating(monkeypatch) -> None:
    """time_scale 1e9 ended in numpy's _ArrayMemoryError (298 GiB for one array)."""
    from excavator_surrogate.surrogate import sizes

    monkeypatch.setattr(sizes, "available_memory", lambda: 8 * 2**30)
    with pytest.raises(ConfigError, match="makes 520000000021 samples.*lower time_scale"):
        dig_reference(EXCAVATOR, time_scale=1e9)
