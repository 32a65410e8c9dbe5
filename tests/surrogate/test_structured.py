"""The structured baseline recovers a dead-zone / gain / delay plant and free-runs like a plain loop."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.data import Episode
from excavator_surrogate.errors import DataError
from excavator_surrogate.evaluate.cbe import evaluate_models
from excavator_surrogate.spec import JointSpec, MachineSpec
from excavator_surrogate.surrogate.baselines import fit_structured
from excavator_surrogate.surrogate.rollout import rollout_episodes
from excavator_surrogate.surrogate.structured import JointFit, fit_joint

SPEC = MachineSpec(
    joints=(JointSpec("a", u_min=-1000, u_max=1000), JointSpec("b", u_min=-1000, u_max=1000)),
    rate_hz=20.0,
)
# the truth; dead-zone edges on the fit's grid (0.6 * 1000 / 30 = 20 command units apart)
TRUTH = (
    JointFit(delay=3, a_pos=160.0, a_neg=-200.0, k_pos=1.0e-3, k_neg=6.0e-4, rmse=0.0),
    JointFit(delay=5, a_pos=100.0, a_neg=-100.0, k_pos=8.0e-4, k_neg=1.2e-3, rmse=0.0),
)


def _commands(rng: np.random.Generator, n_step: int, bias: float = 0.0) -> np.ndarray:
    """Random holds of 5-30 samples at random levels (the dead zones are crossed often)."""
    u = np.empty((n_step, 2))
    for j in range(2):
        k = 0
        while k < n_step:
            n = int(rng.integers(5, 30))
            u[k : k + n, j] = np.clip(rng.uniform(-1000, 1000) + bias, -1000, 1000)
            k += n
    return u


def _plant(u: np.ndarray, theta0: np.ndarray, lo=None, hi=None) -> np.ndarray:
    """theta[t+1] = clip(theta[t] + dt g(u[t-d])) of the truth (u before the start: 0)."""
    theta = np.empty_like(u)
    theta[0] = theta0
    for t in range(len(u) - 1):
        for j, f in enumerate(TRUTH):
            ud = u[t - f.delay, j] if t - f.delay >= 0 else 0.0
            theta[t + 1, j] = theta[t, j] + SPEC.dt * f.speed(ud)
        if lo is not None:
            theta[t + 1] = np.clip(theta[t + 1], lo, hi)
    return theta


def _episode(seed: int, n_step: int = 600, bias: float = 0.0) -> Episode:
    rng = np.random.default_rng(seed)
    u = _commands(rng, n_step, bias)
    theta = _plant(u, rng.uniform(-0.5, 0.5, 2))
    omega = np.vstack([np.zeros((1, 2)), np.diff(theta, axis=0) / SPEC.dt])
    return Episode(
        spec=SPEC, time=np.arange(n_step) * SPEC.dt, u=u, theta=theta, omega=omega, name=f"e{seed}"
    )


def test_fit_recovers_dead_zone_gain_and_delay():
    sur = fit_structured([_episode(s) for s in range(4)], window=30)
    for name, truth in zip(SPEC.names, TRUTH):
        got = sur.metrics["joints"][name]
        assert got["delay"] == truth.delay
        assert got["a_pos"] == pytest.approx(truth.a_pos, abs=1e-9)
        assert got["a_neg"] == pytest.approx(truth.a_neg, abs=1e-9)
        # noise-free data: the least-squares gains are exact up to rounding
        assert got["k_pos"] == pytest.approx(truth.k_pos, rel=1e-6)
        assert got["k_neg"] == pytest.approx(truth.k_neg, rel=1e-6)
        assert got["rmse"] < 1e-9


def test_free_run_equals_a_plain_loop_with_end_stops_at_the_training_range():
    train = [_episode(s) for s in range(4)]
    sur = fit_structured(train, window=30)
    lo = np.min([e.theta.min(axis=0) for e in train], axis=0)
    hi = np.max([e.theta.max(axis=0) for e in train], axis=0)
    # a test that pushes past the training range: the end stops must act
    test = _episode(99, n_step=800, bias=400.0)
    run = rollout_episodes(sur, [test])[0]
    w = sur.window
    ref = np.empty_like(test.theta)
    ref[:w] = test.theta[:w]
    for t in range(w - 1, test.n_step - 1):
        for j, f in enumerate(TRUTH):
            ref[t + 1, j] = ref[t, j] + SPEC.dt * f.speed(test.u[t - f.delay, j])
        ref[t + 1] = np.clip(ref[t + 1], lo, hi)
    assert np.any(ref[w:] == hi) or np.any(ref[w:] == lo)  # the stops were reached
    # float32 network: at most ~1e-7 relative per step over n_step steps of angles ~|hi|
    tol = test.n_step * 1.2e-7 * (1.0 + np.abs(np.r_[lo, hi]).max()) * 10
    np.testing.assert_allclose(run.theta_hat, ref, atol=tol)


def test_evaluate_models_scores_it():
    train = [_episode(s) for s in range(3)]
    sur = fit_structured(train, window=30, end_stops=False)  # the test may leave their range
    metrics, _ = evaluate_models({"structured": sur}, [_episode(50)])
    assert all(metrics["structured"]["theta"][n]["r2"] > 0.999 for n in SPEC.names)


def test_delay_is_bounded_by_the_window():
    sur = fit_structured([_episode(s) for s in range(3)], window=4)
    assert sur.metrics["joints"]["b"]["delay"] <= 3  # the truth's 5 does not fit a window of 4


def test_no_usable_episode_is_one_clear_error():
    with pytest.raises(DataError, match="no training episodes"):
        fit_structured([])
    with pytest.raises(DataError, match="longer than the delay search"):
        fit_joint([np.zeros(3)], [np.zeros(3)], u_min=-1.0, u_max=1.0, max_delay=5)


def test_speed_ratio_is_the_least_squares_scale_of_the_maps_speed() -> None:
    """Speeds 1.3x the map's (after its delay) give 1.3; a map that never moves gives 1."""
    from excavator_surrogate.surrogate.structured import JointFit, speed_ratio

    fit = JointFit(delay=2, a_pos=100.0, a_neg=-50.0, k_pos=1e-3, k_neg=2e-3, rmse=0.0)
    rng = np.random.default_rng(0)
    u = [rng.uniform(-1000, 1000, 300), rng.uniform(-1000, 1000, 200)]
    w = [np.concatenate([[np.nan], np.zeros(2), 1.3 * fit.speed(x[:-3])]) for x in u]
    assert speed_ratio(fit, u, w) == pytest.approx(1.3, rel=1e-12)
    idle = [np.zeros(50)]
    assert speed_ratio(fit, idle, [np.ones(50)]) == 1.0


def test_joint_fit_reads_back_each_joint_of_fit_prior() -> None:
    """``joint_fit`` is ``fit_prior``'s lists read back: every joint's ``JointFit`` as
    ``fit_joints`` gave it, and ``rmse`` 0 where the lists keep none."""
    from excavator_surrogate.surrogate.structured import fit_joints, fit_prior, joint_fit

    eps = [_episode(s) for s in range(2)]
    fit = fit_prior(eps, SPEC, max_delay=6)
    for j, want in enumerate(fit_joints(eps, SPEC, max_delay=6)):
        assert joint_fit(fit, j) == want
    bare = {k: v for k, v in fit.items() if k != "rmse"}
    assert joint_fit(bare, 1).rmse == 0.0 and joint_fit(bare, 1).k_pos == fit["k_pos"][1]
