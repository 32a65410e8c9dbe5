"""Feature encoding and the integration-exact velocity target."""

from __future__ import annotations

import math

import numpy as np
import torch

from excavator_surrogate.spec import JointSpec, MachineSpec
from excavator_surrogate.surrogate import Normalization, encode_np, omega_target, wrap_angle
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec


def test_integrating_targets_reproduces_recorded_angles(spec):
    ep = synthetic_episode(spec, kind="step", n_step=400, seed=5, noise=0.002)
    w = omega_target(ep.theta, spec)
    assert np.isnan(w[0]).all() and np.isfinite(w[1:]).all()
    theta = ep.theta[0] + np.concatenate(
        [np.zeros((1, spec.n_joint)), np.cumsum(spec.dt * w[1:], axis=0)]
    )
    diff = theta - ep.theta
    per = np.array(spec.periodic)
    diff[:, per] = wrap_angle(diff[:, per])  # periodic joints are stored wrapped
    np.testing.assert_allclose(diff, 0.0, atol=1e-9)
    # and step by step: theta[k+1] = theta[k] + T_s * omega_tgt[k+1]
    step = ep.theta[:-1] + spec.dt * w[1:] - ep.theta[1:]
    step[:, per] = wrap_angle(step[:, per])
    np.testing.assert_allclose(step, 0.0, atol=1e-12)


def test_target_wraps_periodic_jumps_only():
    spec = MachineSpec(joints=(JointSpec("swing", periodic=True), JointSpec("boom")), rate_hz=10.0)
    theta = np.array([[3.1, 0.0], [-3.1, 0.5], [-3.0, 1.0]])
    w = omega_target(theta, spec)
    np.testing.assert_allclose(w[1], [(2 * math.pi - 6.2) / 0.1, 5.0])
    np.testing.assert_allclose(w[2], [1.0, 5.0], atol=1e-12)


def test_feature_layout_and_command_scaling():
    spec = MachineSpec(
        joints=(
            JointSpec("swing", periodic=True),
            JointSpec("boom", u_min=0.0, u_max=100.0),
            JointSpec("arm", u_min=-500.0, u_max=1500.0),
        )
    )
    theta = np.array([0.3, -0.2, 1.1])
    u = np.array([500.0, 75.0, 1500.0])
    x = encode_np(theta, u, spec)
    assert x.shape == (spec.n_feature,) == (7,)
    np.testing.assert_allclose(x[:4], [math.sin(0.3), math.cos(0.3), -0.2, 1.1])
    np.testing.assert_allclose(x[4:], [0.5, 0.5, 1.0])


def test_torch_encoding_matches_numpy_and_is_normalised(spec, episodes):
    norm = Normalization.fit([e.theta for e in episodes], [e.u for e in episodes], spec)
    ep = episodes[0]
    xn = norm.encode_np(ep.theta, ep.u, spec)
    xt = norm.encode(
        torch.tensor(ep.theta, dtype=torch.float32), torch.tensor(ep.u, dtype=torch.float32)
    )
    np.testing.assert_allclose(xt.numpy(), xn, atol=1e-5)
    allx = np.concatenate([norm.encode_np(e.theta, e.u, spec) for e in episodes])
    np.testing.assert_allclose(allx.mean(0), 0.0, atol=1e-6)
    y = torch.tensor([[0.1] * spec.n_joint])
    torch.testing.assert_close(norm.target(norm.omega(y)), y)


def test_spec_without_periodic_joints_has_raw_angles():
    spec = synthetic_spec(3, periodic_first=False)
    assert spec.n_feature == 6
    x = encode_np(np.array([0.1, 0.2, 0.3]), np.zeros(3), spec)
    np.testing.assert_allclose(x, [0.1, 0.2, 0.3, 0, 0, 0])
