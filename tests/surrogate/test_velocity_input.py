"""The velocity input feature (``TrainConfig.velocity_input``): encoding, every rollout path,
training, checkpoints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.surrogate import rollout, rollout_reference
from excavator_surrogate.surrogate.angles import omega_in_np, omega_target
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, save_checkpoint
from excavator_surrogate.surrogate.features import Normalization, encode_np
from excavator_surrogate.surrogate.rollout import ClosedLoop, window_rollout
from tests.helpers.surrogates import make_surrogate
from tests.helpers.training import tiny_train_config, train_tiny_free_run


def test_the_feature_is_the_backward_difference_from_rest(spec, episodes):
    ep = episodes[0]
    w = omega_in_np(ep.theta, spec)
    np.testing.assert_array_equal(w[0], 0.0)
    np.testing.assert_allclose(w[1:], omega_target(ep.theta, spec)[1:])
    # a periodic joint across the +-pi seam: the wrapped difference, not 2 pi / T_s
    theta = np.zeros((3, spec.n_joint))
    theta[:, 0] = [np.pi - 0.01, -np.pi + 0.01, -np.pi + 0.03]
    w = omega_in_np(theta, spec)
    np.testing.assert_allclose(w[1:, 0], [0.02 / spec.dt, 0.02 / spec.dt], atol=1e-9)
    norm = Normalization.fit([ep.theta], [ep.u], spec, omega_in=True)
    th = torch.as_tensor(theta)
    np.testing.assert_allclose(norm.velocity_seq(th, spec.dt).numpy(), w, atol=1e-9)


def test_encode_with_velocity_matches_numpy_and_widens_the_input(spec, episodes):
    thetas, us = [e.theta for e in episodes], [e.u for e in episodes]
    norm = Normalization.fit(thetas, us, spec, omega_in=True)
    assert norm.n_feature == spec.n_feature + spec.n_joint
    ep = episodes[1]
    w = omega_in_np(ep.theta, spec)
    x_np = norm.encode_np(ep.theta, ep.u, spec, None, w)
    f32 = torch.float32
    x_t = norm.encode(
        torch.as_tensor(ep.theta, dtype=f32),
        torch.as_tensor(ep.u, dtype=f32),
        None,
        torch.as_tensor(w, dtype=f32),
    )
    np.testing.assert_allclose(x_t.numpy(), x_np, atol=1e-4)
    # the last n_joint raw columns are the velocity, the rest the paper's layout
    raw = encode_np(ep.theta, ep.u, spec, omega=w)
    np.testing.assert_allclose(raw[:, -spec.n_joint :], w)
    np.testing.assert_allclose(raw[:, : spec.n_feature], encode_np(ep.theta, ep.u, spec))
    with pytest.raises(ValueError, match="velocity"):
        norm.encode(torch.zeros(spec.n_joint), torch.zeros(spec.n_joint))
    with pytest.raises(ValueError, match="velocity"):
        norm.encode_np(ep.theta, ep.u, spec)


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
@pytest.mark.parametrize("play", [(), (0.05,)], ids=["plain", "play"])
def test_batched_rollout_with_velocity_equals_the_plain_loop(spec, episodes, mode, play):
    sur = make_surrogate(spec, episodes, mode=mode, window=5, play=play, omega_in=True)
    n = 60
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_b, om_b = rollout(sur, theta, u)
    for i in range(len(episodes)):
        th_r, om_r = rollout_reference(sur, theta[i], u[i])
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5)
        np.testing.assert_allclose(om_b[i], om_r, atol=1e-4)
    # the feature reaches the network: the same weights fed a zero velocity run otherwise
    loop = ClosedLoop(sur)
    loop.reset(theta[:, : sur.window], u[:, : sur.window - 1])
    loop.omega = torch.zeros_like(loop.omega)
    th0, _ = loop.step(u[:, sur.window - 1])
    assert np.abs(th0.numpy() - th_b[:, sur.window]).max() > 1e-6


def test_training_rollout_with_velocity_equals_the_closed_loop(spec, episodes):
    sur = make_surrogate(spec, episodes, mode="windowed", window=5, omega_in=True)
    ep = episodes[0]
    w, h, t = sur.window, 30, 12
    f32 = torch.float32
    vel = torch.as_tensor(omega_in_np(ep.theta, spec), dtype=f32)
    x = sur.norm.encode(
        torch.as_tensor(ep.theta[t - w + 1 : t + 1], dtype=f32),
        torch.as_tensor(ep.u[t - w + 1 : t + 1], dtype=f32),
        None,
        vel[t - w + 1 : t + 1],
    )
    with torch.no_grad():
        _, th = window_rollout(
            sur.net,
            sur.norm,
            x[None],
            torch.as_tensor(ep.theta[t], dtype=f32)[None],
            torch.as_tensor(ep.u[t + 1 : t + h], dtype=f32)[None],
            n_horizon=h,
            dt=spec.dt,
        )
    # the closed loop warmed up on the recorded samples 0..t carries the same velocities
    th_ref, _ = rollout(sur, ep.theta[None, : t + 1], ep.u[None, : t + h], warmup=t + 1)
    np.testing.assert_allclose(th[0, : h - 1].numpy(), th_ref[0, t + 1 :], atol=1e-5)


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
def test_residual_head_adds_the_velocity_and_merges_exactly(spec, episodes, mode):
    """A residual head's output is its plain head's plus the velocity feature, in every
    rollout path; a merged ensemble of residual members equals the members' plain loop."""
    from excavator_surrogate.surrogate.ensemble import merge

    kw = dict(mode=mode, window=5, omega_in=True, residual=True)
    sur = make_surrogate(spec, episodes, **kw)
    x = torch.randn(3, 5, sur.norm.n_feature)
    plain = sur.net.head(sur.net.rnn(x)[0][:, -1])
    torch.testing.assert_close(sur.net(x), plain + x[:, -1, -spec.n_joint :])
    y_seq, _ = sur.net.forward_seq(x)
    torch.testing.assert_close(y_seq[:, -1], sur.net(x), atol=1e-5, rtol=0)
    members = [sur, make_surrogate(spec, episodes, seed=1, hidden=8, **kw)]
    ens = merge(members)
    assert ens.model_cfg.residual
    n = 50
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_b, _ = rollout(ens, theta, u)
    for i in range(len(episodes)):
        th_r, _ = rollout_reference(members, theta[i], u[i])
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5)
    with pytest.raises(Exception, match="residual"):
        merge([sur, make_surrogate(spec, episodes, mode=mode, window=5, omega_in=True)])


def test_checkpoint_keeps_the_velocity_feature(spec, episodes, tmp_path: Path):
    sur = make_surrogate(spec, episodes, omega_in=True)
    back = load_checkpoint(save_checkpoint(tmp_path / "a.pt", sur))
    assert back.norm.omega_in and back.norm.n_feature == spec.n_feature + spec.n_joint
    plain = load_checkpoint(save_checkpoint(tmp_path / "b.pt", make_surrogate(spec, episodes)))
    assert not plain.norm.omega_in


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
def test_training_with_the_velocity_feature(tmp_path, mode):
    ds, sur = train_tiny_free_run(tmp_path, mode, velocity_input=True, residual=True)
    assert sur.norm.omega_in and sur.model_cfg.residual
    assert sur.model_cfg.n_feature == ds.spec.n_feature + ds.spec.n_joint
    th, _ = rollout(sur, ds.test[0].theta[None], ds.test[0].u[None])
    assert np.isfinite(th).all()
    with pytest.raises(Exception, match="velocity_input"):
        tiny_train_config(residual=True)
