"""Batched closed-loop rollout == plain one-step-at-a-time loop (windowed and stateful)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from excavator_surrogate.surrogate import (
    ClosedLoop,
    omega_target,
    rollout,
    rollout_episodes,
    rollout_reference,
)
from tests.helpers.surrogates import make_surrogate


@pytest.mark.parametrize(
    ("cell", "mode"),
    [("lstm", "windowed"), ("lstm", "stateful"), ("gru", "windowed"), ("gru", "stateful")],
)
def test_batched_rollout_matches_plain_loop(spec, episodes, cell, mode):
    sur = make_surrogate(spec, episodes, cell=cell, mode=mode, window=6)
    n = 60
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_b, om_b = rollout(sur, theta, u)
    assert th_b.shape == om_b.shape == (len(episodes), n, spec.n_joint)
    assert np.isnan(om_b[:, : sur.window]).all() and np.isfinite(om_b[:, sur.window :]).all()
    np.testing.assert_array_equal(th_b[:, : sur.window], theta[:, : sur.window].astype(np.float32))
    for i in range(len(episodes)):
        th_r, om_r = rollout_reference(sur, theta[i], u[i])
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5)
        np.testing.assert_allclose(om_b[i], om_r, atol=1e-5)
    # the model actually moves the state (not a trivially constant rollout)
    assert np.abs(th_b[:, -1] - th_b[:, sur.window - 1]).max() > 1e-4


def test_angles_integrate_predicted_velocity(spec, episodes):
    sur = make_surrogate(spec, episodes, mode="stateful")
    th, om = rollout(sur, episodes[0].theta[None, :40], episodes[0].u[None, :40])
    w = sur.window
    np.testing.assert_allclose(th[0, w:], th[0, w - 1 : -1] + spec.dt * om[0, w:], atol=1e-6)


def test_padded_episodes_match_individual_rollouts(spec, episodes):
    sur = make_surrogate(spec, episodes, mode="windowed", window=5)
    together = rollout_episodes(sur, episodes)
    assert [len(r.time) for r in together] == [e.n_step for e in episodes]
    for ep, r in zip(episodes, together):
        alone = rollout_episodes(sur, [ep])[0]
        np.testing.assert_allclose(r.theta_hat, alone.theta_hat, atol=1e-5)
        np.testing.assert_array_equal(r.omega_ref, omega_target(ep.theta, spec))


def test_closed_loop_stepper_continues_a_rollout(spec, episodes):
    sur = make_surrogate(spec, episodes, mode="stateful", window=4)
    ep = episodes[0]
    th, _ = rollout(sur, ep.theta[None, :30], ep.u[None, :30])
    loop = ClosedLoop(sur)
    cur = loop.reset(ep.theta[None, :4], ep.u[None, :3])
    torch.testing.assert_close(cur, torch.tensor(ep.theta[None, 3], dtype=torch.float32))
    for k in range(3, 29):
        cur, _ = loop.step(ep.u[None, k])
        np.testing.assert_allclose(cur.numpy()[0], th[0, k + 1], atol=1e-6)


def test_arx_cannot_be_stepped_statefully(spec, episodes):
    from excavator_surrogate.errors import ConfigError

    sur = make_surrogate(spec, episodes, cell="arx", window=4)
    with pytest.raises(ConfigError):
        ClosedLoop(sur, mode="stateful")


@pytest.mark.parametrize(("mode", "warmup"), [("windowed", 1), ("windowed", 3), ("stateful", 2)])
def test_short_warmup_matches_plain_loop(spec, episodes, mode, warmup):
    sur = make_surrogate(spec, episodes, mode=mode, window=6)
    theta = np.stack([e.theta[:40] for e in episodes])
    u = np.stack([e.u[:40] for e in episodes])
    th_b, om_b = rollout(sur, theta, u, warmup=warmup)
    for i in range(len(episodes)):
        th_r, om_r = rollout_reference(sur, theta[i], u[i], warmup=warmup)
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5)
        np.testing.assert_allclose(om_b[i], om_r, atol=1e-5)


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
def test_reset_at_measured_starts_is_a_reset_on_each_ones_own_history(spec, episodes, mode):
    """``ClosedLoop.reset_at`` (one row per measured start) steps as one loop per start, each
    reset on its own slice of the episode: the warm-up ``theta[k - n + 1 .. k]``, the
    commands ``u[k - n + 1 .. k - 1]``, then ``u[k]`` predicts sample ``k + 1``."""
    sur = make_surrogate(spec, episodes, mode=mode, window=6)
    ep = episodes[0]
    starts = np.array([5, 9, 17, 30])
    for n in (sur.window, sur.window + 3):  # the model's window, and a longer warm-up
        ks = starts[starts >= n - 1]
        loop = ClosedLoop(sur)
        loop.reset_at(ep.theta, ep.u, ks, n_hist=n)
        got = [loop.step(ep.u[ks + j])[0].double().numpy() for j in range(3)]
        for row, k in enumerate(ks):
            one = ClosedLoop(sur)
            one.reset(ep.theta[None, k - n + 1 : k + 1], ep.u[None, k - n + 1 : k])
            for j in range(3):
                ref = one.step(ep.u[None, k + j])[0][0].double().numpy()
                np.testing.assert_allclose(got[j][row], ref, atol=1e-5)


def test_the_true_reference_of_a_log_without_ground_truth_says_what_to_do(episodes):
    from excavator_surrogate.errors import DataError
    from excavator_surrogate.surrogate.rollout import reference_theta

    ep = episodes[0].replace(theta_true=None, omega_true=None)
    np.testing.assert_array_equal(reference_theta(ep, "measured"), ep.theta)
    with pytest.raises(
        DataError, match=f"episode '{ep.name}': has no ground truth .*--reference measured"
    ):
        reference_theta(ep, "true")


def test_a_nan_command_or_angle_is_refused_not_propagated(spec, episodes):
    """One NaN command turned every joint's free run NaN from that step on, and the coverage
    flags did not see it; each entry point now names the entry."""
    from excavator_surrogate.control.predict import SurrogatePredictor
    from excavator_surrogate.errors import ConfigError
    from excavator_surrogate.surrogate.numpy_loop import rollout_numpy

    sur = make_surrogate(spec, episodes, mode="stateful", window=6)
    theta = np.stack([e.theta[:60] for e in episodes[:2]])
    u = np.stack([e.u[:60] for e in episodes[:2]])
    j = spec.n_joint - 1
    name = spec.names[j]
    bad_u = u.copy()
    bad_u[1, 40, j] = np.nan
    with pytest.raises(ConfigError, match=rf"^rollout: u\[1, 40, {j}\] \({name}\) is nan: a free"):
        rollout(sur, theta, bad_u)
    with pytest.raises(ConfigError, match=rf"^rollout_numpy: u\[1, 40, {j}\] \({name}\) is nan"):
        rollout_numpy(sur, theta, bad_u, warmup=sur.window)
    bad_theta = theta.copy()
    bad_theta[0, 3, j] = np.inf
    with pytest.raises(ConfigError, match=rf"^rollout: theta\[0, 3, {j}\] \({name}\) is inf"):
        rollout(sur, bad_theta, u)
    loop = ClosedLoop(sur)
    loop.reset(theta[:, : sur.window], u[:, : sur.window - 1])
    with pytest.raises(ConfigError, match=rf"^ClosedLoop.step: u\[0, {j}\] \({name}\) is nan"):
        loop.step(np.where(np.arange(spec.n_u) == j, np.nan, u[:, 0]))
    p = SurrogatePredictor(sur, n_batch=2)
    p.reset(theta[0, 0])
    nan_at_j = np.where(np.arange(spec.n_joint) == j, np.nan, 0.0)
    with pytest.raises(ConfigError, match=rf"^SurrogatePredictor.observe: theta\[{j}\]"):
        p.observe(u[0, 0], nan_at_j)
    cand = np.zeros((2, 5, spec.n_joint))
    cand[1, 4, j] = np.nan
    with pytest.raises(ConfigError, match=rf"^SurrogatePredictor.predict: u\[1, 4, {j}\]"):
        p.predict(cand)


def test_another_machines_data_is_refused_in_one_line(spec, episodes):
    from excavator_surrogate.errors import DataError

    sur = make_surrogate(spec, episodes, window=6)
    theta = np.stack([e.theta[:30] for e in episodes])
    u = np.stack([e.u[:30] for e in episodes])
    n = spec.n_joint
    with pytest.raises(
        DataError,
        match=rf"rollout: the model is of a machine with joints .*got theta \(\d+, 30, {n - 1}\)",
    ):
        rollout(sur, theta[..., :-1], u)  # one joint fewer: another machine
    with pytest.raises(
        DataError, match=r"rollout: the model is of a machine .*use data of the model's machine"
    ):
        rollout(sur, theta, u[..., :-1])
    with pytest.raises(DataError, match=r"rollout: needs theta .*add the batch axis"):
        rollout(sur, theta, u[0])
    with pytest.raises(DataError, match="of one batch size"):
        rollout(sur, theta, np.concatenate([u, u]))
    with pytest.raises(DataError, match=r"ClosedLoop.reset: the model is of a machine"):
        ClosedLoop(sur).reset(theta[:, :6, :-1], u[:, :5])
