"""The synthetic plant of the tests' fixtures: its per-joint float stepping against the
array form of its equations."""

from __future__ import annotations

import numpy as np

from excavator_surrogate.surrogate.synthetic import _advance, synthetic_episode, synthetic_spec


def _advance_arrays(theta, v, drive, gain, grav, tau, lo, hi, *, drag, h, substeps):
    """The module's equations on arrays, all joints at once (the plain reference)."""
    for _ in range(substeps):
        v_cmd = gain * drive * (1.0 - grav * np.sign(drive) * np.cos(theta))
        acc = (v_cmd - v) / tau - drag * v * np.abs(v)
        v = v + h * acc
        theta = theta + h * v
        stop = (theta < lo) | (theta > hi)
        theta = np.clip(theta, lo, hi)
        v = np.where(stop, 0.0, v)
    return theta, v


def test_joint_by_joint_floats_step_as_the_arrays_do_and_rest_on_the_stops():
    rng = np.random.default_rng(0)
    nj = 4
    gain, tau = np.array([0.35, 0.45, 0.55, 0.35]), np.array([0.15, 0.2, 0.15, 0.2])
    grav = np.array([0.0, 0.15, 0.15, 0.15])
    lo, hi = np.array([-np.inf, -0.4, -0.5, -0.6]), np.array([np.inf, 0.4, 0.5, 0.6])
    theta, v = rng.uniform(-0.3, 0.3, nj), np.zeros(nj)
    th_list, v_list = theta.tolist(), v.tolist()
    plant = (gain.tolist(), grav.tolist(), tau.tolist(), lo.tolist(), hi.tolist())
    rested = np.zeros(nj, dtype=bool)
    for _ in range(300):
        drive = rng.uniform(-1.0, 1.0, nj) * (rng.random(nj) > 0.2)  # zero drive too
        _advance(th_list, v_list, drive.tolist(), *plant, drag=0.5, h=0.005, substeps=10)
        theta, v = _advance_arrays(
            theta, v, drive, gain, grav, tau, lo, hi, drag=0.5, h=0.005, substeps=10
        )
        np.testing.assert_allclose(th_list, theta, rtol=0, atol=1e-12)
        np.testing.assert_allclose(v_list, v, rtol=0, atol=1e-12)
        rested |= (theta == lo) | (theta == hi)
    assert rested[1:].all() and not rested[0]  # every bounded joint met a stop, the swing none


def test_an_episode_is_the_same_for_the_same_seed_and_stays_inside_its_stops():
    spec = synthetic_spec(4)
    a = synthetic_episode(spec, kind="step", n_step=400, seed=3)
    b = synthetic_episode(spec, kind="step", n_step=400, seed=3)
    np.testing.assert_array_equal(a.theta_true, b.theta_true)
    for j, joint in enumerate(spec.joints):
        if joint.theta_min is not None:
            assert joint.theta_min <= a.theta_true[:, j].min()
            assert a.theta_true[:, j].max() <= joint.theta_max
