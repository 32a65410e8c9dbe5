"""End stops: free-run angles are clipped to the spec's joint limits, identically in every path."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.surrogate import rollout, rollout_reference
from excavator_surrogate.surrogate.angles import integrate, integrate_np, joint_limits
from excavator_surrogate.surrogate.checkpoint import (
    checkpoint_dict,
    load_checkpoint,
    save_checkpoint,
)
from excavator_surrogate.surrogate.rollout import window_rollout
from tests.helpers.surrogates import make_surrogate


def test_joint_limits_leave_periodic_and_open_joints_unbounded(spec):
    lo, hi = joint_limits(spec)
    for k, j in enumerate(spec.joints):
        if j.periodic:
            assert lo[k] == -math.inf and hi[k] == math.inf
        else:
            assert (lo[k], hi[k]) == (j.theta_min, j.theta_max)


def test_integrate_clips_only_what_crosses_a_stop():
    lo = torch.tensor([-math.inf, -1.0, 0.0])
    hi = torch.tensor([math.inf, 1.0, 2.0])
    theta = torch.tensor([[5.0, 0.95, 0.5], [0.0, -0.5, 1.99]])
    omega = torch.tensor([[30.0, 2.0, 0.3], [-1.0, -0.1, 1.0]])
    dt = 0.05
    th, om = integrate(theta, omega, dt=dt, limits=(lo, hi))
    expect_th = torch.tensor([[6.5, 1.0, 0.515], [-0.05, -0.505, 2.0]])
    torch.testing.assert_close(th, expect_th)
    # unclipped entries keep the prediction bit for bit; clipped ones report the travel
    assert om[0, 0] == 30.0 and om[0, 2] == omega[0, 2] and om[1, 1] == omega[1, 1]
    torch.testing.assert_close(om[0, 1], torch.tensor((1.0 - 0.95) / dt))
    torch.testing.assert_close(om[1, 2], torch.tensor((2.0 - 1.99) / dt))
    th_n, om_n = integrate_np(
        theta.double().numpy(),
        omega.double().numpy(),
        dt=dt,
        limits=(lo.double().numpy(), hi.double().numpy()),
    )
    np.testing.assert_allclose(th_n, th.double().numpy(), atol=1e-6)
    np.testing.assert_allclose(om_n, om.double().numpy(), atol=1e-4)
    # no limits: plain integration
    th0, om0 = integrate(theta, omega, dt=dt)
    torch.testing.assert_close(th0, theta + dt * omega)
    assert om0 is omega


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
def test_free_run_stays_inside_the_stops_and_matches_the_plain_loop(spec, episodes, mode):
    sur = make_surrogate(spec, episodes, mode=mode, window=5, end_stops=True, drive=6.0)
    free = make_surrogate(spec, episodes, mode=mode, window=5, end_stops=False, drive=6.0)
    n = 60
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_b, om_b = rollout(sur, theta, u)
    th_f, _ = rollout(free, theta, u)
    lo, hi = joint_limits(spec)
    eps = 1e-6
    w = sur.window
    assert (th_b >= lo - eps).all() and (th_b <= hi + eps).all()
    limited = np.isfinite(lo)
    # without the stops the same network leaves the range; with them it rests on a stop
    assert (
        (th_f[..., limited] < lo[limited] - 0.1) | (th_f[..., limited] > hi[limited] + 0.1)
    ).any()
    at_stop = np.isclose(th_b[:, w:], lo, atol=1e-5) | np.isclose(th_b[:, w:], hi, atol=1e-5)
    assert at_stop[..., limited].mean() > 0.1
    # resting on a stop reports zero velocity; omega is what the angle actually travelled
    np.testing.assert_allclose(th_b[:, w:], th_b[:, w - 1 : -1] + spec.dt * om_b[:, w:], atol=1e-5)
    for i in range(len(episodes)):
        th_r, om_r = rollout_reference(sur, theta[i], u[i])
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5)
        np.testing.assert_allclose(om_b[i], om_r, atol=1e-4)


def test_training_rollout_uses_the_same_stops(spec, episodes):
    sur = make_surrogate(spec, episodes, mode="windowed", window=5, end_stops=True, drive=6.0)
    ep = episodes[0]
    w, h, t = sur.window, 40, 10
    x = sur.norm.encode(
        torch.as_tensor(ep.theta[t - w + 1 : t + 1], dtype=torch.float32),
        torch.as_tensor(ep.u[t - w + 1 : t + 1], dtype=torch.float32),
    )
    with torch.no_grad():
        _, th = window_rollout(
            sur.net,
            sur.norm,
            x[None],
            torch.as_tensor(ep.theta[t], dtype=torch.float32)[None],
            torch.as_tensor(ep.u[t + 1 : t + h], dtype=torch.float32)[None],
            n_horizon=h,
            dt=spec.dt,
            limits=sur.limits(),
        )
    # the windowed closed loop from the same history gives the same angles
    th_ref, _ = rollout(sur, ep.theta[None, t - w + 1 : t + 1], ep.u[None, t - w + 1 : t + h])
    np.testing.assert_allclose(th[0, : h - 1].numpy(), th_ref[0, w:], atol=1e-5)
    lo, hi = joint_limits(spec)
    assert (th.numpy() >= lo - 1e-6).all() and (th.numpy() <= hi + 1e-6).all()


def test_checkpoint_keeps_the_flag_and_old_checkpoints_load_without_stops(
    spec, episodes, tmp_path: Path
):
    sur = make_surrogate(spec, episodes, end_stops=True)
    path = save_checkpoint(tmp_path / "a.pt", sur)
    assert load_checkpoint(path).end_stops is True
    old = checkpoint_dict(sur)
    del old["end_stops"]
    torch.save(old, tmp_path / "old.pt")
    back = load_checkpoint(tmp_path / "old.pt")
    assert back.end_stops is False and back.limits() is None
