"""The ARX baseline recovers a linear system and rolls out like the LSTM."""

from __future__ import annotations

import numpy as np
import torch

from excavator_surrogate.data import Episode
from excavator_surrogate.spec import JointSpec, MachineSpec
from excavator_surrogate.surrogate import fit_arx, omega_target, rollout_episodes


def _linear_episode(spec: MachineSpec, n_step: int, seed: int) -> Episode:
    """omega[k+1] = A omega[k] + B u[k-1]/1000 + C theta[k]  (a delayed, coupled linear plant)."""
    rng = np.random.default_rng(seed)
    A = np.array([[0.8, 0.05], [0.0, 0.6]])
    B = np.array([[0.4, 0.0], [0.1, 0.3]])
    C = np.array([[-0.02, 0.0], [0.0, -0.05]])
    u = rng.uniform(-1000, 1000, (n_step, 2))
    theta = np.zeros((n_step, 2))
    omega = np.zeros((n_step, 2))
    for k in range(1, n_step - 1):
        omega[k + 1] = A @ omega[k] + B @ (u[k - 1] / 1000) + C @ theta[k]
        theta[k + 1] = theta[k] + spec.dt * omega[k + 1]
    return Episode(
        spec=spec,
        time=np.arange(n_step) * spec.dt,
        u=u,
        theta=theta,
        omega=omega,
        name=f"lin{seed}",
    )


def test_arx_recovers_linear_system():
    spec = MachineSpec(joints=(JointSpec("a"), JointSpec("b")), rate_hz=20.0)
    train = [_linear_episode(spec, 400, s) for s in range(3)]
    test = _linear_episode(spec, 300, 99)
    arx = fit_arx(train, window=4, spec=spec, ridge=1e-10)
    # one-step predictions reproduce the exact targets
    x = arx.norm.encode_np(test.theta, test.u, spec)
    win = np.stack([x[t - 3 : t + 1] for t in range(3, test.n_step - 1)])
    with torch.no_grad():
        y = arx.net(torch.tensor(win, dtype=torch.float32)).double().numpy()
    omega_hat = y * arx.norm.y_std.double().numpy() + arx.norm.y_mean.double().numpy()
    np.testing.assert_allclose(omega_hat, omega_target(test.theta, spec)[4:], atol=1e-4)
    # closed loop: the free run stays on the true trajectory
    run = rollout_episodes(arx, [test])[0]
    err = np.abs(run.theta_hat - test.theta).max()
    assert err < 1e-4, err


def test_arx_ridge_is_chosen_on_validation():
    from excavator_surrogate.surrogate.baselines import RIDGES

    spec = MachineSpec(joints=(JointSpec("a"), JointSpec("b")), rate_hz=20.0)
    train = [_linear_episode(spec, 200, s) for s in range(2)]
    arx = fit_arx(train, window=3, spec=spec, val=[_linear_episode(spec, 120, 7)])
    assert arx.metrics["ridge"] in RIDGES and arx.metrics["val_error"] < 0.05
